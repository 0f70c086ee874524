"""`lab sweep` as a library call: a hyperparameter sweep of `lab train` runs on Ray Tune.

Everything is checked before Ray starts: the task, framework and fixed --set values as
`lab train` checks them, and every value the space can draw (`space.py`). A sweep's dir,
<logs>/sweeps/<name>/, holds what it was asked (sweep.yaml, space.yaml), Ray Tune's state (what
`--resume` restores) with a folder per trial, and at the end results.json and best.yaml; each
trial is a lab run dir under <logs>/<framework>/<task>/, as `lab train` makes them. Ray is
imported only once it is known to be installed (`labcli/runs/tuning.py`)."""

from __future__ import annotations

import contextlib
import json
import math
import signal
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.console import Console

from labcli import files
from labcli.envs.cores import cores
from labcli.errors import Interrupted, LabError
from labcli.runs import config, interrupt, rundir, space, sweep_state
from labcli.runs.plan import gpu_scale, plan

if TYPE_CHECKING:
    from labcli.runs.tuning import TrialState

SWEEPS = "sweeps"  # <logs>/sweeps/<name>/
SETTINGS, SPACE, RESULTS, BEST = "sweep.yaml", "space.yaml", "results.json", "best.yaml"
# lab's own files in a sweep dir, read as YAML or JSON data; the rest is Ray Tune's, signed.
OWN = frozenset({SETTINGS, SPACE, RESULTS, BEST})
# --metric: the figure each trial reports and the sweep maximizes, and where a run's summary
# keeps it.
METRICS = {"success": "success_rate", "return": "mean_return"}
SCHEDULERS = ("asha", "none")
SEARCHES = ("random", "optuna")
INSTALL = 'pip install "lab[sweep]", or pip install -e ".[sweep]" in a checkout'
# A trial that its scheduler stopped early: its run ended as Ctrl-C ends one (state
# 'interrupted', checkpointed, resumable with `lab train --checkpoint`), but the sweep is done
# with it.
STOPPED = "stopped"
PENDING = "pending"  # a trial that had not started when the sweep was interrupted
NAME_LIMIT = 60  # a sweep's name is part of its trials' run names, themselves at most 100


def require_ray(search: str = "random") -> None:
    """Ray Tune (and Optuna for --search optuna) are an optional extra: one line saying how to
    install them when they are missing."""
    try:
        import ray.tune  # noqa: F401
    except ImportError:
        raise LabError("lab sweep needs Ray Tune, which is not installed",
                       f"install it: {INSTALL}") from None
    if search == "optuna":
        try:
            import optuna  # noqa: F401
        except ImportError:
            raise LabError("--search optuna needs Optuna, which is not installed",
                           f"install it: {INSTALL}") from None


@dataclass
class SweepSpec:
    """What a sweep was asked, kept as sweep.yaml in its dir: `--resume` reads it back."""

    task: str
    framework: str
    space: dict[str, Any]  # the space file's mapping, as written
    samples: int
    metric: str
    scheduler: str
    search: str
    fixed: list[str]  # --set
    iterations: int  # each trial's, resolved (--iterations, or the framework's default)
    name: str
    logs_dir: str  # absolute: the trials write their runs there from Tune's own folders
    max_concurrent: int | None = None  # as asked; None: as many as the resources allow

    def to_yaml(self) -> str:
        return space.to_yaml(asdict(self))

    @classmethod
    def load(cls, sweep_dir: Path) -> SweepSpec:
        path = sweep_dir / SETTINGS
        if not path.is_file():
            raise LabError(f"{sweep_dir} is not a lab sweep: it has no {SETTINGS}",
                           f"pass a dir made by `lab sweep`, <logs>/{SWEEPS}/<name>")
        try:
            data = files.load_yaml(files.read_text(path))
            spec = cls(**data)
            spec.check()
        except (files.Unreadable, TypeError, LabError) as exc:
            raise LabError(f"{path} is damaged: {getattr(exc, 'message', exc)}",
                           "restore it, or start a new sweep") from None
        return spec

    def check(self) -> None:
        """What `lab sweep` checks of its options, for a sweep.yaml read back."""
        kinds = {"task": str, "framework": str, "space": dict, "samples": int, "metric": str,
                 "scheduler": str, "search": str, "fixed": list, "iterations": int, "name": str,
                 "logs_dir": str, "max_concurrent": (int, type(None))}
        for key, kind in kinds.items():
            value = getattr(self, key)
            if not isinstance(value, kind) or isinstance(value, bool):
                raise TypeError(f"{key} is {value!r}, not of the kind lab wrote")
        if not all(isinstance(item, str) for item in self.fixed):
            raise TypeError(f"fixed is {self.fixed!r}, not a list of KEY=VALUE strings")
        _check_options(self.samples, self.metric, self.scheduler, self.search,
                       self.max_concurrent, self.iterations)
        _check_name(self.name)


