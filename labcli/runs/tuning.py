"""A sweep's side in Ray Tune: Ray started or joined, the Tuner built or restored, each trial one
`lab train` as a library call whose iterations are reported to Tune and which ends as a lab run
however Tune ends it, and the trials' progress told in the driver. Imports Ray: only
`labcli/runs/sweep.py` imports this module, once it knows Ray is installed.

How Tune stops a function trainable (read in Ray 2.60's `ray/train/_internal/session.py` and
`ray/tune/trainable/function_trainable.py`): the trial's function runs in a daemon thread of the
trial's actor, and `tune.report` blocks it until the controller has seen the result. To stop the
trial (its scheduler's decision, the sweep's end, Ctrl-C), the controller calls the actor's
`stop`, whose `cleanup` raises SystemExit in that thread from inside `tune.report`, waits for
it 0 s, and the actor exits, killing the thread wherever it is: mid-checkpoint. So here the
report's SystemExit becomes a stop of the lab run (checkpointed, its summary written, as Ctrl-C
does to `lab train`), and `cleanup` waits for the run to end before the actor may exit."""

from __future__ import annotations

import logging
import math
import os
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import ray
from ray import tune
from ray.train._internal.session import get_session
from ray.tune.trainable.function_trainable import wrap_function
from rich.console import Console

from labcli import endpoints
from labcli.envs import metrics
from labcli.errors import LabError, first_line
from labcli.plugins import registry
from labcli.runs import checkpoints, rundir, space
from labcli.runs.sweep import METRICS as SUMMARY_FIELDS
from labcli.runs.sweep import format_metric

# The figures each report carries (fixed from the first report on: Tune's CSV log keeps the
# columns of the first one). The two metrics are lab's shared TensorBoard tags.
METRICS = {"success": metrics.SUCCESS_RATE, "return": metrics.MEAN_RETURN}
STEPS = "steps"
# Config key of the settings every trial shares (the rest of a trial's config is what it drew).
LAB = "lab"
# How long a stopped trial's actor waits for its run to write its checkpoint and summary. Tune
# kills an actor whose stop takes longer than 10 s when the sweep ends (`TuneController`'s
# `_actor_force_cleanup_timeout`); a cartpole checkpoint takes a fraction of a second.
STOP_WAIT_S = 60.0


def run_name(sweep_name: str, trial_id: str) -> str:
    """The `--run-name` of a trial's lab run: its sweep and Tune's id of it."""
    return f"{sweep_name}_{trial_id}"


def run_of(logs_dir: Path, framework: str, task: str, name: str) -> rundir.Run | None:
    """The newest lab run named `name` (a trial's), or None before it exists."""
    runs = [run for run in rundir.find(logs_dir, task, framework)
            if rundir.run_name(run.dir) == name]
    return runs[0] if runs else None


def drawn(config: Mapping[str, Any]) -> dict[str, Any]:
    """What a trial drew from the space, by key (its config less the shared settings)."""
    return {key: space.plain(value) for key, value in config.items() if key != LAB}


class Reporter:
    """The `on_iteration` hook of a trial's run: each iteration's figures go to Tune, so that
    its scheduler sees them; Tune's stop ends the run as a signal would."""

    def __init__(self, max_iterations: int):
        self.max_iterations = max_iterations
        self.known: dict[str, float] = {}
        self.stopped = False

    def __call__(self, iteration: int, steps: int, figures: Mapping[str, float]) -> bool:
        # An iteration in which no episode ended has no return or success: the last known ones
        # stand (as in the run's summary), NaN before any (ASHA's cut-offs skip NaN).
        self.known.update({name: float(figures[tag]) for name, tag in METRICS.items()
                           if tag in figures})
        report = {name: self.known.get(name, math.nan) for name in METRICS}
        # Tune counts reports from 1 in each actor; a resumed trial's run goes on from its
        # checkpoint's iteration, and its scheduler must see that one.
        report.update({STEPS: steps, "training_iteration": iteration})
        try:
            tune.report(report)
        except SystemExit:  # Tune stops this trial: the run checkpoints and ends first
            self.stopped = True
            # At the last iteration the run has finished anyway (ASHA stops trials at its
            # horizon): it is not an interruption.
            return iteration < self.max_iterations
        return False


