"""lab's skrl update (lab_skrl.ppo.LabSkrlPPO) against the library's own PPO on the same
rollouts: on a GPU, where it replays one CUDA graph, the same parameters, learning rate,
observation statistics and losses within float tolerance over several updates and across a save
and load; on the CPU the same with the library's update and a fused Adam."""

from __future__ import annotations

import contextlib
import copy

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import no_device_waits
from lab_skrl.framework import Actor, Critic
from lab_skrl.ppo import LabSkrlPPO
from skrl.agents.torch.ppo import PPO, PPO_CFG
from skrl.memories.torch import RandomMemory
from skrl.resources.preprocessors.torch import RunningStandardScaler
from skrl.resources.schedulers.torch import KLAdaptiveLR

ENVS, STEPS, OBS, ACTIONS, STATES = 256, 8, 6, 2, 9
DEVICES = ["cpu", pytest.param("cuda", marks=[pytest.mark.gpu, pytest.mark.skipif(
    not torch.cuda.is_available(), reason="needs a CUDA GPU")])]
OBS_SPACE = gym.spaces.Box(-np.inf, np.inf, (OBS,))
ACTION_SPACE = gym.spaces.Box(-1.0, 1.0, (ACTIONS,))
# A task's critic observations: the value model's states, normalized on their own.
STATE_SPACE = gym.spaces.Box(-np.inf, np.inf, (STATES,))
WITH_STATES = {"state_preprocessor": RunningStandardScaler,
               "state_preprocessor_kwargs": {"size": STATE_SPACE}}
# Rewards scaled before skrl's time-out bootstrap, as lab's reward_scale does.
SHAPED = {"rewards_shaper": lambda rewards, timestep, timesteps: 0.6 * rewards}


def agent(cls: type[PPO], device: str, **settings) -> PPO:
    torch.manual_seed(0)
    states = STATE_SPACE if "state_preprocessor" in settings else None
    if states is not None:
        settings["state_preprocessor_kwargs"] = {**settings["state_preprocessor_kwargs"],
                                                 "device": device}
    models = {"policy": Actor(OBS_SPACE, ACTION_SPACE, device, [32, 32], "elu", 0.0),
              "value": Critic(OBS_SPACE, ACTION_SPACE, device, [32, 32], "elu",
                              state_space=states)}
    cfg = PPO_CFG(**{
        "rollouts": STEPS, "learning_epochs": 3, "mini_batches": 5, "learning_rate": 1e-3,
        "learning_rate_scheduler": KLAdaptiveLR,
        "learning_rate_scheduler_kwargs": {"kl_threshold": 0.002},
        "observation_preprocessor": RunningStandardScaler,
        "observation_preprocessor_kwargs": {"size": OBS_SPACE, "device": device},
        "value_preprocessor": RunningStandardScaler,
        "value_preprocessor_kwargs": {"size": 1, "device": device},
        "time_limit_bootstrap": True, **settings})
    made = cls(models=models, memory=RandomMemory(memory_size=STEPS, num_envs=ENVS, device=device),
               observation_space=OBS_SPACE, state_space=states, action_space=ACTION_SPACE,
               device=device, cfg=cfg)
    made.init()
    made.enable_training_mode(True)
    return made


def agents(device: str, **settings) -> tuple[PPO, LabSkrlPPO]:
    return agent(PPO, device, **settings), agent(LabSkrlPPO, device, **settings)


def rollout_and_update(alg: PPO, iteration: int) -> dict[str, float]:
    """One rollout of random transitions and the update at its end; skrl's figures."""
    device = alg.device
    torch.manual_seed(iteration)  # the same action samples for every agent
    gen = torch.Generator(device=device).manual_seed(iteration)
    def draw(size: int) -> torch.Tensor | None:
        return (None if size == STATES and alg.state_space is None
                else 2.0 * torch.randn(ENVS, size, generator=gen, device=device) + 1.0)

    obs, states = draw(OBS), draw(STATES)
    for step in range(STEPS):
        with torch.no_grad():
            actions, _ = alg.act(obs, states, timestep=step, timesteps=STEPS)
            next_obs, next_states = draw(OBS), draw(STATES)
            alg.record_transition(
                observations=obs, states=states, actions=actions,
                rewards=torch.randn(ENVS, 1, generator=gen, device=device),
                next_observations=next_obs, next_states=next_states,
                terminated=torch.rand(ENVS, 1, generator=gen, device=device) < 0.05,
                truncated=torch.rand(ENVS, 1, generator=gen, device=device) < 0.05,
                infos={}, timestep=step, timesteps=STEPS)
        torch.manual_seed(1000 + iteration)  # the same mini-batch shuffles
        alg.post_interaction(timestep=step, timesteps=STEPS)
        obs, states = next_obs, next_states
    figures = {tag: values[-1] for tag, values in alg.tracking_data.items()
               if not tag.startswith("Stats")}
    alg.tracking_data.clear()
    return figures


