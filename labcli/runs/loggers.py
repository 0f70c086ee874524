"""Where a run's figures go: the run dir's TensorBoard event files, always (`lab plot`, the
benches and the best checkpoint read them), and with `--logger wandb` a Weights & Biases run as
well: the same scalars, a row per iteration against `env_steps`, the run's settings as its
config, and each `lab export` of the run as a model artifact. The W&B run's id is kept in the run
dir (`wandb.json`): a resume logs on into the same W&B run, an export adds to it.

W&B is optional (`pip install 'lab[wandb]'`); it reads its own settings from the environment
(`WANDB_API_KEY`, `WANDB_ENTITY`, `WANDB_MODE=offline` to log into the run dir and
`wandb sync` later); the project is `WANDB_PROJECT`, else "lab".
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from labcli.errors import LabError, first_line
from labcli.runs import rundir

LOGGERS = ("tensorboard", "wandb")
WANDB_FILE = "wandb.json"
STEP = "env_steps"
INSTALL = "pip install 'lab[wandb]' (or pip install wandb)"


def check(logger: str) -> None:
    """Raise the LabError that says why `logger` cannot log, before anything is written."""
    if logger not in LOGGERS:
        raise LabError(f"--logger {logger!r} is not a logger lab has",
                       f"pass one of {', '.join(LOGGERS)}")
    if logger == "wandb":
        _wandb()


def _wandb() -> Any:
    try:
        import wandb
    except ImportError:
        raise LabError("--logger wandb needs Weights & Biases, which is not installed",
                       INSTALL) from None
    return wandb


def _saved(run_dir: Path) -> dict[str, Any]:
    path = run_dir / WANDB_FILE
    if not path.is_file():
        return {}
    try:
        saved = json.loads(path.read_text())
        return saved if isinstance(saved.get("id"), str) else {}
    except (OSError, ValueError, AttributeError):
        return {}  # unreadable: a new W&B run rather than a failed training


def _start(run_dir: Path, config: dict[str, Any] | None, job: str) -> Any:
    """The run dir's W&B run, resumed if it has one, else a new one recorded there."""
    wandb = _wandb()
    saved = _saved(run_dir)
    try:
        run = wandb.init(
            project=saved.get("project") or os.environ.get("WANDB_PROJECT") or "lab",
            name=run_dir.name, group=f"{run_dir.parent.name}/{run_dir.parent.parent.name}",
            dir=str(run_dir), id=saved.get("id"), resume="allow" if saved else None,
            config=config, job_type=job,
            # lab shows its own progress: W&B neither prints nor captures the console.
            settings=wandb.Settings(silent=True, console="off"))
    except Exception as exc:  # W&B's own errors: no login, no network, a bad entity
        raise LabError(f"Weights & Biases could not start a run: {first_line(exc)}",
                       "log in with `wandb login`, or set WANDB_MODE=offline to log into the "
                       "run dir and `wandb sync` it later") from None
    if not saved:
        rundir.write_json(run_dir, WANDB_FILE, {"id": run.id, "project": run.project})
    return run


class Figures:
    """What lab and the libraries log through (SummaryWriter's methods): every scalar into
    TensorBoard and, given a W&B run, into it too, one row per step; any other figure
    (histograms, text) into TensorBoard only."""

    def __init__(self, tensorboard: Any):
        self.tensorboard = tensorboard
        self.wandb_run: Any = None
        self._step: float | None = None
        self._row: dict[str, float] = {}

    def join_wandb(self, run_dir: Path, config: dict[str, Any]) -> None:
        """Log into the run dir's W&B run from now on (`--logger wandb`)."""
        self.wandb_run = _start(run_dir, config, "train")
        self.wandb_run.define_metric(STEP)
        self.wandb_run.define_metric("*", step_metric=STEP)

    def add_scalar(self, tag: str, value: Any, global_step: Any = None, *args: Any,
                   **kwargs: Any) -> None:
        self.tensorboard.add_scalar(tag, value, global_step, *args, **kwargs)
        if self.wandb_run is None:
            return
        if global_step != self._step:
            self._flush()
            self._step = global_step
        self._row[tag] = float(value)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.tensorboard, name)

    def _flush(self) -> None:
        if self._row:
            self.wandb_run.log({**self._row, STEP: self._step})
            self._row = {}

    def close(self) -> None:
        try:
            if self.wandb_run is not None:
                self._flush()
                self.wandb_run.finish()
        finally:
            self.tensorboard.close()


def log_export(run_dir: Path, paths: list[Path]) -> str | None:
    """The exported files as a model artifact of the run's W&B run, where it has one: None, or
    the line that says why they were not (the export itself stands)."""
    if not _saved(run_dir):
        return None
    try:
        run = _start(run_dir, None, "export")
    except LabError as exc:
        return f"note: the export was not logged to Weights & Biases: {exc.message}"
    try:
        artifact = _wandb().Artifact(f"{run_dir.parent.name}-{run.id}", type="model")
        for path in paths:
            artifact.add_file(str(path))
        run.log_artifact(artifact)
    except Exception as exc:  # W&B's own errors: the export on disk stands
        return f"note: the export was not logged to Weights & Biases: {first_line(exc)}"
    finally:
        run.finish()
    return None
