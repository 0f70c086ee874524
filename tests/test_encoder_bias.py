"""mjlab's encoder bias (`EncoderBias`, `JointPos(biased=True)`) on the G1: encoders that read
q + b, position targets taken back by b, the draw carried with the env's state."""

import pytest
import torch
from conftest import needs_menagerie

from labcli.gym import make_env

pytestmark = needs_menagerie("unitree_g1")
MJLAB = "env.events.encoder_bias.bias_range=[-0.015,0.015]"


def g1(*overrides: str, seed: int = 0):
    env = make_env("g1-flat", num_envs=3, seed=seed, backend="cpu", device="cpu",
                   overrides=["env.observation_noise=false", *overrides])
    env.reset()
    return env


def joint_pos_columns(env) -> slice:
    names = env.task.observation_names
    first = names.index("joint_pos.left_hip_pitch_joint")
    return slice(first, first + len(env.task.robot.joint_names))


def test_the_encoders_read_q_plus_b_and_the_servos_aim_at_the_target_minus_b():
    env = g1(MJLAB, "env.events.encoder_bias.joints=[.*_knee_joint]")
    try:
        robot = env.task.robot
        bias = robot.encoder_bias
        knees = [i for i, name in enumerate(robot.joint_names) if name.endswith("_knee_joint")]
        others = [i for i in range(bias.shape[1]) if i not in knees]
        assert (bias[:, knees].abs() <= 0.015).all() and (bias[:, knees] != 0).all()
        assert (bias[:, others] == 0).all()
        assert not torch.equal(bias[0], bias[1])  # per env
        action = torch.full((3, bias.shape[1]), 0.2)
        obs, *_ = env.step(action)
        relative = robot.joint_pos - robot.default_joint_pos
        assert obs[:, joint_pos_columns(env)].double() == pytest.approx(
            (relative + bias).double(), abs=1e-6)
        scales = torch.tensor([g.scale(env.task.cfg.robot.natural_frequency_hz,
                                       env.task.cfg.robot.damping_ratio)
                               for g in _groups(env)], dtype=torch.float64)
        target = robot.default_joint_pos.double() + 0.2 * scales - bias.double()
        assert env.sim.ctrl.double() == pytest.approx(target, abs=1e-6)
    finally:
        env.close()


def _groups(env):
    robot = env.task.cfg.robot
    return [robot.group_of(name)[1] for name in env.task.robot.joint_names]


def test_the_bias_is_carried_with_the_env_s_state_and_not_drawn_again():
    env, twin = g1(MJLAB), g1(MJLAB, seed=1)
    try:
        assert not torch.equal(env.task.robot.encoder_bias, twin.task.robot.encoder_bias)
        twin.set_state(env.get_state())
        assert torch.equal(env.task.robot.encoder_bias, twin.task.robot.encoder_bias)
        twin.reset()  # a later reset keeps the start-up draw
        assert torch.equal(env.task.robot.encoder_bias, twin.task.robot.encoder_bias)
    finally:
        env.close()
        twin.close()


def test_at_a_range_of_zero_nothing_is_drawn_and_the_env_is_as_without_the_event():
    with_event, without = g1(), g1("env.events.encoder_bias=null",
                                   "env.observations.joint_pos.biased=false")
    try:
        actions = torch.rand(5, 3, len(with_event.task.robot.joint_names),
                             generator=torch.Generator().manual_seed(0)) * 2 - 1
        for action in actions:
            a, *_ = with_event.step(action)
            b, *_ = without.step(action)
            assert torch.equal(a, b)
        assert torch.equal(with_event.sim.qpos, without.sim.qpos)
    finally:
        with_event.close()
        without.close()
