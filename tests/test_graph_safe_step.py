"""Every task's env step as a GPU runs it (none of the CPU's shortcuts through host reads),
checked on the CPU: it makes no tensor from host data (on a GPU, a copy from the host) and reads
no tensor on the host (`.item()`, `bool()`, `float()`, a Python `if` on a tensor), neither of
which a CUDA graph of the step can capture. CI has no GPU: here such a step fails first."""

from __future__ import annotations

import pytest
import torch
from conftest import needs_menagerie
from host_ops import UNCAPTURABLE, HostOps

from labcli.envs.env import LabVecEnv
from labcli.envs.spec import Menagerie
from labcli.gym import make_env
from labcli.plugins import registry

# Options whose terms take other paths through the step than the tasks' defaults: upright
# against the terrain, the privileged critic, and the sim-to-real settings of docs/deploying.md
# (latency, a motor model, randomized motors and joints at each reset, a sensor's bias, history
# and lag, a mounted IMU).
VARIANTS = {
    "go1-rough": ["env.rewards.flat_orientation_l2.weight=-1.0",
                  "env.rewards.flat_orientation_l2.reference=terrain"],
    "g1-rough": ["env.rewards.upright.body=null", "env.rewards.upright.reference=terrain",
                 "env.critic_observations=privileged"],
    "go1-flat": ["env.actions.delay=[0,8]", "env.robot.actuators.hip.model=dc_motor",
                 *(f"env.events.{event}.mode=reset" for event in (
                     "actuator_gains", "joint_friction", "joint_damping", "joint_armature")),
                 "env.events.actuator_gains.stiffness_range=[0.8,1.2]",
                 "env.events.joint_friction.range=[0.0,0.3]",
                 "env.events.joint_friction.operation=add",
                 "env.events.joint_damping.range=[0.5,1.5]",
                 "env.events.joint_armature.range=[0.9,1.1]",
                 "env.observations.joint_pos.bias=0.02",
                 "env.observations.joint_pos.history_length=3",
                 "env.observations.joint_vel.delay=[0,2]",
                 "env.observations.projected_gravity.site=imu",
                 "env.observations.projected_gravity.mounting_range={roll: [-0.05, 0.05]}"],
}


def _case(task: str, sets: list[str]):
    model = registry.get_task(task).model
    marks = [needs_menagerie(model.robot)] if isinstance(model, Menagerie) else []
    return pytest.param(task, sets, marks=marks, id=f"{task}-options" if sets else task)


CASES = [*(_case(task, []) for task in registry.loaded().names(registry.TASK)),
         *(_case(task, sets) for task, sets in VARIANTS.items())]


def test_the_spy_sees_what_a_cuda_graph_cannot_capture():
    x = torch.zeros(3)
    with HostOps(UNCAPTURABLE) as spy:
        x.new_tensor([1.0, 0.0])
        bool(x.any())
        x.add_(1.0)
    assert sorted(spy.seen.values()) == [1, 1] and len(spy.seen) == 2


@pytest.mark.parametrize(("task", "sets"), CASES)
def test_the_step_as_a_gpu_runs_it_neither_copies_from_nor_reads_on_the_host(task, sets,
                                                                            monkeypatch):
    monkeypatch.setattr(LabVecEnv, "_reads_on_the_host", lambda self: False)
    # Episodes of a few steps: the resets run in the spied steps too.
    env = make_env(task, num_envs=4, seed=0, overrides=["env.episode_length_s=0.1", *sets])
    gen = torch.Generator().manual_seed(0)
    shape = env.action_space.shape
    env.reset(seed=0)
    env.step(torch.rand(shape, generator=gen) * 2 - 1)  # first-use set-up, as a GPU's warm-up
    actions = [torch.rand(shape, generator=gen) * 2 - 1 for _ in range(20)]
    with HostOps(UNCAPTURABLE) as spy:
        ends = [torch.logical_or(*env.step(a)[2:4]) for a in actions]
    env.close()
    assert torch.stack(ends).any(), "no episode ended: the resets were not stepped"
    assert not spy.seen, f"{task}'s step: " + "; ".join(f"{k} ({n}x)" for k, n in spy.seen.items())
