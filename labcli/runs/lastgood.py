"""The last good state of a run, kept between checkpoints so that a diverging run still ends
with it on disk.

After each iteration the agent is written to a hidden `.candidate/` dir of the run, not flushed
to the disk, and the env's state (episodes in flight, generators) is held in memory: only this
process reads them back (on the CPU, a 4,096-env G1 run kept it in 20 ms an iteration this way,
62 ms with the state written and both flushed). The next iteration proves the candidate: its
rollout acted finitely, so it becomes `.good/`. When training diverges, the newest proven state
is written into the run dir as an ordinary checkpoint with its env state (unless that
iteration's checkpoint is there already); when training ends otherwise both are removed.
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
        self._states: dict[str, dict[str, Any]] = {}  # the env states, by dir name

    def keep(self, iteration: int, state: dict[str, Any] | None,
             save: Callable[[Path], None]) -> None:
        """Write the agent after `iteration`'s update as the candidate, a complete checkpoint;
        hold `state` (the env's and generators') with it."""
        candidate = self.run_dir / CANDIDATE
        files.remove(candidate)
        self._states.pop(CANDIDATE, None)
        checkpoints.write(candidate, self.framework, iteration, save, below=self.run_dir,
                          durable=False)
        if state is not None:
            self._states[CANDIDATE] = state

    def promote(self) -> None:
        """The candidate acted finitely for a whole rollout: it is the last good state now."""
        candidate, good = self.run_dir / CANDIDATE, self.run_dir / GOOD
        if candidate.is_dir() and not candidate.is_symlink():
            files.remove(good)
            candidate.replace(good)
            self._states.pop(GOOD, None)
            if CANDIDATE in self._states:
                self._states[GOOD] = self._states.pop(CANDIDATE)

    def commit(self, candidate_proven: bool) -> None:
        """Write the newest proven state into the run dir as a checkpoint, unless that
        iteration is checkpointed there already."""
        name = CANDIDATE if candidate_proven else GOOD
        kept = self.run_dir / name
        found = None
        if kept.is_dir() and not kept.is_symlink():
            found = checkpoints.latest_complete(self.framework, kept)
        if found is not None and not checkpoints.manifest_path(self.run_dir,
                                                               found.iteration).exists():
            state = self._states.get(name)
            extra = snapshot.writer(found.iteration, state) if state is not None else None
            checkpoints.rewrite(kept, self.framework, found.iteration, self.run_dir, extra)
        self.discard()

    def discard(self) -> None:
        for name in (CANDIDATE, GOOD):
            files.remove(self.run_dir / name)
        self._states.clear()
