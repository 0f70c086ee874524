"""The wrapper pipeline: env wrappers → exactly one framework adapter → framework wrappers, with
a wrong order refused before any wrapper is built, naming the wrapper and the rule it breaks."""

from __future__ import annotations

import dataclasses
import io
import warnings
from collections.abc import Iterator
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st
from lab_sb3.adapter import Sb3VecEnv
from lab_sb3.framework import Sb3Framework
from lab_sb3.plugin import SPEC as SB3
from rich.console import Console
from stable_baselines3.common.vec_env import VecNormalize

from labcli.envs.env import LabVecEnv
from labcli.envs.wrappers import Stage, Step, WrapperSpec, apply, validate
from labcli.errors import LabError
from labcli.plugins import registry
from labcli.plugins.hookspecs import hookimpl
from labcli.runs import training

ORDER_RULE = "order is env wrappers, then the one adapter, then framework wrappers"


class ObservationNoise(gym.vector.VectorWrapper):
    """An env-stage wrapper, torch in and torch out: Gaussian noise on every observation,
    the true last one of ended episodes included."""

    def __init__(self, env: gym.vector.VectorEnv, std: float = 0.1, seed: int = 0):
        super().__init__(env)
        self.std = std
        self.generator = torch.Generator().manual_seed(seed)

    def _noisy(self, obs: torch.Tensor) -> torch.Tensor:
        return obs + self.std * torch.randn(obs.shape, generator=self.generator)

    def reset(self, **kwargs: Any):
        obs, info = self.env.reset(**kwargs)
        return self._noisy(obs), info

    def step(self, actions):
        obs, reward, terminated, truncated, info = self.env.step(actions)
        info = {**info, "final_obs": self._noisy(info["final_obs"])}
        return self._noisy(obs), reward, terminated, truncated, info


NOISE = WrapperSpec("obs_noise", Stage.ENV, ObservationNoise, description="Gaussian obs noise")


def registered(name: str) -> WrapperSpec:
    return registry.get_wrapper(name)


@pytest.fixture
def env(tmp_path, monkeypatch) -> Iterator[LabVecEnv]:
    monkeypatch.chdir(tmp_path)  # MuJoCo's warning log, should it write one
    spec = registry.get_task("cartpole")
    env = LabVecEnv(spec, spec.config_class(num_envs=4), backend="cpu")
    yield env
    env.close()


class Built:
    """Stands in for the wrappers' build functions, recording what got built and in which order."""

    def __init__(self) -> None:
        self.names: list[str] = []

    def spy(self, spec: WrapperSpec) -> WrapperSpec:
        def build(env: Any, **kwargs: Any) -> Any:
            self.names.append(spec.name)
            return env

        return dataclasses.replace(spec, build=build)


# What is registered ----------------------------------------------------------------------------
def test_registered_wrappers_declare_their_stage_and_framework():
    assert registered("sb3.adapter").stage is Stage.ADAPTER
    assert registered("sb3.vec_normalize").stage is Stage.FRAMEWORK
    for fw in ("sb3", "rsl_rl", "skrl"):
        assert registered(f"{fw}.adapter").framework == fw


@pytest.mark.parametrize("name", ["sb3", "rsl_rl", "skrl"])
def test_every_frameworks_own_pipeline_is_valid(name):
    fw = registry.get_framework(name).load()
    pipeline = fw.pipeline(fw.agent_config())
    validate(pipeline, name)
    adapter = pipeline[0].spec
    assert adapter.stage is Stage.ADAPTER and adapter.framework == name
    assert registered(adapter.name) == adapter  # the one `lab list` shows is the one used


# A right order builds, innermost first ---------------------------------------------------------
@pytest.mark.filterwarnings("ignore:The `render_mode` attribute:UserWarning")
def test_env_wrapper_adapter_and_framework_wrapper_build_in_order(env):
    pipeline = [Step(NOISE, {"std": 0.5}), Step(registered("sb3.adapter")),
                Step(registered("sb3.vec_normalize"), {"norm_reward": False})]
    wrapped = apply(env, pipeline, "sb3")
    assert isinstance(wrapped, VecNormalize) and not wrapped.norm_reward
    assert isinstance(wrapped.venv, Sb3VecEnv)
    assert isinstance(wrapped.venv.env, ObservationNoise) and wrapped.venv.env.std == 0.5
    assert wrapped.venv.env.env is env

    obs = wrapped.reset()
    assert isinstance(obs, np.ndarray) and obs.shape == (4, 4)
    obs, reward, done, infos = wrapped.step(np.zeros((4, 1), dtype=np.float32))
    assert obs.shape == (4, 4) and reward.shape == (4,) and done.shape == (4,)
    # The noise is there: the adapter sees something else than the env's own state.
    raw = env.task.observations().float()
    assert not np.allclose(wrapped.get_original_obs(), raw.numpy())


def test_sb3_adapter_builds_without_warnings(env):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        apply(env, [Step(registered("sb3.adapter"))], "sb3")