def run_trial(config: dict[str, Any]) -> None:
    """One trial: `lab train` with the sweep's fixed settings and what this trial drew, as a
    lab run named after the trial. A trial that Tune restarts (a resumed sweep) goes on from
    its run's last checkpoint."""
    import torch

    from labcli.runs import training

    lab = config[LAB]
    task, framework, logs_dir = lab["task"], lab["framework"], Path(lab["logs_dir"])
    params = drawn(config)
    overrides = [*lab["fixed"], *lab["extra"], *(space.override(k, v) for k, v in params.items())]
    name = run_name(lab["name"], tune.get_context().get_trial_id())
    torch.set_num_threads(lab["torch_threads"])
    reporter = Reporter(lab["iterations"])
    previous = run_of(logs_dir, framework, task, name)
    checkpoint = None
    if previous is not None:
        summary = previous.summary() or {}
        if summary.get("state") == rundir.FINISHED:  # it ended as the sweep stopped: told again
            reporter(summary.get("iterations", 0), summary.get("steps", 0),
                     {METRICS[n]: summary[f] for n, f in SUMMARY_FIELDS.items()
                      if summary.get(f) is not None})
            _end(reporter)
            return
        # Its last complete checkpoint, whatever its summary says (a run whose actor was
        # killed never wrote its end); without one the trial starts a new run.
        if checkpoints.latest_complete(registry.get_framework(framework), previous.dir):
            checkpoint = str(previous.dir)
    command = ["lab", "train", "--task", task, "--framework", framework,
               "--max-iterations", str(lab["iterations"]), "--run-name", name,
               *(arg for item in overrides for arg in ("--set", item))]
    training.train(task, framework, max_iterations=lab["iterations"], run_name=name,
                   overrides=overrides, checkpoint=checkpoint, logs_dir=logs_dir,
                   console=Console(quiet=True), command=command, on_iteration=reporter)
    _end(reporter)


def _end(reporter: Reporter) -> None:
    if reporter.stopped:
        # As Tune's own report would have: the thread ends here, reporting nothing more.
        raise SystemExit(0)


class LabTrial(wrap_function(run_trial)):
    """Tune's function trainable of `run_trial`, whose stop waits for the lab run to end."""

    def cleanup(self) -> None:
        session = get_session()
        if session is not None and session.training_started:
            # Wakes the run's thread with SystemExit in its report (Reporter), and waits.
            session.finish(timeout=STOP_WAIT_S)
        super().cleanup()


def trial_dirname(trial: Any) -> str:
    """The name of a trial's folder in the sweep's dir: Tune's id, as in its run's name (Tune's
    default adds every drawn value)."""
    return trial.trial_id


def trainable(resources: dict[str, float]) -> Any:
    return tune.with_resources(LabTrial, resources)


def settings(task: str, framework: str, *, name: str, logs_dir: Path, fixed: list[str],
             extra: list[str], iterations: int, torch_threads: int) -> dict[str, Any]:
    """The settings every trial shares, as plain data in Tune's config (kept in the sweep's
    state, so a resumed sweep's trials have them)."""
    return {"task": task, "framework": framework, "name": name, "logs_dir": str(logs_dir),
            "fixed": fixed, "extra": extra, "iterations": iterations,
            "torch_threads": torch_threads}


# Ray ---------------------------------------------------------------------------------------


LOCAL = "local"
MIN_OBJECT_STORE = 80 * 2**20  # Ray refuses less than 75 MiB
ANSWER_TIMEOUT_S = 10.0  # a cluster's head that does not accept a connection in this long


def start(address: str | None, cores: int) -> bool:
    """Join the cluster at `address`, or start a local Ray on `cores` cores: no dashboard, and
    the trials' output kept in Ray's logs rather than mixed into the sweep's. Returns whether
    Ray was started here (and is to be shut down here)."""
    if ray.is_initialized():
        return False
    if address not in (None, "auto", LOCAL):
        # Ray's client retries an address where nothing listens for minutes (822 s measured).
        host, port = endpoints.parse(address.removeprefix("ray://"), "--address",
                                     "ray://HOST:10001")
        endpoints.check_answers(host, port, ANSWER_TIMEOUT_S, f"cannot join Ray at {address}",
                                "check --address: the cluster's head as ray://HOST:10001 for Ray "
                                "Client or HOST:6379 for its GCS")
    options: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                               "logging_level": logging.ERROR}
    if address is None:
        # "local": a Ray of this sweep's own. Left to itself, ray.init joins whatever cluster
        # RAY_ADDRESS or Ray's last `ray start` on this machine names, another user's or one
        # long gone.
        options["num_cpus"] = cores
        options.update(_object_store_under_limit())
    try:
        ray.init(address=address or LOCAL, **options)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise LabError(f"cannot {'join Ray at ' + address if address else 'start Ray'}: "
                       f"{first_line(exc)}",
                       "check --address (ray://HOST:10001 or HOST:6379), that the cluster runs "
                       "the same Ray, and RAY_AUTH_MODE=token where it asks for a token"
                       if address else "see Ray's logs in /tmp/ray") from None
    return True


