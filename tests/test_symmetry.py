"""The robots' left-right mirror images (labcli.envs.mdp.symmetry) against real MuJoCo: the
mirror image of a state moves as the mirror image of the state under mirrored actions, and
RSL-RL trains with symmetry augmentation."""

from __future__ import annotations

import pytest
import torch
from conftest import needs_menagerie
from typer.testing import CliRunner

from labcli.commands.app import app
from labcli.envs.mdp.symmetry import AXIAL, POLAR, mirror_of
from labcli.errors import LabError
from labcli.gym import make_env
from labcli.runs import plot, training

pytestmark = [needs_menagerie("unitree_go1"), needs_menagerie("unitree_go2"),
              needs_menagerie("unitree_g1"), needs_menagerie("franka_emika_panda")]

# Nothing that would break the symmetry of two envs: no noise, pushes or per-env masses.
STILL = ["env.observation_noise=false", "env.events.push_robot=null",
         "env.events.add_base_mass=null", "env.events.base_com=null",
         "env.events.foot_friction=null"]


def _quiet(task: str) -> list[str]:
    events = make_env(task, num_envs=1).task.cfg.events.terms()
    return [o for o in STILL if not o.startswith("env.events.")
            or o.split(".")[2].split("=")[0] in dict(events)]


@pytest.mark.parametrize("task", ["go1-flat", "go2-flat", "g1-flat", "g1-rough"])
def test_each_mirror_map_is_its_own_inverse_and_moves_every_left_column_right(task):
    env = make_env(task, num_envs=3, seed=0)
    mirror = mirror_of(env.task)
    obs, _ = env.reset(seed=0)
    assert torch.equal(mirror.observations(mirror.observations(obs)), obs)
    actions = torch.randn(3, env.single_action_space.shape[0])
    assert torch.equal(mirror.actions(mirror.actions(actions)), actions)
    names = env.task.observation_names
    for i, name in enumerate(names):
        image = names[int(mirror.obs_index[i])]
        for left, right in (("left_", "right_"), ("FL_", "FR_"), ("RL_", "RR_")):
            if left in name:
                assert image == name.replace(left, right)
    index = {name: i for i, name in enumerate(names)}
    for term, signs in (("base_lin_vel", POLAR), ("base_ang_vel", AXIAL),
                        ("projected_gravity", POLAR)):
        got = [float(mirror.obs_sign[index[f"{term}.{axis}"]]) for axis in "xyz"]
        assert got == list(signs)
    assert float(mirror.obs_sign[index["velocity_commands.lin_vel_y"]]) == -1.0
    if task == "g1-rough":  # the scan's point at y = +0.5 m looks at the one at -0.5 m
        assert names[int(mirror.obs_index[index["height_scan.+0.80,+0.50"]])] == \
            "height_scan.+0.80,-0.50"


def _mirror_state(env, state: dict, mirror) -> dict:
    """Env 1 of `state` made the mirror image of env 0, through the world's x-z plane."""
    robot = env.task.robot
    qpos, qvel = state["qpos"].clone(), state["qvel"].clone()
    q0, v0 = qpos[0], qvel[0]
    qpos[1, :7] = q0[:7] * torch.tensor([1, -1, 1, 1, -1, 1, -1], dtype=q0.dtype)
    qvel[1, :6] = v0[:6] * torch.tensor([1, -1, 1, -1, 1, -1], dtype=v0.dtype)
    model = env.sim.model
    qidx = torch.tensor([int(model.jnt_qposadr[j]) for j in robot.joint_ids])
    didx = torch.tensor([int(model.jnt_dofadr[j]) for j in robot.joint_ids])
    qpos[1, qidx] = mirror.actions(q0[qidx][None])[0]
    qvel[1, didx] = mirror.actions(v0[didx][None])[0]
    state = {**state, "qpos": qpos, "qvel": qvel}
    for key in ("task/action", "task/previous_action"):
        state[key] = state[key].clone()
        state[key][1] = mirror.actions(state[key][:1])[0]
    # The velocity command, its heading and kind of env: the mirror image's.
    for key, sign in (("command", torch.tensor([1.0, -1.0, -1.0])), ("heading", -1.0),
                      ("time_left", 1.0), ("heading_env", None), ("standing_env", None),
                      ("forward_env", None)):
        key = f"task/base_velocity/{key}"
        state[key] = state[key].clone()
        state[key][1] = state[key][0] if sign is None else state[key][0] * sign
    return state


@pytest.mark.parametrize("task", ["go1-flat", "g1-flat"])
def test_the_mirror_image_of_a_state_moves_as_its_mirror_image_under_mirrored_actions(task):
    env = make_env(task, num_envs=2, seed=0, overrides=_quiet(task))
    mirror = mirror_of(env.task)
    env.reset(seed=0)
    torch.manual_seed(0)
    n = env.single_action_space.shape[0]
    for _ in range(10):  # somewhere off the default pose, moving
        env.step(0.5 * torch.randn(1, n).expand(2, n))
    env.set_state(_mirror_state(env, env.get_state(), mirror))
    # The pose: joints and the gravity's direction. Menagerie's models are symmetric to within
    # their CAD inertias (the Go1's trunk's centre of mass is 2 mm left of its middle): over
    # 25 steps the two drift 0.009 apart at most; one joint's sign wrong in the map, 0.05-0.65.
    names = env.task.observation_names
    pose = torch.tensor([name.startswith(("joint_pos.", "projected_gravity.")) for name in names])
    for _ in range(25):
        action = 0.5 * torch.randn(1, n)
        obs, *_ = env.step(torch.cat([action, mirror.actions(action)]))
        apart = (obs[1] - mirror.observations(obs[:1])[0]).abs() * pose
        assert apart.max() < 0.02, names[int(apart.argmax())]


def test_a_robot_without_a_declared_mirror_is_one_line(tmp_path):
    # go1-rough's Go1 is the datasheet model, with no robot description; panda-reach's Panda
    # declares no mirror.
    with pytest.raises(LabError, match="has no robot description"):
        mirror_of(make_env("go1-rough", num_envs=1).task)
    with pytest.raises(LabError, match="declares none"):
        mirror_of(make_env("panda-reach", num_envs=1).task)
    result = CliRunner().invoke(app, [
        "train", "--task", "ant", "--framework", "rsl_rl", "--num-envs", "2",
        "--max-iterations", "1", "--set", "agent.symmetry_augmentation=true"],
        env={"LAB_LOGS_DIR": str(tmp_path), "COLUMNS": "200"})
    assert result.exit_code == 2, result.output
    assert "has no robot description" in result.stderr and "Traceback" not in result.output
    assert not any(tmp_path.rglob("run.json"))


def test_rsl_rl_learns_from_each_mini_batch_and_its_mirror_image(tmp_path):
    outcome = training.train(
        "go1-flat", "rsl_rl", num_envs=8, max_iterations=2, logs_dir=tmp_path, seed=0,
        overrides=["agent.num_steps_per_env=8", "agent.num_mini_batches=2",
                   "agent.num_learning_epochs=1", "agent.actor_hidden_dims=[16]",
                   "agent.critic_hidden_dims=[16]", "agent.symmetry_augmentation=true",
                   "agent.mirror_loss_coef=0.1"])
    assert outcome.summary["iterations"] == 2
    # RSL-RL logs the mirror loss only when its symmetry extension ran in the update.
    losses = plot.read_scalars(outcome.run.dir)["Loss/symmetry"]
    assert len(losses) == 2 and all(v > 0 for _, v in losses)
