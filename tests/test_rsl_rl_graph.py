"""lab's RSL-RL update (lab_rsl_rl.ppo.LabPPO) against the library's own PPO on the same
rollouts: on a GPU, where it replays one CUDA graph, the same parameters, learning rate and
losses within float tolerance over several updates (symmetric augmentation and the mirror loss
included) and across a save and load; on the CPU the same with the library's update and a fused
Adam."""

from __future__ import annotations

import copy

import pytest
import torch
from lab_rsl_rl.framework import mirror_augmentation
from lab_rsl_rl.ppo import LabPPO
from rsl_rl.algorithms import PPO
from rsl_rl.models import MLPModel
from rsl_rl.storage import RolloutStorage
from tensordict import TensorDict

from labcli.envs.mdp.symmetry import Mirror

ENVS, STEPS, OBS, ACTIONS = 256, 8, 6, 2
DEVICES = ["cpu", pytest.param("cuda", marks=[pytest.mark.gpu, pytest.mark.skipif(
    not torch.cuda.is_available(), reason="needs a CUDA GPU")])]


def observations(seed: int, device: str) -> TensorDict:
    gen = torch.Generator(device=device).manual_seed(seed)
    return TensorDict({"policy": torch.randn(ENVS, OBS, generator=gen, device=device)},
                      batch_size=[ENVS])


def algorithms(device: str, **kwargs) -> tuple[PPO, LabPPO]:
    torch.manual_seed(0)
    obs = observations(0, device)
    actor = MLPModel(obs, {"actor": ["policy"]}, "actor", ACTIONS, hidden_dims=[32, 32],
                     obs_normalization=True,
                     distribution_cfg={"class_name": "GaussianDistribution", "init_std": 1.0})
    critic = MLPModel(obs, {"critic": ["policy"]}, "critic", 1, hidden_dims=[32, 32],
                      obs_normalization=True)
    settings = {"num_learning_epochs": 3, "num_mini_batches": 4, "desired_kl": 0.01,
                "device": device, **kwargs}
    return tuple(cls(copy.deepcopy(actor), copy.deepcopy(critic),
                     RolloutStorage("rl", ENVS, STEPS, obs, [ACTIONS], device), **settings)
                 for cls in (PPO, LabPPO))


def symmetry(device: str, augmentation: bool, mirror_loss_coef: float) -> dict:
    """RSL-RL's symmetry_cfg with a mirror image of the test's observations and actions (two
    columns swapped, signs flipped), as lab's runner builds it from a task's `Mirror`."""
    obs_index, obs_sign = [1, 0, 2, 3, 4, 5], [1.0, 1.0, -1.0, 1.0, -1.0, 1.0]
    mirror = Mirror(*(torch.tensor(v, device=device) for v in (
        obs_index, obs_sign, [1, 0], [-1.0, -1.0], obs_index, obs_sign)))
    return {"env": None, "data_augmentation_func": mirror_augmentation(mirror),
            "use_data_augmentation": augmentation, "use_mirror_loss": mirror_loss_coef > 0,
            "mirror_loss_coeff": mirror_loss_coef}


def rollout_and_update(alg: PPO, iteration: int) -> dict[str, float]:
    device = alg.device
    torch.manual_seed(iteration)  # the same action samples for every algorithm
    gen = torch.Generator(device=device).manual_seed(iteration)
    with torch.inference_mode():  # as RSL-RL's runner collects
        for step in range(STEPS):
            obs = observations(100 * iteration + step, device)
            alg.act(obs)
            dones = torch.rand(ENVS, generator=gen, device=device) < 0.05
            alg.process_env_step(obs, torch.randn(ENVS, generator=gen, device=device), dones,
                                 {"time_outs": dones & (torch.rand(ENVS, device=device) < 0.5)})
        alg.compute_returns(observations(100 * iteration + STEPS, device))
    torch.manual_seed(1000 + iteration)  # the same mini-batch shuffle
    return alg.update()


def assert_same(eager: PPO, ours: LabPPO, exact: bool) -> None:
    tolerance = {"rtol": 0, "atol": 0} if exact else {"rtol": 1e-4, "atol": 2e-5}
    for module in ("actor", "critic"):
        mine = getattr(ours, module).state_dict()
        for name, value in getattr(eager, module).state_dict().items():
            torch.testing.assert_close(mine[name], value, **tolerance, msg=f"{module}.{name}")
    assert ours.learning_rate == pytest.approx(eager.learning_rate, rel=0 if exact else 1e-5)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("kwargs", [
    {},
    {"use_clipped_value_loss": False, "normalize_advantage_per_mini_batch": True,
     "entropy_coef": 0.01},
    {"schedule": "fixed"},
])
def test_lab_ppo_updates_as_rsl_rl_does(device, kwargs):
    assert_updates_alike(device, kwargs)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize(("augmentation", "mirror_loss_coef"), [(True, 0.0), (False, 0.5),
                                                                 (True, 0.5)])
def test_lab_ppo_learns_symmetry_as_rsl_rl_does(device, augmentation, mirror_loss_coef):
    assert_updates_alike(device, {"symmetry_cfg": symmetry(device, augmentation,
                                                           mirror_loss_coef)})


def assert_updates_alike(device: str, kwargs: dict) -> None:
    eager, ours = algorithms(device, **kwargs)
    assert ours.graphed == (device == "cuda")
    assert ours.optimizer.param_groups[0]["fused"]
    learning_rates = set()
    for iteration in range(4):
        expected = rollout_and_update(eager, iteration)
        got = rollout_and_update(ours, iteration)
        assert got.keys() == expected.keys()
        assert got == pytest.approx(expected, rel=1e-4, abs=1e-6)
        assert_same(eager, ours, exact=False)
        learning_rates.add(eager.learning_rate)
    if kwargs.get("schedule") != "fixed":
        assert len(learning_rates) > 1, "the adaptive learning rate never moved: nothing compared"


@pytest.mark.parametrize("device", DEVICES)
def test_a_saved_lab_ppo_resumes_as_it_would_have_gone_on(device):
    eager, ours = algorithms(device)
    for iteration in range(2):
        rollout_and_update(eager, iteration)
        rollout_and_update(ours, iteration)
    saved = ours.save()
    assert isinstance(saved["optimizer_state_dict"]["param_groups"][0]["lr"], float)
    _, resumed = algorithms(device)
    resumed.load(copy.deepcopy(saved), None, strict=True)
    library = algorithms("cpu")[0]  # an eager, CPU PPO takes the checkpoint too
    library.load({k: {n: t.cpu() if torch.is_tensor(t) else t for n, t in v.items()}
                  if k != "optimizer_state_dict" else v for k, v in copy.deepcopy(saved).items()},
                 None, strict=True)
    assert library.learning_rate == pytest.approx(ours.learning_rate)
    for alg in (eager, ours, resumed):
        rollout_and_update(alg, 2)
    assert_same(eager, resumed, exact=False)
    assert_same(ours, resumed, exact=True)
