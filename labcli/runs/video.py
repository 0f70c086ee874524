"""Where videos of a run go and what `--video-length` / `--video-interval` ask for."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from labcli.envs.wrappers import Step
from labcli.errors import LabError
from labcli.plugins.builtin import VIDEO

VIDEOS = "videos"
TRAIN, PLAY = "train", "play"


@dataclass(frozen=True)
class VideoSettings:
    """What `--video-length` and `--video-interval` ask for."""

    length: int = 200
    interval: int | None = 2000

    def __post_init__(self) -> None:
        if self.length < 2:
            raise LabError(f"--video-length must be at least 2 steps, got {self.length}")
        if self.interval is not None and self.interval <= 0:
            raise LabError(f"--video-interval must be a positive number of steps, got "
                           f"{self.interval}")

    def step(self, folder: Path) -> Step:
        return Step(VIDEO, {"folder": folder, "length": self.length, "interval": self.interval})


def folder(run_dir: Path, kind: str) -> Path:
    return run_dir / VIDEOS / kind