def format_metric(metric: str, value: float | None) -> str:
    if value is None or not math.isfinite(value):
        return "-"
    return f"{value:.0%}" if metric == "success" else f"{value:.1f}"


@dataclass
class TrialRow:
    """One line of the results table: what a trial drew, how its run ended."""

    trial_id: str
    params: dict[str, Any]
    metric: float | None
    iterations: int | None
    state: str
    run_dir: Path | None = None
    error: str | None = None
    # Both figures of its run's summary, by --metric name: the other one breaks ties (trials
    # that all reach a success of 100% are told apart by their return).
    figures: dict[str, float | None] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {**self.__dict__, "run_dir": str(self.run_dir) if self.run_dir else None}


@dataclass
class SweepOutcome:
    dir: Path
    spec: SweepSpec
    rows: list[TrialRow]  # best first
    interrupted: bool = False
    signum: int = signal.SIGINT
    best_file: Path | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def best(self) -> TrialRow | None:
        return self.rows[0] if self.rows and self.rows[0].metric is not None else None


def sweep(task: str, framework: str, space_file: Path, *, samples: int,
          metric: str = "success", scheduler: str = "asha", search: str = "random",
          max_concurrent: int | None = None, address: str | None = None,
          overrides: Sequence[str] = (), iterations: int | None = None, name: str | None = None,
          logs_dir: Path | None = None, console: Console | None = None) -> SweepOutcome:
    """Run `samples` trials of `lab train --task task --framework framework` with `overrides`
    and values drawn from `space_file`, on Ray Tune, and rank them by `metric`."""
    console = console or Console(stderr=True)
    _check_options(samples, metric, scheduler, search, max_concurrent, iterations)
    # Absolute: Tune runs each trial in a folder of its own.
    logs_dir = (logs_dir or rundir.default_logs_dir()).absolute()
    name = name or rundir.stamp()
    _check_name(name)
    fixed = list(overrides)
    the_plan = plan(task, framework, overrides=fixed, max_iterations=iterations,
                    logs_dir=logs_dir)
    gpu = gpu_scale(None, None)
    drawn = space.load(space_file)
    space.check(drawn, the_plan.spec, the_plan.framework, fixed,
                max_iterations=the_plan.agent_cfg.max_iterations, gpu_scale=gpu,
                where=str(space_file), scalar_choices=search == "optuna")
    sweep_dir = logs_dir / SWEEPS / name
    exists = LabError(f"sweep {sweep_dir} exists",
                      f"continue it with lab sweep --resume {sweep_dir}, or pick another --name")
    if sweep_dir.exists():
        raise exists
    rundir.check_writable(sweep_dir.parent)
    require_ray(search)  # after the input's checks: those need no Ray
    sweep_state.key()  # the key that signs its state when it stops: a problem with it, now
    spec = SweepSpec(task=the_plan.spec.name, framework=the_plan.framework.name,
                     space=files.load_yaml(files.read_text(space_file)), samples=samples,
                     metric=metric, scheduler=scheduler, search=search, fixed=fixed,
                     iterations=the_plan.agent_cfg.max_iterations, name=name,
                     logs_dir=str(logs_dir), max_concurrent=max_concurrent)
    top = sweep_dir  # the highest directory made for the sweep, removed if it writes nothing
    while not top.parent.exists():
        top = top.parent
    files.user_dir(sweep_dir.parent)
    try:  # made here and nowhere else: of two sweeps of one name, the second stops here
        sweep_dir.mkdir(mode=files.DIR_MODE)
    except FileExistsError:
        raise exists from None
    except OSError as exc:
        raise files.unwritable(sweep_dir, exc) from exc
    try:
        with _holding(sweep_dir):
            return _run(spec, sweep_dir, drawn, gpu, address, console, restore=False)
    finally:
        if not any(sweep_dir.iterdir()):  # stopped before it wrote anything
            for made in (sweep_dir, *sweep_dir.parents[:len(sweep_dir.relative_to(top).parts)]):
                with contextlib.suppress(OSError):
                    made.rmdir()