# A wrong order is refused, naming the wrapper and the rule -------------------------------------
SB3_ADAPTER, VEC_NORMALIZE = "sb3.adapter", "sb3.vec_normalize"
CASES = {
    "env wrapper after the adapter": (
        [SB3_ADAPTER, NOISE, VEC_NORMALIZE], "sb3",
        ["'obs_noise' (env stage) comes after 'sb3.adapter' (adapter stage)"], ORDER_RULE),
    "framework wrapper before the adapter": (
        [VEC_NORMALIZE, SB3_ADAPTER], "sb3",
        ["'sb3.adapter' (adapter stage) comes after 'sb3.vec_normalize' (framework stage)"],
        ORDER_RULE),
    "two adapters": (
        [NOISE, SB3_ADAPTER, SB3_ADAPTER], "sb3",
        ["exactly one framework adapter, got sb3.adapter, sb3.adapter"], "use the 'sb3' adapter"),
    "adapters of two frameworks": (
        [SB3_ADAPTER, "skrl.adapter"], "sb3",
        ["exactly one framework adapter, got sb3.adapter, skrl.adapter"], "once"),
    "no adapter": (
        [NOISE], "sb3", ["exactly one framework adapter, got none"], "use the 'sb3' adapter"),
    "VecNormalize with no adapter at all": (
        [NOISE, VEC_NORMALIZE], "sb3", ["exactly one framework adapter, got none"],
        "after every env wrapper"),
    "VecNormalize behind another framework's adapter": (
        [NOISE, "skrl.adapter", VEC_NORMALIZE], "skrl",
        ["'sb3.vec_normalize' needs the 'sb3' adapter", "uses 'skrl.adapter' (skrl)"],
        "drop 'sb3.vec_normalize' or train with --framework sb3"),
    "adapter of another framework": (
        ["rsl_rl.adapter"], "sb3",
        ["adapter 'rsl_rl.adapter' converts for 'rsl_rl', but the framework is 'sb3'"],
        "use the 'sb3' adapter"),
}


@pytest.mark.parametrize(("wrappers", "framework", "named", "hint"), CASES.values(), ids=CASES)
def test_a_wrong_pipeline_is_refused_before_anything_is_built(wrappers, framework, named, hint):
    built = Built()
    specs = [w if isinstance(w, WrapperSpec) else registered(w) for w in wrappers]
    pipeline = [Step(built.spy(spec)) for spec in specs]
    with pytest.raises(LabError) as err:
        apply(object(), pipeline, framework)
    assert built.names == []
    for text in named:
        assert text in err.value.message
    assert hint in err.value.hint
    assert "\n" not in str(err.value)


MISORDERED = "sb3_misordered"


class _MisorderedSb3(Sb3Framework):
    """SB3 under another name, its VecNormalize put in front of its adapter: a plugin author's
    mistake."""

    def pipeline(self, cfg):
        steps = [Step(dataclasses.replace(step.spec, name=f"{self.name}.{step.spec.name}",
                                          framework=self.name), step.kwargs)
                 for step in super().pipeline(cfg)]
        return list(reversed(steps))


class _MisorderedPlugin:
    @hookimpl
    def register_frameworks(self, register):
        register(dataclasses.replace(SB3, name=MISORDERED, framework=_MisorderedSb3, wrappers=()))


@pytest.fixture
def misordered_framework() -> Iterator[str]:
    plugin = _MisorderedPlugin()
    registry.pm.register(plugin, name="test-misordered")
    registry.reload()
    yield MISORDERED
    registry.pm.unregister(plugin)
    registry.reload()


def test_train_refuses_a_misordered_framework_before_writing_a_run(misordered_framework,
                                                                    tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    logs = tmp_path / "logs"
    with pytest.raises(LabError, match=r"'sb3_misordered.sb3.adapter' \(adapter stage\) comes "
                                       r"after 'sb3_misordered.sb3.vec_normalize'"):
        training.train("cartpole", misordered_framework, num_envs=4, max_iterations=1,
                       logs_dir=logs, console=Console(file=io.StringIO()))
    assert not logs.exists() or not any(logs.rglob("*"))


# Any pipeline: valid exactly when the rules say so ---------------------------------------------
POOL = [
    NOISE,
    WrapperSpec("video", Stage.ENV, lambda env: env),
    WrapperSpec("sb3.adapter", Stage.ADAPTER, lambda env: env, framework="sb3"),
    WrapperSpec("skrl.adapter", Stage.ADAPTER, lambda env: env, framework="skrl"),
    WrapperSpec("rsl_rl.adapter", Stage.ADAPTER, lambda env: env, framework="rsl_rl"),
    WrapperSpec("sb3.vec_normalize", Stage.FRAMEWORK, lambda env: env, framework="sb3"),
    WrapperSpec("sb3.frame_stack", Stage.FRAMEWORK, lambda env: env, framework="sb3"),
    WrapperSpec("skrl.record", Stage.FRAMEWORK, lambda env: env, framework="skrl"),
]


def follows_the_rules(specs: list[WrapperSpec], framework: str) -> bool:
    adapters = [s for s in specs if s.stage is Stage.ADAPTER]
    return (len(adapters) == 1 and adapters[0].framework == framework
            and [s.stage for s in specs] == sorted(s.stage for s in specs)
            and all(s.framework == framework for s in specs if s.stage is Stage.FRAMEWORK))


@given(st.lists(st.sampled_from(POOL), max_size=6), st.sampled_from(["sb3", "skrl", "rsl_rl"]))
def test_any_pipeline_builds_exactly_when_it_follows_the_rules(specs, framework):
    built = Built()
    pipeline = [Step(built.spy(spec)) for spec in specs]
    if follows_the_rules(specs, framework):
        apply(object(), pipeline, framework)
        assert built.names == [s.name for s in specs]
    else:
        with pytest.raises(LabError) as err:
            apply(object(), pipeline, framework)
        assert built.names == []
        # The wrapper at fault, or "none" where the adapter is missing.
        assert any(name in err.value.message for name in [s.name for s in specs] + ["none"])