def _object_store_under_limit() -> dict[str, int]:
    """Under a limit on each process's address space (`ulimit -v`), an object store that fits:
    Ray's default (30% of the memory) maps more than the limit in its raylet, which then dies
    while the driver waits for it forever. The sweep's trials pass Ray only small results."""
    try:
        import resource
    except ImportError:  # Windows: no such limit
        return {}
    limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    if limit == resource.RLIM_INFINITY:
        return {}
    store = limit // 8
    if store < MIN_OBJECT_STORE:
        raise LabError(f"Ray cannot start under this address-space limit (ulimit -v "
                       f"{limit // 1024} KiB): its object store needs {MIN_OBJECT_STORE // 2**20} "
                       "MiB and its processes several times more",
                       "raise it (ulimit -v unlimited), or join a cluster with --address")
    return {"object_store_memory": store}


def stop(started: bool) -> None:
    if started:
        ray.shutdown()


def resources() -> dict[str, float]:
    """What the cluster has: {"CPU": ..., "GPU": ...}."""
    return dict(ray.cluster_resources())


# Tuner -------------------------------------------------------------------------------------

SEARCH_SEED = 0  # a sweep draws the same samples each time it is started with the same space


def distributions(drawn_space: Mapping[str, space.Distribution]) -> dict[str, Any]:
    """Tune's sampler for each distribution of the space."""
    out = {}
    for key, dist in drawn_space.items():
        if dist.kind == space.CHOICE:
            out[key] = tune.choice(list(dist.values))
        elif dist.kind == space.RANDINT:
            low, high = dist.values
            out[key] = tune.randint(low, high + 1)  # Tune's upper end is excluded; lab's is not
        elif dist.kind == space.LOGUNIFORM:
            out[key] = tune.loguniform(*dist.values)
        else:
            out[key] = tune.uniform(*dist.values)
    return out


