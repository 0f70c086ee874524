"""`lab play` as a library call: load a run's policy and roll it out deterministically."""

from __future__ import annotations

import enum
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from rich.console import Console

from labcli import files
from labcli.envs import metrics
from labcli.envs.make import make_env
from labcli.envs.render.video import VideoRecorder
from labcli.envs.render.viewer import Viewer, check_display
from labcli.errors import LabError
from labcli.plugins import registry
from labcli.plugins.framework import Checkpoint, Framework
from labcli.plugins.policy import Policy
from labcli.runs import checkpoints, config, loading, recorded, rundir
from labcli.runs import video as videos
from labcli.runs.video import VideoSettings

TIME_OUT = "time_out"
CPU = "cpu"  # play steps on the CPU, whatever the run trained on
SANITY = "sanity"  # <logs>/sanity/<task>/<time>_<agent>/ holds sanity agents' videos


class Agent(str, enum.Enum):
    """Policies that need no training, to check a task before training it."""

    zero = "zero"
    random = "random"


@dataclass
class LoadedPolicy:
    run: rundir.Run
    spec: Any  # a TaskSpec, or the spec of a gym: task
    framework: Framework
    checkpoint: Checkpoint
    env: Any  # the task's env, on the CPU
    policy: Policy


def load(*, run_dir: Path | None = None, checkpoint: Path | None = None,
         task: str | None = None, framework: str | None = None, logs_dir: Path | None = None,
         num_envs: int | None = None, seed: int = 0,
         overrides: Sequence[str] = ()) -> LoadedPolicy:
    """Find the run (a checkpoint's, `run_dir`, or the newest matching one), rebuild its env
    on the CPU from params/env.yaml and the model it recorded, and load the checkpoint as a
    Policy. The task's `play_overrides` (e.g. observation noise off) apply, and `overrides`
    may set those keys only, and the settings with which params/env.yaml names a file (which
    lab opens only when the user names it this time, `config.check_saved`)."""
    if num_envs is not None and num_envs <= 0:
        raise LabError(f"--num-envs must be a positive integer, got {num_envs}")
    logs_dir = logs_dir or rundir.default_logs_dir()
    # `latest` or `best`: of --run's run, else of the newest run.
    word = str(checkpoint) if str(checkpoint) in (checkpoints.LATEST, checkpoints.BEST) else None
    if checkpoint is not None and word is None:
        run = rundir.open_run(checkpoint.parent if checkpoint.is_file() else checkpoint)
    elif run_dir is not None:
        run = rundir.open_run(run_dir)
    else:
        run = rundir.latest(logs_dir, task, framework)
    task_name, framework_name = run.identity()
    # The model the run trained on, whatever the task names now.
    spec, warning = recorded.spec_of(run, registry.get_task(task_name))
    if warning is not None:
        Console(stderr=True, markup=False).print(f"warning: {warning}", highlight=False,
                                                 soft_wrap=True)
    fw_spec = registry.get_framework(framework_name)
    if word is not None:
        ckpt = checkpoints.pick(word, run, fw_spec)
    else:
        _, ckpt = checkpoints.find(str(checkpoint or run.dir), logs_dir, spec.name, fw_spec)
    saved = run.params(rundir.ENV_PARAMS)
    given = _play_settings(spec, overrides, saved)
    config.check_saved(spec.config_class, "env", run.dir / rundir.ENV_PARAMS, saved, [given])
    layers = [saved, dict(spec.config_class.play_overrides), given]
    if num_envs is not None:
        layers.append({"num_envs": num_envs})
    env_cfg = config.build(spec.config_class, "env", layers)
    agent_cfg = checkpoints.agent_config(fw_spec, run)
    fw = fw_spec.load()
    env = make_env(spec, env_cfg, backend=CPU, device="cpu", seed=seed)
    try:
        policy = loading.policy_of(fw, ckpt, env, agent_cfg)
    except BaseException:
        env.close()
        raise
    return LoadedPolicy(run, spec, fw, ckpt, env, policy)


