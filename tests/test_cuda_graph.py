"""The env step's CUDA graph, the parts that hold without a GPU; replays are tested on a GPU in
test_warp.py."""

from __future__ import annotations

import pytest
import torch
from lab_cartpole.config import CartpoleConfig

from labcli.envs.cuda_graph import _fresh
from labcli.envs.env import LabVecEnv
from labcli.errors import LabError
from labcli.plugins import registry


def cpu_env(**cfg) -> LabVecEnv:
    spec = registry.get_task("cartpole")
    return LabVecEnv(spec, CartpoleConfig(num_envs=4, **cfg), backend="cpu")


def test_outputs_are_copied_and_shared_tensors_stay_shared():
    done, obs = torch.tensor([True, False]), torch.zeros(2, 3)
    out = (obs, {"_final_obs": done, "lab_episode": {"r": obs[:, 0]}, "_lab_episode": done, "n": 2})
    copy = _fresh(out, {})
    assert copy[0] is not obs and torch.equal(copy[0], obs)
    assert copy[1]["_final_obs"] is copy[1]["_lab_episode"] is not done
    assert copy[1]["n"] == 2
    obs.fill_(1.0)
    assert copy[0].eq(0).all() and copy[1]["lab_episode"]["r"].eq(0).all()


def test_cpu_envs_step_eagerly_and_the_flag_is_config():
    assert cpu_env()._graphed is None
    assert cpu_env(cuda_graph=False).cfg.cuda_graph is False
    assert CartpoleConfig().cuda_graph is True


@pytest.mark.parametrize("shape", [(4,), (3, 1), (4, 2), (1, 1)])
def test_actions_of_another_shape_are_an_error_naming_the_right_one(shape):
    env = cpu_env()
    env.reset(seed=0)
    with pytest.raises(LabError, match=r"actions of shape") as err:
        env.step(torch.zeros(shape))
    assert "[4, 1]" in err.value.hint
    env.close()