def resume(sweep_dir: Path, *, address: str | None = None,
           console: Console | None = None) -> SweepOutcome:
    """Go on with an interrupted sweep: its unfinished trials from their runs' checkpoints,
    then the samples it had not started."""
    console = console or Console(stderr=True)
    sweep_dir = sweep_dir.absolute()
    spec = SweepSpec.load(sweep_dir)
    require_ray(spec.search)
    from labcli.runs import tuning

    with _holding(sweep_dir):
        if not tuning.can_restore(sweep_dir):
            raise LabError(f"{sweep_dir} holds no Ray Tune state to resume",
                           "it was stopped before its first trial started: start it again")
        sweep_state.verify(sweep_dir, OWN)  # before Ray unpickles any of it
        # The task and framework must still be there, and the fixed settings still valid.
        plan(spec.task, spec.framework, overrides=spec.fixed, max_iterations=spec.iterations,
             logs_dir=Path(spec.logs_dir))
        drawn = space.parse(spec.space, str(sweep_dir / SPACE))
        return _run(spec, sweep_dir, drawn, gpu_scale(None, None), address, console,
                    restore=True)


def _holding(sweep_dir: Path):
    """One driver at a time in a sweep dir: a second `lab sweep --resume` while one runs would
    have Ray Tune write the same state twice."""
    return rundir.holding(sweep_dir, lambda: LabError(
        f"sweep {sweep_dir} is being run by another lab sweep",
        "wait for it to end, or stop it (Ctrl-C) and resume it then"))


def _check_options(samples: int, metric: str, scheduler: str, search: str,
                   max_concurrent: int | None, iterations: int | None) -> None:
    if samples <= 0:
        raise LabError(f"--samples must be a positive integer, got {samples}")
    for option, value, known in (("--metric", metric, METRICS), ("--scheduler", scheduler,
                                 SCHEDULERS), ("--search", search, SEARCHES)):
        if value not in known:
            raise LabError(f"{option} '{value}' is not one of {', '.join(known)}")
    if max_concurrent is not None and max_concurrent <= 0:
        raise LabError(f"--max-concurrent must be a positive integer, got {max_concurrent}")
    if iterations is not None and iterations <= 0:
        raise LabError(f"--iterations must be a positive integer, got {iterations}")


def _check_name(name: str) -> None:
    if not rundir.RUN_NAME.fullmatch(name) or len(name) > NAME_LIMIT:
        raise LabError(f"--name {name[:NAME_LIMIT]!r} is not a plain name",
                       f"use at most {NAME_LIMIT} letters, digits and punctuation other than "
                       "/ \\ :, no spaces, not starting with . or -")


@dataclass
class TrialFit:
    """How trials share the cluster: Ray's resources for each, how many run at once, and the
    settings that size a trial to them."""

    resources: dict[str, float]
    concurrent: int
    extra: list[str]  # --set the sweep adds (env.threads)
    torch_threads: int

    def describe(self) -> str:
        each = ", ".join(f"{value:g} {key.upper()}" for key, value in self.resources.items())
        trials = "1 trial" if self.concurrent == 1 else f"{self.concurrent} trials"
        return f"{trials} at a time, each on {each}"