def make_tuner(sweep_dir: Path, *, param_space: dict[str, Any], samples: int, metric: str,
               scheduler: str, search: str, iterations: int, max_concurrent: int,
               trial_resources: dict[str, float], progress: Progress) -> tune.Tuner:
    if scheduler == "asha":
        # Rungs at grace × 3^k iterations: a trial is cut when it is below the best third of
        # the trials that reached the same rung.
        chosen = tune.schedulers.ASHAScheduler(
            time_attr="training_iteration", max_t=iterations,
            grace_period=max(1, iterations // 10), reduction_factor=3)
    else:
        chosen = tune.schedulers.FIFOScheduler()
    if search == "optuna":
        from ray.tune.search.optuna import OptunaSearch

        searcher = OptunaSearch(seed=SEARCH_SEED)
    else:
        from ray.tune.search import BasicVariantGenerator

        searcher = BasicVariantGenerator(random_state=SEARCH_SEED)
    return tune.Tuner(
        trainable(trial_resources), param_space=param_space,
        tune_config=tune.TuneConfig(
            metric=metric, mode="max", num_samples=samples, scheduler=chosen,
            search_alg=searcher, max_concurrent_trials=max_concurrent, reuse_actors=False,
            trial_dirname_creator=trial_dirname),
        run_config=tune.RunConfig(name=sweep_dir.name, storage_path=str(sweep_dir.parent),
                                  verbose=0, callbacks=[progress]))


NEW_OUTPUT = "RAY_AIR_NEW_OUTPUT"
# Where Tune logs a failed trial with its traceback, and the trials that did not complete.
TUNE_LOGGERS = ("ray.tune.execution.tune_controller", "ray.tune.tune")


def fit(tuner: tune.Tuner) -> None:
    """Run the sweep, Tune's own output left out: the sweep prints its progress (Progress) and
    its table, with each failed trial's error. Tune's newer output engine prints its header
    whatever the verbosity; the older one at verbosity 0 prints nothing."""
    previous = os.environ.get(NEW_OUTPUT)
    os.environ[NEW_OUTPUT] = "0"
    quiet = _SaidInTheTable()
    loggers = [logging.getLogger(name) for name in TUNE_LOGGERS]
    for logger in loggers:
        logger.addFilter(quiet)
    try:
        with warnings.catch_warnings():
            # A trial reports NaN until one of its episodes ends (Reporter); ASHA's cut-off
            # skips NaN, and numpy warns when a rung holds nothing else.
            warnings.filterwarnings("ignore", "All-NaN slice encountered", RuntimeWarning)
            tuner.fit()
    finally:
        for logger in loggers:
            logger.removeFilter(quiet)
        if previous is None:
            os.environ.pop(NEW_OUTPUT, None)
        else:
            os.environ[NEW_OUTPUT] = previous



class _SaidInTheTable(logging.Filter):
    """Drops Tune's traceback of a trial that failed on a LabError (Ray re-raises it as a
    subclass of it) and its list of unfinished trials: the results table says both in one line
    each. Any other failure, a bug, keeps its traceback."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.exc_info and isinstance(record.exc_info[1], LabError):
            return False
        return not record.getMessage().startswith("Trials did not complete")


def can_restore(sweep_dir: Path) -> bool:
    return tune.Tuner.can_restore(str(sweep_dir))


def restore_tuner(sweep_dir: Path, trial_resources: dict[str, float]) -> tune.Tuner:
    """The sweep's Tuner as Tune saved it, to go on with its unfinished trials (from their
    runs' checkpoints: `run_trial`) and the samples it had not started."""
    try:
        return tune.Tuner.restore(str(sweep_dir), trainable(trial_resources),
                                  resume_unfinished=True, resume_errored=False)
    except Exception as exc:  # Ray's own errors of a state it cannot read, of many kinds
        raise LabError(f"{sweep_dir}'s Ray Tune state cannot be restored: {first_line(exc)}",
                       "start the sweep again under a new --name") from None


@dataclass
class TrialState:
    trial_id: str
    config: dict[str, Any]
    status: str  # Tune's: PENDING, RUNNING, PAUSED, TERMINATED, ERROR
    error: str | None = None

    @property
    def unfinished(self) -> bool:
        return self.status not in ("TERMINATED", "ERROR")


def trial_states(sweep_dir: Path) -> list[TrialState]:
    """The sweep's trials as Tune last saved them: after a Ctrl-C, those it will resume are
    still PENDING or RUNNING."""
    analysis = tune.ExperimentAnalysis(str(sweep_dir))
    return [TrialState(t.trial_id, dict(t.config), str(t.status), _error_of(t))
            for t in analysis.trials]


def _error_of(trial: Any) -> str | None:
    """The last line of a failed trial's traceback (Tune's error.txt in its folder): a
    LabError's message, or another exception's name and message."""
    path = getattr(trial, "error_file", None)
    if not path or not Path(path).is_file():
        return None
    lines = [line.strip() for line in Path(path).read_text(errors="replace").splitlines()
             if line.strip()]
    if not lines:
        return None
    name, _, message = lines[-1].partition(": ")
    return message if name.startswith("labcli.errors.") and message else lines[-1]


class Progress(tune.Callback):
    """The sweep's progress in the driver: a rich bar of trials ended on a terminal, a line per
    ended trial elsewhere. Tune saves its callbacks with the sweep (tuner.pkl): the console and
    bar are made where it runs, never saved."""

    def __init__(self, total: int, metric: str):
        self.total = total
        self.metric = metric
        self._console: Console | None = None
        self._bar: Any = None
        self._task: Any = None
        self._ended: set[str] = set()
        self._best: float | None = None

    def __getstate__(self) -> dict[str, Any]:
        return {"total": self.total, "metric": self.metric}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["total"], state["metric"])

    def setup(self, **info: Any) -> None:
        from rich import progress as bars

        self._console = Console(stderr=True, markup=False)
        if self._console.is_terminal:
            self._bar = bars.Progress(
                bars.TextColumn("trials"), bars.BarColumn(), bars.MofNCompleteColumn(),
                bars.TextColumn("{task.fields[best]}"), bars.TimeElapsedColumn(),
                console=self._console)
            self._bar.start()
            self._task = self._bar.add_task("trials", total=self.total, best="")

    def on_step_end(self, iteration: int, trials: list, **info: Any) -> None:
        # Counted from Tune's states: a resumed sweep's earlier trials count too.
        self._ended = {t.trial_id for t in trials if t.status in ("TERMINATED", "ERROR")}
        self._update()

    def on_trial_result(self, iteration: int, trials: list, trial: Any, result: dict,
                        **info: Any) -> None:
        value = result.get(self.metric)
        if isinstance(value, (int, float)) and math.isfinite(value):
            self._best = value if self._best is None else max(self._best, value)

    def on_trial_complete(self, iteration: int, trials: list, trial: Any, **info: Any) -> None:
        self._say(trial, "ended")

    def on_trial_error(self, iteration: int, trials: list, trial: Any, **info: Any) -> None:
        self._say(trial, "failed")

    def on_experiment_end(self, trials: list, **info: Any) -> None:
        if self._bar is not None:
            self._bar.stop()
            self._bar = None

    def _say(self, trial: Any, how: str) -> None:
        """A line per ended trial where there is no bar (a log, CI)."""
        if self._bar is not None or self._console is None:
            return
        result = trial.last_result or {}
        value = result.get(self.metric)
        shown = "" if value is None else f", {self.metric} {format_metric(self.metric, value)}"
        self._console.print(f"  trial {trial.trial_id} {how} at iteration "
                            f"{result.get('training_iteration', 0)}{shown}", highlight=False)

    def _update(self) -> None:
        if self._bar is not None:
            best = "" if self._best is None else \
                f"best {self.metric} {format_metric(self.metric, self._best)}"
            self._bar.update(self._task, completed=len(self._ended), best=best)