def _play_settings(spec: Any, overrides: Sequence[str],
                   saved: Mapping[str, Any]) -> dict[str, Any]:
    """`--set` for a run: only what a task lets play change (its `play_overrides` keys and
    `play_settable` paths), and a setting with which the run's `saved` env settings name a
    file: the user's file instead."""
    layers = config.parse_set(overrides)
    allowed = set(spec.config_class.play_overrides)
    paths = [tuple(key.split(".")) for key in sorted(getattr(spec.config_class,
                                                              "play_settable", ()))]
    files = [keys for keys, _ in config.named_files(saved)]
    wrong = [f"agent.{k}" for k in layers["agent"]] + [
        "env." + ".".join(map(str, keys)) for keys in _leaves(layers["env"])
        if keys[0] not in allowed and not any(_within(keys, path) for path in paths)
        and not any(keys == named[:len(keys)] for named in files)]
    if wrong:
        settable = [f"env.{k}" for k in sorted(allowed)] + [
            "env." + ".".join(path) for path in paths] + [
            "env." + ".".join(map(str, config.settable(keys))) for keys in files]
        raise LabError(f"--set {wrong[0]} cannot change a run that plays with its own params",
                       f"a run of task '{spec.name}' may set: "
                       f"{', '.join(dict.fromkeys(settable)) or 'nothing'}")
    return layers["env"]


def _within(keys: tuple, path: tuple[str, ...]) -> bool:
    """Whether `keys` name `path` or a key under it; "*" in `path` stands for any one key."""
    return len(keys) >= len(path) and all(p in ("*", k) for k, p in zip(keys[:len(path)], path,
                                                                       strict=True))


def _leaves(tree: Mapping[str, Any], keys: tuple = ()) -> list[tuple]:
    """The keys of every value set in `tree` (nested mappings, as `--set` makes them)."""
    out: list[tuple] = []
    for key, value in tree.items():
        if isinstance(value, Mapping) and value:
            out += _leaves(value, (*keys, key))
        else:
            out.append((*keys, key))
    return out


@dataclass
class Episodes:
    returns: list[float] = field(default_factory=list)
    lengths: list[int] = field(default_factory=list)
    successes: list[bool] = field(default_factory=list)
    causes: list[str] = field(default_factory=list)
    videos: list[Path] = field(default_factory=list)
    # The task's episode metrics (`Metrics/<term>/<key>` without the prefix), means over every
    # episode that ended in the rollout: `ended` of them, a few more than the episodes above
    # where envs end episodes of different lengths.
    task_metrics: dict[str, float] = field(default_factory=dict)
    ended: int = 0

    @property
    def success_rate(self) -> float:
        return sum(self.successes) / len(self.successes) if self.successes else 0.0

    @property
    def mean_return(self) -> float:
        return statistics.fmean(self.returns) if self.returns else float("nan")


