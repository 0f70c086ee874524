"""The deployment contract of an exported robot policy (labcli/envs/mdp/deployment.py): what
`lab export` writes beside the network, read as a deployer reads it, against the task's own
numbers: go1-flat's joints, gains, limits, default pose, action scale and offset, commands;
ant's observation scales; the same in mjlab's ONNX metadata keys."""

from __future__ import annotations

import json

import mujoco
import onnx
import pytest
from conftest import needs_menagerie
from lab_locomotion.go1 import ROBOT as GO1
from typer.testing import CliRunner

from labcli.commands.app import app
from labcli.envs.task import actuator_name

GO1_HOME = [0.0, 0.9, -1.8] * 4  # Menagerie's home keyframe: hip, thigh, calf of each leg
GO1_EFFORT = [23.7, 23.7, 35.55] * 4  # hip, thigh, calf (tasks/lab_locomotion/go1.py)


def go1_gains(joint: str) -> tuple[float, float]:
    """(kp, kd) of `joint`'s servo, as go1-flat's robot description derives them."""
    return GO1.group_of(joint)[1].gains(GO1.natural_frequency_hz, GO1.damping_ratio)


def _exported(tmp_path, task: str) -> tuple[dict, dict[str, str]]:
    """A 2-iteration rsl_rl run of `task` exported to ONNX: its JSON metadata and the ONNX
    file's metadata props."""
    env = {"LAB_LOGS_DIR": str(tmp_path), "COLUMNS": "200"}
    runner = CliRunner()
    trained = runner.invoke(app, ["train", "--task", task, "--framework", "rsl_rl",
                                  "--num-envs", "8", "--max-iterations", "2"], env=env)
    assert trained.exit_code == 0, trained.output
    exported = runner.invoke(app, ["export", "onnx", "--last"], env=env)
    assert exported.exit_code == 0, exported.output
    (onnx_file,) = tmp_path.glob(f"rsl_rl/{task}/*/exported/policy.onnx")
    meta = json.loads(onnx_file.with_name("policy.onnx.json").read_text())
    props = {p.key: p.value for p in onnx.load(str(onnx_file)).metadata_props}
    assert json.loads(props["lab"])["deployment"] == meta["deployment"]
    return meta, props


@needs_menagerie("unitree_go1")
def test_a_go1_export_says_how_to_drive_each_joint_and_what_commands_it_takes(tmp_path):
    meta, props = _exported(tmp_path, "go1-flat")
    joints = meta["deployment"]["joints"]
    assert [j["joint"] for j in joints] == [a["action"] for a in meta["output"]["actions"]]
    assert [j["default_position"] for j in joints] == pytest.approx(GO1_HOME)
    assert [j["effort_limit"] for j in joints] == pytest.approx(GO1_EFFORT)
    for joint in joints:
        # Position servos with the description's gains; targets = default + 0.25 * action.
        assert (joint["stiffness"], joint["damping"]) == pytest.approx(go1_gains(joint["joint"]))
        assert joint["action_scale"] == 0.25
        assert joint["action_offset"] == joint["default_position"]
        assert joint["command"] == "position target"
    (command,) = meta["deployment"]["commands"]
    assert command["name"] == "base_velocity"
    assert command["ranges"] == {"lin_vel_x": [-1.0, 1.0], "lin_vel_y": [-1.0, 1.0],
                                 "ang_vel_z": [-1.0, 1.0]}
    terms = meta["deployment"]["observations"]
    assert [t["term"] for t in terms] == ["base_lin_vel", "base_ang_vel", "projected_gravity",
                                          "velocity_commands", "joint_pos", "joint_vel",
                                          "actions"]
    names = [o["name"] for o in meta["input"]["observations"]]
    for term in terms:  # the columns partition the input, in order
        lo, hi = term["columns"]
        assert term["names"] == names[lo:hi]
    assert terms[-1]["columns"][1] == len(names)
    assert {t["term"]: t["source"] for t in terms}["velocity_commands"] == "command"
    assert meta["input"]["normalizer_included"] is True
    units = {o["name"]: o["unit"] for o in meta["input"]["observations"]}
    assert all(units.values()), [name for name, unit in units.items() if not unit]
    assert units["velocity_commands.ang_vel_z"] == "rad/s"
    assert units["joint_pos.FL_calf_joint"] == "rad (m for a slide joint) from the default pose"
    # mjlab's keys, for deployment code written against its exports.
    assert props["joint_names"].split(",") == [j["joint"] for j in joints]
    assert [float(v) for v in props["default_joint_pos"].split(",")] == pytest.approx(GO1_HOME)
    assert [float(v) for v in props["joint_stiffness"].split(",")] == pytest.approx(
        [go1_gains(j["joint"])[0] for j in joints])
    assert props["command_names"] == "base_velocity"


def test_an_ant_export_carries_its_observation_scales(tmp_path):
    """ant's joint velocities enter ×0.2 and its foot forces ×0.1: a deployer who fed them raw
    would feed values 5 and 10 times too large."""
    meta, props = _exported(tmp_path, "ant")
    scales = {t["term"]: t["scale"] for t in meta["deployment"]["observations"]}
    assert scales["joint_vel_rel"] == 0.2
    assert [s for name, s in scales.items() if "force" in name or "wrench" in name] == [0.1]
    assert props["observation_terms_scale"].split(",") == [str(s) for s in scales.values()]
    assert all(o["unit"] for o in meta["input"]["observations"])
    # ant's motors: the action is the torque's scale, no gains.
    for joint in meta["deployment"]["joints"]:
        assert joint["stiffness"] is None and joint["command"] == "torque"


def test_an_unnamed_actuator_is_named_after_the_joint_it_drives():
    model = mujoco.MjModel.from_xml_string("""
    <mujoco><worldbody><body><joint name="knee" type="hinge"/><geom size="0.1"/>
      <site name="s"/></body></worldbody>
      <actuator><motor joint="knee"/><motor name="named" joint="knee"/>
      <motor site="s" gear="0 0 0 0 0 1"/></actuator></mujoco>""")
    assert [actuator_name(model, i) for i in range(3)] == [
        "actuator 0 (knee)", "named", "actuator 2"]
