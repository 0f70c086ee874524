"""The last good state of a run, kept between checkpoints so that a diverging run still ends
with it on disk.

After each iteration the agent is written to a hidden `.candidate/` dir of the run. The next
iteration proves it: its rollout acted finitely, so the candidate becomes `.good/`. When training
diverges, the newest proven state is moved into the run dir as an ordinary checkpoint (unless
that iteration's checkpoint is there already); when training ends otherwise both are removed.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from labcli.plugins.framework import FrameworkSpec
from labcli.runs import snapshot

CANDIDATE, GOOD = ".candidate", ".good"


class LastGood:
    def __init__(self, run_dir: Path, framework: FrameworkSpec):
        self.run_dir, self.framework = run_dir, framework

    def keep(self, iteration: int, state: dict[str, Any] | None,
             save: Callable[[Path], None]) -> None:
        """Write the agent after `iteration`'s update as the candidate."""
        candidate = self.run_dir / CANDIDATE
        shutil.rmtree(candidate, ignore_errors=True)
        candidate.mkdir()
        if state is not None:
            snapshot.save(snapshot.path_of(candidate, iteration), state)
        save(self.framework.checkpoint_path(candidate, iteration))

    def promote(self) -> None:
        """The candidate acted finitely for a whole rollout: it is the last good state now."""
        candidate, good = self.run_dir / CANDIDATE, self.run_dir / GOOD
        if candidate.is_dir():
            shutil.rmtree(good, ignore_errors=True)
            os.replace(candidate, good)

    def commit(self, candidate_proven: bool) -> None:
        """Move the newest proven state into the run dir as a checkpoint, companions first."""
        kept = self.run_dir / (CANDIDATE if candidate_proven else GOOD)
        found = self.framework.checkpoints(kept) if kept.is_dir() else []
        if found and not self.framework.checkpoint_path(self.run_dir,
                                                         found[-1].iteration).exists():
            model = found[-1].path
            for path in [*(p for p in kept.iterdir() if p != model), model]:
                os.replace(path, self.run_dir / path.name)
        self.discard()

    def discard(self) -> None:
        for name in (CANDIDATE, GOOD):
            shutil.rmtree(self.run_dir / name, ignore_errors=True)
