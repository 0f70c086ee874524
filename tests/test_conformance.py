"""The conformance suite (labcli.testing) over every built-in framework, at tiny sizes."""

from __future__ import annotations

import dataclasses
import io
import re

import numpy as np
import pytest
import torch
from lab_rl_games.framework import RlGamesFramework
from lab_rl_games.plugin import SPEC as RL_GAMES
from rich.console import Console

from labcli import testing
from labcli.envs.env import LabVecEnv
from labcli.errors import LabError
from labcli.plugins.hookspecs import hookimpl
from labcli.plugins.policy import Policy
from labcli.runs import session, training
from labcli.runs.ranks import Ranks

FRAMEWORKS = ["sb3", "sb3_sac", "sb3_td3", "rsl_rl", "skrl", "skrl_sac", "skrl_td3", "rl_games"]

# Tiny agents: 8 steps per env per iteration, two small epochs, 16-unit networks.
SMALL = testing.SMALL_AGENTS


def _probe_sb3(env, actions: torch.Tensor) -> testing.ProbeStep:
    env.step_async(actions.numpy())
    obs, reward, done, infos = env.step_wait()
    truncated = np.array([info.get("TimeLimit.truncated", False) for info in infos])
    return testing.ProbeStep(obs, reward, done & ~truncated, truncated)


def _probe_rsl_rl(env, actions: torch.Tensor) -> testing.ProbeStep:
    obs, reward, dones, extras = env.step(actions)
    truncated = extras["time_outs"].bool()
    return testing.ProbeStep(obs["policy"], reward, dones.bool() & ~truncated, truncated)


def _probe_skrl(env, actions: torch.Tensor) -> testing.ProbeStep:
    obs, reward, terminated, truncated, _ = env.step(actions)
    return testing.ProbeStep(obs, reward, terminated, truncated)


def _probe_rl_games(env, actions: torch.Tensor) -> testing.ProbeStep:
    obs, reward, dones, infos = env.step(actions)
    truncated = infos["time_outs"].bool()
    return testing.ProbeStep(obs, reward, dones.bool() & ~truncated, truncated)


PROBES = {"sb3": _probe_sb3, "sb3_sac": _probe_sb3, "sb3_td3": _probe_sb3,
          "rsl_rl": _probe_rsl_rl, "skrl": _probe_skrl, "skrl_sac": _probe_skrl,
          "skrl_td3": _probe_skrl, "rl_games": _probe_rl_games}


@pytest.mark.parametrize("name", FRAMEWORKS)
def test_adapter(name):
    testing.check_adapter(name, PROBES[name])


@pytest.mark.parametrize("name", FRAMEWORKS)
def test_training_outputs(name, tmp_path):
    testing.check_training_outputs(name, tmp_path, SMALL[name])


@pytest.mark.parametrize("name", FRAMEWORKS)
def test_policy_roundtrip(name, tmp_path):
    testing.check_policy_roundtrip(name, tmp_path, SMALL[name])


@pytest.mark.parametrize("name", FRAMEWORKS)
def test_resume_equals_an_unbroken_run(name, tmp_path):
    assert testing.check_resume(name, tmp_path, SMALL[name]) == 0.0  # bitwise, measured


@pytest.mark.parametrize("name", FRAMEWORKS)
def test_same_seed_same_returns_other_seed_other_returns(name, tmp_path):
    testing.check_determinism(name, tmp_path, SMALL[name])


@pytest.mark.parametrize("name", FRAMEWORKS)
def test_export_onnx(name, tmp_path):
    testing.check_export(name, tmp_path, SMALL[name])


@pytest.mark.parametrize("name", FRAMEWORKS)
def test_training_improves_the_return(name, tmp_path):
    testing.check_training_improves(name, tmp_path)


@pytest.mark.parametrize("name", FRAMEWORKS)
def test_the_update_runs_on_half_the_runs_threads_and_the_rollout_on_one(
        name, tmp_path, monkeypatch):
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    threads: dict[str, set[int]] = {"env step": set(), "backward": set()}
    step, backward = LabVecEnv.step, torch.autograd.backward

    def counted_step(self, actions):
        threads["env step"].add(torch.get_num_threads())
        return step(self, actions)

    def counted_backward(*args, **kwargs):
        threads["backward"].add(torch.get_num_threads())
        return backward(*args, **kwargs)

    monkeypatch.setattr(LabVecEnv, "step", counted_step)
    monkeypatch.setattr(torch.autograd, "backward", counted_backward)
    before = torch.get_num_threads()
    # 6 physics threads: the update gets 3 (the default here, one per core, is 2).
    training.train("cartpole", name, num_envs=8, max_iterations=2, logs_dir=tmp_path,
                   overrides=[*SMALL[name], "env.threads=6"], console=Console(file=io.StringIO()))
    assert threads == {"env step": {1}, "backward": {3}}
    assert torch.get_num_threads() == before


