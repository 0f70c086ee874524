"""mp4 videos of env 0: an env-stage wrapper that renders while training or playing. It is
registered as the wrapper `video` (labcli/plugins/builtin.py)."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from labcli import files
from labcli.errors import LabError


class VideoRecorder(gym.vector.VectorWrapper):
    """Records `length` env steps of env 0 every `interval` steps (the first from step 0), each
    recording one mp4 in `folder`; `interval` None records once. Steps pass through unchanged."""

    def __init__(self, env: gym.vector.VectorEnv, folder: Path, length: int = 200,
                 interval: int | None = 2000, fps: float | None = None):
        # imageio writes mp4 through imageio-ffmpeg; without it, it would pick another format's
        # writer and fail at the first video's end: said before any work.
        if importlib.util.find_spec("imageio_ffmpeg") is None:
            raise LabError("writing mp4 videos needs imageio-ffmpeg, which is not installed",
                           "pip install imageio-ffmpeg, or leave out --video")
        super().__init__(env)
        self.folder, self.length, self.interval = Path(folder), length, interval
        self.fps = fps or 1.0 / env.unwrapped.step_dt
        self.step_count = 0
        self.files: list[Path] = []
        self._frames: list[np.ndarray] = []
        self._start = 0

    def __getattr__(self, name: str) -> Any:
        # What lab reads from its env (pop_stats, device, task_spec...) passes through.
        if name == "env":
            raise AttributeError(name)
        return getattr(self.env, name)

    def step(self, actions: Any):
        result = self.env.step(actions)
        due = self.step_count == 0 if self.interval is None else \
            self.step_count % self.interval == 0
        if not self._frames and due:
            self._start = self.step_count
        if self._frames or due:
            self._frames.append(self.env.render())
            if len(self._frames) >= self.length:
                self._write()
        self.step_count += 1
        return result

    def close(self, **kwargs: Any) -> None:
        if len(self._frames) > 1:  # a recording cut short by the end of training or play
            self._write()
        self.env.close(**kwargs)

    def _write(self) -> None:
        import imageio.v2 as imageio

        path = self.folder / f"step-{self._start}.mp4"
        with files.staged(path, below=self.folder) as tmp:  # a reader never sees half a video
            imageio.mimwrite(tmp, self._frames, fps=self.fps, macro_block_size=1)
        self.files.append(path)
        self._frames = []
