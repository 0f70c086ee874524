"""A robot's imperfections, randomized per env. Joints and motors
(`env.events.joint_friction|joint_damping|joint_armature|actuator_gains`, off by default): each
env's own values in the model it steps, drawn within the ranges by each operation, again at
resets where asked, carried through a resume. Sensors (an observation term's `bias`): an offset
held through each episode."""

from __future__ import annotations

import pytest
import torch
from conftest import needs_menagerie, needs_warp

from labcli.errors import LabError
from labcli.gym import make_env

BASE = ["env.observation_noise=false", "env.events.push_robot=null"]
GAINS = ["env.events.actuator_gains.stiffness_range=[0.5,1.5]",
         "env.events.actuator_gains.damping_range=[0.8,1.2]"]
JOINTS = ["env.events.joint_damping.range=[0.1,0.3]", "env.events.joint_damping.operation=abs",
          "env.events.joint_friction.range=[0.0,0.5]", "env.events.joint_friction.operation=add",
          "env.events.joint_armature.range=[0.8,1.2]", "env.events.joint_armature.mode=reset"]
LEGS = slice(6, 18)  # go1's 12 leg dofs, after the free joint's 6
pytestmark = needs_menagerie("unitree_go1")


def go1(n: int, *overrides: str, backend: str = "cpu", **kwargs):
    env = make_env("go1-flat", num_envs=n, seed=0, overrides=[*BASE, *overrides],
                   backend=backend, **kwargs)
    env.reset()
    return env


def nominal_kp() -> torch.Tensor:
    """Each servo's stiffness in go1-flat's model, as its robot description sets it."""
    env = go1(1)
    kp = torch.from_numpy(env.sim.model.actuator_gainprm[:, 0].copy())
    env.close()
    return kp


def test_each_env_steps_with_its_own_gains_and_joints_drawn_by_each_operation():
    env = go1(16, *GAINS, *JOINTS)
    nominal, models = env.sim.model, env.sim.models
    kp0, kd0 = nominal.actuator_gainprm[:, 0], -nominal.actuator_biasprm[:, 2]
    armature0 = nominal.dof_armature[LEGS]
    kps = []
    for m in models:
        kp, kd = m.actuator_gainprm[:, 0], -m.actuator_biasprm[:, 2]
        assert (kp >= 0.5 * kp0).all() and (kp <= 1.5 * kp0).all()
        assert (kd >= 0.8 * kd0 - 1e-12).all() and (kd <= 1.2 * kd0 + 1e-12).all()
        assert (m.actuator_biasprm[:, 1] == -kp).all()  # still a servo: kp (target - q)
        assert ((m.dof_damping[LEGS] >= 0.1) & (m.dof_damping[LEGS] <= 0.3)).all()  # abs
        assert ((m.dof_frictionloss[LEGS] >= 0.0) & (m.dof_frictionloss[LEGS] <= 0.5)).all()
        ratio = m.dof_armature[LEGS] / armature0  # scale
        assert ((ratio >= 0.8 - 1e-12) & (ratio <= 1.2 + 1e-12)).all()
        assert (m.dof_damping[:6] == nominal.dof_damping[:6]).all()  # the base's: untouched
        kps.append(kp.copy())
    assert len({tuple(kp) for kp in kps}) == 16
    # The shared model stays nominal.
    assert torch.equal(torch.from_numpy(nominal.actuator_gainprm[:, 0]), nominal_kp())

    # At a reset, only the reset-mode terms draw again, and only for the envs reset.
    armature = torch.stack([torch.from_numpy(m.dof_armature.copy()) for m in models])
    mask = torch.zeros(16, dtype=torch.bool)
    mask[:8] = True
    env.task.reset(mask, env.task.rng)
    after = torch.stack([torch.from_numpy(m.dof_armature.copy()) for m in models])
    assert torch.equal(after[8:], armature[8:]) and not torch.equal(after[:8], armature[:8])
    assert all((m.actuator_gainprm[:, 0] == kp).all() for m, kp in zip(models, kps, strict=True))
    env.close()


def test_a_resumed_env_steps_with_the_gains_it_had():
    env = go1(4, *GAINS)
    for _ in range(3):
        env.step(torch.zeros(4, 12))
    twin = make_env("go1-flat", num_envs=4, seed=9, overrides=[*BASE, *GAINS],
                    backend="cpu")
    twin.resume_from(env.get_state())
    twin.reset()
    for mine, theirs in zip(env.sim.models, twin.sim.models, strict=True):
        assert (mine.actuator_gainprm == theirs.actuator_gainprm).all()
        assert (mine.actuator_biasprm == theirs.actuator_biasprm).all()
    env.close(), twin.close()


# Each model event's whole fields, by its name in env.events, as a lab before 2026-11-29 saved
# them in the env's state (`<event>/values`, an actuator's gains `bias` too).
WHOLE_FIELDS = {"joint_friction": {"values": "dof_frictionloss"},
                "joint_damping": {"values": "dof_damping"},
                "joint_armature": {"values": "dof_armature"},
                "actuator_gains": {"values": "actuator_gainprm", "bias": "actuator_biasprm"},
                "add_base_mass": {"values": "body_mass"}, "base_com": {"values": "body_ipos"}}