@pytest.mark.parametrize(("physics", "ranks", "omp", "expected"), [
    (16, 1, None, 8), (6, 1, None, 3), (3, 1, None, 2), (2, 1, None, 2), (1, 1, None, 1),
    (2, 1, "1", 1), (16, 1, "4,2", 4), (16, 1, "", 8), (16, 1, "many", 8), (16, 1, "0", 8),
    (None, 2, None, 2), (None, 4, None, 1)])
def test_update_threads_are_half_the_physics_both_of_two_and_omp_num_threads_at_most(
        physics, ranks, omp, expected, monkeypatch):
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    if omp is not None:
        monkeypatch.setenv("OMP_NUM_THREADS", omp)
    monkeypatch.setattr(session, "cores", lambda: 4)  # the host of a run without env.threads
    env = dataclasses.make_dataclass("Env", [("threads", int | None)])(physics)
    assert session.update_threads(env, Ranks(local_world_size=ranks, world_size=ranks)) == expected


def test_check_framework_runs_every_check(tmp_path):
    testing.check_framework("rsl_rl", tmp_path, SMALL["rsl_rl"], PROBES["rsl_rl"],
                            improve_overrides=None)


# The suite catches a Policy that does not act as the trained agent --------------------------
class _StdAsVariance(RlGamesFramework):
    """rl_games whose Policy's normalizer is handed the std where the variance goes."""

    def load_policy(self, checkpoint, env, cfg):
        policy = super().load_policy(checkpoint, env, cfg)
        policy.normalizer.std.copy_(policy.normalizer.std.sqrt())
        return policy


class _ConstantActor(RlGamesFramework):
    """rl_games whose Policy ignores the observations."""

    def load_policy(self, checkpoint, env, cfg):
        policy = super().load_policy(checkpoint, env, cfg)
        zeros = torch.zeros(1, env.single_observation_space.shape[0])
        return Policy(_Constant(policy(zeros)), policy.normalizer).eval()


class _Constant(torch.nn.Module):
    def __init__(self, action: torch.Tensor):
        super().__init__()
        self.register_buffer("action", action)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.action.expand(obs.shape[0], -1)


class _NoActor(RlGamesFramework):
    """rl_games that never shows lab its live agent."""

    def train(self, env, ctx):
        ctx.set_actor = lambda actor: None
        super().train(env, ctx)


def _register_variant(register_plugin, name: str, cls: type) -> None:
    adapter = dataclasses.replace(RL_GAMES.adapter, name=f"{name}.adapter", framework=name)
    spec = dataclasses.replace(RL_GAMES, name=name, framework=cls, wrappers=(adapter,))

    class Plugin:
        @hookimpl
        def register_frameworks(self, register):
            register(spec)

    register_plugin(Plugin(), f"test-{name}")


@pytest.mark.parametrize(("cls", "how_far"), [(_StdAsVariance, 1e-3), (_ConstantActor, 1e-2)],
                         ids=["std-as-variance", "constant-actor"])
def test_the_suite_fails_a_policy_that_does_not_act_as_the_trained_agent(
        cls, how_far, register_plugin, tmp_path):
    _register_variant(register_plugin, "broken", cls)
    with pytest.raises(LabError, match=r"the Policy loaded from model_\d+\.pth acts up to "
                                       r"(\S+) away from the agent") as err:
        testing.check_policy_roundtrip("broken", tmp_path, SMALL["rl_games"])
    assert float(re.search(r"acts up to (\S+) away", err.value.message).group(1)) > how_far


def test_the_suite_fails_a_framework_that_never_shows_its_live_agent(register_plugin, tmp_path):
    _register_variant(register_plugin, "silent", _NoActor)
    with pytest.raises(AssertionError, match="never calls ctx.set_actor"):
        testing.check_policy_roundtrip("silent", tmp_path, SMALL["rl_games"])
