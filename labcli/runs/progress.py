"""Training progress: a rich bar on a terminal, a plain line every tenth of the run elsewhere."""

from __future__ import annotations

import math
import time

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)


class TrainProgress:
    def __init__(self, total: int, description: str, console: Console | None = None,
                 start: int = 0):
        self.console = console or Console(stderr=True)
        self.total = total
        self.description = description
        self.start = start
        self._bar: Progress | None = None
        self._next_line = start
        self._last_line: tuple[float, int] | None = None  # (time, steps) of the last line

    def __enter__(self) -> TrainProgress:
        if self.console.is_terminal:
            self._bar = Progress(
                TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                TextColumn("{task.fields[stats]}"), TimeElapsedColumn(), TimeRemainingColumn(),
                console=self.console)
            self._bar.__enter__()
            self._task = self._bar.add_task(self.description, total=self.total,
                                             completed=self.start, stats="")
        else:
            self.console.print(f"{self.description}: {self.total} iterations")
        return self

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._bar.__exit__(*exc)

    def update(self, iteration: int, steps_per_s: float, mean_return: float | None,
               success_rate: float | None, terrain_level: float | None = None,
               steps: int | None = None) -> None:
        """`steps_per_s`: the iteration's own rate, which the bar shows. A line shows the rate
        since the last line (with `steps`, the run's count), what the run did between them:
        one iteration's may be one that wrote a checkpoint."""
        line_due = self._bar is None and (iteration >= self._next_line
                                          or iteration == self.total)
        if line_due and steps is not None:
            now = time.perf_counter()
            if self._last_line is not None and now > self._last_line[0]:
                steps_per_s = (steps - self._last_line[1]) / (now - self._last_line[0])
            self._last_line = (now, steps)
        parts = [f"{steps_per_s:,.0f} steps/s"]
        if mean_return is not None and not math.isnan(mean_return):
            parts.append(f"return {mean_return:.1f}")
        if success_rate is not None and not math.isnan(success_rate):
            parts.append(f"success {success_rate:.0%}")
        if terrain_level is not None and not math.isnan(terrain_level):
            parts.append(f"terrain level {terrain_level:.1f}")
        stats = "  ".join(parts)
        if self._bar is not None:
            self._bar.update(self._task, completed=iteration, stats=stats)
        elif line_due:
            self.console.print(f"  iteration {iteration}/{self.total}  {stats}")
            self._next_line = iteration + max(1, self.total // 10)