def fit_trials(cluster: dict[str, float], gpu: bool, fixed: Sequence[str],
               max_concurrent: int | None) -> TrialFit:
    """On GPUs, one trial a GPU. On CPUs, each trial's physics and torch threads fit the cores
    it is given: one each by default (cartpole's 64-128 envs gain nothing from a second on a
    shared machine), cores // --max-concurrent when that is asked, env.threads when fixed."""
    if gpu:
        gpus = int(cluster.get("GPU", 0))
        if gpus < 1:
            raise LabError("the trials would step on the GPU (the warp backend is the default "
                           "here), but Ray sees no GPU", "check the cluster's GPUs")
        return TrialFit({"cpu": 1, "gpu": 1}, max_concurrent or gpus, [], 1)
    cores = max(1, int(cluster.get("CPU", 1)))
    fixed_threads = config.parse_set(fixed)["env"].get("threads")
    if isinstance(fixed_threads, int) and not isinstance(fixed_threads, bool):
        threads = fixed_threads
        if threads > cores:
            raise LabError(f"env.threads={threads} asks more cores a trial than the {cores} "
                           "Ray has", f"use at most {cores}")
    else:
        fixed_threads = None
        threads = max(1, cores // max_concurrent) if max_concurrent else 1
    extra = [] if fixed_threads else [f"env.threads={threads}"]
    return TrialFit({"cpu": threads}, max_concurrent or max(1, cores // threads), extra, threads)


@contextmanager
def _sigterm_as_sigint(stop: interrupt.StopRequest) -> Iterator[None]:
    """Tune stops a sweep cleanly on SIGINT only (its handler saves the sweep's state with its
    running trials as unfinished); SIGTERM does the same here."""
    def handler(signum: int, frame: Any) -> None:
        stop.request(signum)
        current = signal.getsignal(signal.SIGINT)
        if callable(current):
            current(signal.SIGINT, frame)

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _run(spec: SweepSpec, sweep_dir: Path, drawn: space.Space, gpu: bool, address: str | None,
         console: Console, *, restore: bool) -> SweepOutcome:
    what = "resume" if restore else "sweep"
    console.print(f"{what} {spec.task} with {spec.framework}: {spec.samples} trials of "
                  f"{spec.iterations} iterations over {', '.join(drawn)}, {spec.search} "
                  f"search, {spec.scheduler} scheduler, best {spec.metric}; {sweep_dir}",
                  highlight=False, soft_wrap=True)
    with interrupt.deferred(interrupt.StopRequest(interrupt.startup.signum)) as stop:
        from labcli.runs import tuning

        started = tuning.start(address, cores())
        try:
            fit = fit_trials(tuning.resources(), gpu, spec.fixed, spec.max_concurrent)
            console.print(fit.describe(), highlight=False)
            if stop.requested:
                raise Interrupted(f"interrupted by {stop.name} before the sweep started"
                                  f"{'' if restore else '; nothing was written'}",
                                  stop.exit_code)
            if restore:
                tuner = tuning.restore_tuner(sweep_dir, fit.resources)
            else:
                files.user_dir(sweep_dir)
                files.write_atomic(sweep_dir / SETTINGS, spec.to_yaml())
                files.write_atomic(sweep_dir / SPACE, space.to_yaml(spec.space))
                settings = tuning.settings(
                    spec.task, spec.framework, name=spec.name, logs_dir=Path(spec.logs_dir),
                    fixed=spec.fixed, extra=fit.extra, iterations=spec.iterations,
                    torch_threads=fit.torch_threads)
                tuner = tuning.make_tuner(
                    sweep_dir, param_space={**tuning.distributions(drawn),
                                            tuning.LAB: settings},
                    samples=spec.samples, metric=spec.metric, scheduler=spec.scheduler,
                    search=spec.search, iterations=spec.iterations,
                    max_concurrent=fit.concurrent, trial_resources=fit.resources,
                    progress=tuning.Progress(spec.samples, spec.metric))
            with _sigterm_as_sigint(stop):
                tuning.fit(tuner)
            states = tuning.trial_states(sweep_dir)
        finally:
            tuning.stop(started)
            if (sweep_dir / SETTINGS).is_file():  # Ray has stopped writing: sign what it left
                sweep_state.sign(sweep_dir, OWN)
    outcome = SweepOutcome(sweep_dir, spec, rows(spec, states))
    outcome.interrupted = len(states) < spec.samples or any(s.unfinished for s in states)
    outcome.signum = stop.signum or signal.SIGINT
    _write_results(outcome)
    return outcome


def rows(spec: SweepSpec, states: list[TrialState]) -> list[TrialRow]:
    """A row per trial, from its lab run (the figures, state and error it recorded), best
    first by the sweep's metric."""
    from labcli.runs import tuning

    out = []
    for state in states:
        run = tuning.run_of(Path(spec.logs_dir), spec.framework, spec.task,
                            tuning.run_name(spec.name, state.trial_id))
        row = TrialRow(state.trial_id, tuning.drawn(state.config), None, None,
                       PENDING if state.unfinished else rundir.FAILED, error=state.error)
        if run is not None:
            row.run_dir = run.dir
            try:
                summary = run.summary() or {}
                row.state = rundir.run_state(run)
            except LabError as exc:
                summary, row.state, row.error = {}, rundir.DAMAGED, exc.message
            row.figures = {name: _finite(summary.get(key)) for name, key in METRICS.items()}
            row.metric = row.figures[spec.metric]
            row.iterations = summary.get("iterations")
            row.error = summary.get("error") or row.error
            if row.state == rundir.INTERRUPTED and not state.unfinished:
                row.state = STOPPED
        out.append(row)
    other = next(name for name in METRICS if name != spec.metric)
    return sorted(out, key=lambda r: (r.metric is None, -(r.metric or 0.0),
                                      r.figures.get(other) is None,
                                      -(r.figures.get(other) or 0.0), r.trial_id))


def _finite(value: Any) -> float | None:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    return float(value) if ok else None


def best_config(spec: SweepSpec, best: TrialRow) -> dict[str, dict[str, Any]]:
    """The config file that `lab train --config` reproduces the best trial with: the fixed
    --set values, the trials' length and what it drew, in env and agent sections."""
    items = [*spec.fixed, f"agent.max_iterations={spec.iterations}",
             *(space.override(key, value) for key, value in best.params.items())]
    return space.as_config(items)


def _write_results(outcome: SweepOutcome) -> None:
    spec, sweep_dir = outcome.spec, outcome.dir
    results = {"name": spec.name, "task": spec.task, "framework": spec.framework,
               "metric": spec.metric, "samples": spec.samples,
               "interrupted": outcome.interrupted,
               "trials": [row.as_dict() for row in outcome.rows]}
    files.write_atomic(sweep_dir / RESULTS, json.dumps(results, indent=2) + "\n",
                       below=sweep_dir)
    best = outcome.best
    if best is None:
        outcome.notes.append(f"no trial reported a {spec.metric}: no {BEST} written")
        return
    figures = ", ".join(f"{name} {format_metric(name, value)}"
                        for name, value in best.figures.items())
    header = (f"# lab sweep {spec.name}: the best of {len(outcome.rows)} trials by "
              f"{spec.metric} ({figures}), trial {best.trial_id}, run {best.run_dir}\n"
              f"# lab train --task {spec.task} --framework {spec.framework} --config "
              f"{sweep_dir / BEST}\n")
    outcome.best_file = sweep_dir / BEST
    files.write_atomic(outcome.best_file, header + space.to_yaml(best_config(spec, best)),
                       below=sweep_dir)
