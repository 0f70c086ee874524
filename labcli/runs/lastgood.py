"""The last good state of a run, kept between checkpoints so that a diverging run still ends
with it on disk.

After each iteration the agent is written to a hidden `.candidate/` dir of the run. The next
iteration proves it: its rollout acted finitely, so the candidate becomes `.good/`. When training
diverges, the newest proven state is moved into the run dir as an ordinary checkpoint (unless
that iteration's checkpoint is there already); when training ends otherwise both are removed.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from labcli import files
from labcli.plugins.framework import FrameworkSpec
from labcli.runs import checkpoints, snapshot

CANDIDATE, GOOD = ".candidate", ".good"


class LastGood:
    def __init__(self, run_dir: Path, framework: FrameworkSpec):
        self.run_dir, self.framework = run_dir, framework

    def keep(self, iteration: int, state: dict[str, Any] | None,
             save: Callable[[Path], None]) -> None:
        """Write the agent after `iteration`'s update as the candidate, a complete checkpoint."""
        candidate = self.run_dir / CANDIDATE
        files.remove(candidate)
        extra = snapshot.writer(iteration, state) if state is not None else None
        checkpoints.write(candidate, self.framework, iteration, save, extra, below=self.run_dir)

    def promote(self) -> None:
        """The candidate acted finitely for a whole rollout: it is the last good state now."""
        candidate, good = self.run_dir / CANDIDATE, self.run_dir / GOOD
        if candidate.is_dir() and not candidate.is_symlink():
            files.remove(good)
            candidate.replace(good)

    def commit(self, candidate_proven: bool) -> None:
        """Move the newest proven state into the run dir as a checkpoint, unless that iteration
        is checkpointed there already."""
        kept = self.run_dir / (CANDIDATE if candidate_proven else GOOD)
        found = None
        if kept.is_dir() and not kept.is_symlink():
            found = checkpoints.latest_complete(self.framework, kept)
        if found is not None and not checkpoints.manifest_path(self.run_dir,
                                                               found.iteration).exists():
            checkpoints.move(kept, self.run_dir, found.iteration)
        self.discard()

    def discard(self) -> None:
        for name in (CANDIDATE, GOOD):
            files.remove(self.run_dir / name)