def learning_rate(alg: PPO) -> float:
    return float(alg.optimizer.param_groups[0]["lr"])


def assert_same(eager: PPO, ours: LabSkrlPPO, exact: bool) -> None:
    tolerance = {"rtol": 0, "atol": 0} if exact else {"rtol": 1e-4, "atol": 2e-5}
    for name, module in eager.checkpoint_modules.items():
        if name == "optimizer":
            continue
        mine = ours.checkpoint_modules[name].state_dict()
        for key, value in module.state_dict().items():
            torch.testing.assert_close(mine[key], value, **tolerance, msg=f"{name}.{key}")
    assert learning_rate(ours) == pytest.approx(learning_rate(eager), rel=0 if exact else 1e-5)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("settings", [
    {},
    {"value_clip": 0.0, "entropy_loss_scale": 0.01, "grad_norm_clip": 0.0},
    {"learning_rate_scheduler": None, "learning_rate_scheduler_kwargs": {}},
    WITH_STATES,
    SHAPED,
])
def test_lab_skrl_ppo_updates_as_skrl_does(device, settings):
    eager, ours = agents(device, **settings)
    assert ours.graphed == (device == "cuda")
    assert ours.optimizer.param_groups[0]["fused"]
    learning_rates = set()
    for iteration in range(4):
        expected = rollout_and_update(eager, iteration)
        got = rollout_and_update(ours, iteration)
        assert got.keys() == expected.keys()
        assert got == pytest.approx(expected, rel=1e-4, abs=1e-6)
        assert_same(eager, ours, exact=False)
        learning_rates.add(learning_rate(eager))
    if settings.get("learning_rate_scheduler", KLAdaptiveLR):
        assert len(learning_rates) > 1, "the adaptive learning rate never moved: nothing compared"


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("settings", [{}, WITH_STATES, SHAPED])
def test_time_outs_are_bootstrapped_as_skrl_does_without_reading_the_device(device, settings):
    eager, ours = agents(device, **settings)
    gen = torch.Generator(device=device).manual_seed(0)
    def draw(size: int) -> torch.Tensor | None:
        return (None if size == STATES and "state_preprocessor" not in settings
                else torch.randn(ENVS, size, generator=gen, device=device))

    for step, timed_out in enumerate([0.0, 0.3]):  # a step without time-outs, then one with
        obs, states, next_obs, next_states = draw(OBS), draw(STATES), draw(OBS), draw(STATES)
        rewards = torch.randn(ENVS, 1, generator=gen, device=device)
        truncated = torch.rand(ENVS, 1, generator=gen, device=device) < timed_out
        for alg in (eager, ours):
            torch.manual_seed(step)  # the same action samples
            with torch.no_grad():
                actions, _ = alg.act(obs, states, timestep=step, timesteps=STEPS)
            with no_device_waits(device) if alg is ours else contextlib.nullcontext():
                alg.record_transition(
                    observations=obs, states=states, actions=actions, rewards=rewards.clone(),
                    next_observations=next_obs, next_states=next_states,
                    terminated=torch.zeros_like(truncated), truncated=truncated, infos={},
                    timestep=step, timesteps=STEPS)
    got, expected = (alg.memory.get_tensor_by_name("rewards")[:2] for alg in (ours, eager))
    torch.testing.assert_close(got, expected, rtol=0, atol=0)
    shaper = settings.get("rewards_shaper") or (lambda r, t, n: r)
    added = expected[1] - shaper(rewards, 1, STEPS)  # the bootstrap skrl added at the time-outs
    assert truncated.any() and (added[truncated] != 0).all() and (added[~truncated] == 0).all()


@pytest.mark.parametrize("device", DEVICES)
def test_a_saved_lab_skrl_ppo_resumes_as_it_would_have_gone_on(device):
    eager, ours = agents(device)
    for iteration in range(2):
        rollout_and_update(eager, iteration)
        rollout_and_update(ours, iteration)
    # copied, as torch.save would: a state dict shares its tensors with the live agent
    saved = copy.deepcopy({name: module.state_dict()
                           for name, module in ours.checkpoint_modules.items()})
    assert isinstance(saved["optimizer"]["param_groups"][0]["lr"], float)
    resumed = agent(LabSkrlPPO, device)
    for name, module in resumed.checkpoint_modules.items():
        module.load_state_dict(copy.deepcopy(saved[name]))
    library = agent(PPO, device)  # the library's own agent takes the checkpoint too
    library.optimizer.load_state_dict(copy.deepcopy(saved["optimizer"]))
    assert learning_rate(library) == pytest.approx(learning_rate(ours))
    for alg in (eager, ours, resumed):
        rollout_and_update(alg, 2)
    assert_same(eager, resumed, exact=False)
    assert_same(ours, resumed, exact=True)