FIELDS = ("actuator_gainprm", "actuator_biasprm", "dof_frictionloss", "dof_damping",
          "dof_armature", "body_mass", "body_ipos")


@pytest.mark.parametrize("saved_by", ["this lab", "an older lab"])
def test_a_saved_state_holds_the_drawn_values_and_resumes_them(saved_by):
    """The state carries each event's drawn rows, not the model's whole fields (a terrain's
    thousands of geoms made those 82 MB a state for a G1's foot friction); a state an older lab
    saved with the whole fields resumes to the same models."""
    env = go1(4, *GAINS, *JOINTS)
    for _ in range(3):
        env.step(torch.zeros(4, 12))
    state = env.get_state()
    drawn = {k.removeprefix("task/").removesuffix("/drawn"): v for k, v in state.items()
             if k.endswith("/drawn")}
    assert set(drawn) == set(WHOLE_FIELDS)
    assert not any(k.endswith(("/values", "/bias")) for k in state)
    assert drawn["joint_damping"].shape == (4, 12)  # the legs' dofs, not the base's 6
    assert drawn["actuator_gains"].shape == (4, 12, 2)  # each servo's kp and kd
    assert drawn["add_base_mass"].shape == (4, 1)  # the trunk, of go1's 14 bodies
    if saved_by == "an older lab":
        state = {k: v for k, v in state.items() if not k.endswith("/drawn")}
        for event, saved in WHOLE_FIELDS.items():
            for name, field in saved.items():
                state[f"task/{event}/{name}"] = env.sim.model_field(field).clone()
    twin = make_env("go1-flat", num_envs=4, seed=9, overrides=[*BASE, *GAINS, *JOINTS],
                    backend="cpu")
    twin.resume_from(state)
    twin.reset()
    for mine, theirs in zip(env.sim.models, twin.sim.models, strict=True):
        for field in FIELDS:
            assert (getattr(mine, field) == getattr(theirs, field)).all(), field
    action = torch.full((4, 12), 0.3)
    for _ in range(3):
        torch.testing.assert_close(env.step(action)[0], twin.step(action)[0], rtol=0, atol=0)
    env.close(), twin.close()


@needs_menagerie("unitree_g1")
def test_a_term_that_names_nothing_it_can_change_is_one_line():
    with pytest.raises(LabError, match="name no hinge or slide joint"):
        make_env("g1-flat", num_envs=2, backend="cpu",
                 overrides=["env.events.joint_damping.joints=[floating_base_joint]"])


def test_an_observation_bias_is_an_offset_held_through_each_episode():
    env = go1(64, "env.observation_noise=true", "env.observations.joint_pos.bias=0.1",
              "env.observations.joint_pos.noise=0")
    task = env.task
    term = [b.name for b in task._obs].index("joint_pos")
    built, start = task._obs[term], sum(task._obs_widths[:term])
    columns = slice(start, start + task._obs_widths[term])

    def offset() -> torch.Tensor:
        obs = env.step(torch.zeros(64, 12))[0]
        return obs[:, columns] - built.compute()

    first = offset()
    assert first.abs().max() <= 0.1 and first.abs().max() > 0.09
    assert len(first.unique(dim=0)) == 64
    torch.testing.assert_close(offset(), first, rtol=0, atol=1e-6)  # held
    mask = torch.zeros(64, dtype=torch.bool)
    mask[:32] = True
    env.task.reset(mask, env.task.rng)
    after = offset()
    torch.testing.assert_close(after[32:], first[32:], rtol=0, atol=1e-6)
    assert (after[:32] - first[:32]).abs().max() > 0.01
    # Carried with the env's state, for an exact resume; the other columns have none.
    offset_state = task.state()["observations/offset"]
    torch.testing.assert_close(offset_state[:, columns], after, rtol=0, atol=1e-6)
    assert not offset_state[:, :start].any()
    env.close()
    played = go1(4, "env.observations.joint_pos.bias=0.1", "env.observation_noise=false")
    assert played.task._post.bias is None  # as noise: training only
    played.close()


@pytest.mark.gpu
@needs_warp()
def test_each_world_of_mujoco_warp_steps_with_its_own_gains_and_joints():
    env = go1(16, *GAINS, *JOINTS, backend="warp", device="cuda")
    kp = env.sim.model_field("actuator_gainprm")[:, :, 0].cpu()
    bias = env.sim.model_field("actuator_biasprm").cpu()
    damping = env.sim.model_field("dof_damping")[:, LEGS].cpu()
    kp0 = nominal_kp().float()
    assert ((kp >= 0.5 * kp0 - 1e-4) & (kp <= 1.5 * kp0 + 1e-4)).all()
    assert torch.equal(bias[:, :, 1], -kp) and len(kp.unique(dim=0)) == 16
    assert ((damping >= 0.1 - 1e-6) & (damping <= 0.3 + 1e-6)).all()
    for _ in range(10):
        env.step(torch.zeros(16, 12, device="cuda"))
    assert torch.isfinite(env.sim.qpos).all()
    env.close()