def rollout(env: Any, act, episodes: int, seed: int = 0) -> Episodes:
    """Step `env` with `act(obs) -> actions` until `episodes` episodes have ended (or a viewer
    in front of it is closed). Each env contributes its episodes in order, so with num_envs >=
    episodes none favours short ones."""
    out = Episodes()
    obs, _ = env.reset(seed=seed)
    env.pop_stats()  # from this reset on
    names = env.termination_names
    taken = torch.zeros(env.num_envs, dtype=torch.long)
    per_env = -(-episodes // env.num_envs)  # ceil: the fewest episodes each env must give
    while len(out.returns) < episodes and getattr(env, "running", True):
        with torch.inference_mode():
            obs, _, terminated, truncated, info = env.step(act(obs))
        done = (terminated | truncated).cpu()
        if not done.any():
            continue
        ep = info["lab_episode"]
        causes = info["terminations"].cpu()
        for i in done.nonzero().flatten().tolist():
            if taken[i] >= per_env or len(out.returns) >= episodes:
                continue
            taken[i] += 1
            out.returns.append(float(ep["r"][i]))
            out.lengths.append(int(ep["l"][i]))
            out.successes.append(bool(ep["success"][i]))
            hit = causes[i].nonzero().flatten().tolist()
            out.causes.append(names[hit[0]] if hit else TIME_OUT)
    stats = env.pop_stats()
    out.ended = int(stats.get(metrics.EPISODES, 0))
    out.task_metrics = {tag.removeprefix(metrics.TASK_METRIC): value
                        for tag, value in stats.items()
                        if tag.startswith(metrics.TASK_METRIC) and tag != metrics.SUCCESS_RATE}
    return out


@dataclass(frozen=True)
class Show:
    """How to look at a rollout: an mp4 of env 0 (`video`), MuJoCo's viewer, or neither."""

    video: VideoSettings | None = None
    viewer: bool = False

    def __post_init__(self) -> None:
        if self.viewer:
            check_display()  # before any env is built


def _rollout_shown(env, act, episodes: int, seed: int, show: Show,
                   root: Path, folder: Path, stamped: bool = False) -> Episodes:
    """The rollout, shown as `show` says; videos go to `folder` under `root`, a run dir or a
    sanity agent's dir that is made for them; `stamped`, to a new `<time>/` folder in it, which
    a later play's never writes over."""
    recorder = None
    if show.video is not None:
        # An unwritable place, or a link planted on the way, fails now, not after the rollout.
        files.real_dir(folder, below=files.user_dir(root))
        if stamped:
            folder = rundir.unique_dir(folder, rundir.stamp())
        recorder = VideoRecorder(env, folder, show.video.length, interval=None)
    shown = recorder or env
    if show.viewer:
        shown = Viewer(shown)
    try:
        eps = rollout(shown, act, episodes, seed)
    finally:
        if shown is not env:
            shown.close()  # writes the video; its owner closes the env again, harmlessly
    eps.videos = list(recorder.files) if recorder else []
    return eps


def _check_rollout(episodes: int, seed: int) -> None:
    if episodes <= 0:
        raise LabError(f"--episodes must be a positive integer, got {episodes}")
    if not 0 <= seed < 2**32:  # the range training seeds take
        raise LabError(f"--seed must be in [0, 2**32), got {seed}")


def play(*, episodes: int = 10, seed: int = 0, show: Show = Show(),
         **where) -> tuple[LoadedPolicy, Episodes]:
    _check_rollout(episodes, seed)
    if where.get("num_envs") is None:
        where["num_envs"] = min(episodes, 256)
    loaded = load(seed=seed, **where)
    try:
        return loaded, _rollout_shown(loaded.env, loaded.policy, episodes, seed, show,
                                      loaded.run.dir, videos.folder(loaded.run.dir, videos.PLAY),
                                      stamped=True)
    finally:
        loaded.env.close()


def sanity(task: str, agent: Agent | str, *, episodes: int = 10, seed: int = 0,
           num_envs: int | None = None, overrides: Sequence[str] = (), show: Show = Show(),
           logs_dir: Path | None = None) -> tuple[Any, Episodes]:
    """Roll out `task` with zero or uniformly random actions in [-1, 1] and no checkpoint: do
    rewards, terminations and time-outs behave before a single training step is spent?"""
    agent = Agent(agent)
    _check_rollout(episodes, seed)
    if num_envs is not None and num_envs <= 0:
        raise LabError(f"--num-envs must be a positive integer, got {num_envs}")
    spec = registry.get_task(task)
    layers = config.parse_set(overrides)
    if layers["agent"]:
        raise LabError(f"--agent {agent.value} has no agent settings to set",
                       "only env.KEY=VALUE applies to a sanity agent")
    env_cfg = config.build(spec.config_class, "env", [
        layers["env"], {"num_envs": num_envs or min(episodes, 256)}])
    env = make_env(spec, env_cfg, backend=CPU, device="cpu", seed=seed)
    generator = torch.Generator().manual_seed(seed)
    shape = (env.num_envs, *env.single_action_space.shape)

    def act(obs: torch.Tensor) -> torch.Tensor:
        if agent is Agent.zero:
            return torch.zeros(shape)
        return torch.rand(shape, generator=generator) * 2.0 - 1.0

    try:
        name = f"{rundir.stamp()}_{agent.value}"
        root = (logs_dir or rundir.default_logs_dir()) / SANITY / task / name
        return spec, _rollout_shown(env, act, episodes, seed, show, root,
                                    videos.folder(root, videos.PLAY))
    finally:
        env.close()
