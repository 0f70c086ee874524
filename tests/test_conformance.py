"""The conformance suite (labcli.testing) over every built-in framework, at tiny sizes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from labcli import testing

FRAMEWORKS = ["sb3", "rsl_rl", "skrl"]

# Tiny agents: 8 steps per env per iteration, two small epochs, 16-unit networks.
SMALL = {
    "sb3": ["agent.n_steps=8", "agent.batch_size=16", "agent.n_epochs=2",
            "agent.net_arch=[16,16]", "agent.normalize_obs=true"],
    "rsl_rl": ["agent.num_steps_per_env=8", "agent.num_learning_epochs=2",
               "agent.num_mini_batches=2", "agent.actor_hidden_dims=[16,16]",
               "agent.critic_hidden_dims=[16,16]"],
    "skrl": ["agent.rollouts=8", "agent.learning_epochs=2", "agent.mini_batches=2",
             "agent.hidden_sizes=[16,16]"],
}


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


# The learning check runs the task's defaults at 16 envs; SB3's at 32, whose 32-step rollouts
# fill its batch of 1024 (seeds 0-2 gained 1.8-2.3x in 25 iterations; at 16 envs, 1.4x).
IMPROVE = {"sb3": {"num_envs": 32}, "rsl_rl": {}, "skrl": {}}

PROBES = {"sb3": _probe_sb3, "rsl_rl": _probe_rsl_rl, "skrl": _probe_skrl}


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
    testing.check_training_improves(name, tmp_path, **IMPROVE[name])


def test_check_framework_runs_every_check(tmp_path):
    testing.check_framework("rsl_rl", tmp_path, SMALL["rsl_rl"], PROBES["rsl_rl"],
                            improve_overrides=None)
