"""bench/model_diff.py: a model's physics dumped by name, and two dumps compared field by
field with mjlab's entity prefixes stripped."""

from __future__ import annotations

import benchscripts
import pytest
from conftest import needs_menagerie


@pytest.fixture(scope="module")
def model_diff():
    return benchscripts.load("model_diff")


def test_prefixes_are_stripped_and_entries_only_one_side_has_are_named(model_diff):
    mjlab = {"bodies": {"robot/link_6": {"mass": 0.367476, "gravcomp": 0.0},
                        "terrain": {"mass": 0.0, "gravcomp": 0.0}},
             "actuators": {"on robot/joint1": {"gain": [19.4475], "forcerange": [-28, 28]}}}
    lab = {"bodies": {"link_6": {"mass": 0.3674761, "gravcomp": 1.0}},
           "actuators": {"on joint1": {"gain": [19.44751], "forcerange": [-28, 28]}}}
    assert model_diff.compare(mjlab, lab) == ["bodies link_6: gravcomp 0.0 | 1.0",
                                              "bodies terrain: only in the first"]


@needs_menagerie("i2rt_yam")
def test_a_setting_of_the_robot_shows_as_the_fields_it_changes(model_diff):
    """yam-lift with Menagerie's control range on the gripper against its default."""
    free = model_diff.dump(model_diff.lab_model("yam-lift", []))
    kept = model_diff.dump(model_diff.lab_model(
        "yam-lift", ["env.robot.actuators.gripper.clip_targets=true"]))
    assert model_diff.compare(free, kept) == [
        "actuators on left_finger: ctrllimited False | True",
        "actuators on left_finger: ctrlrange None | [0.0, 0.041]"]
    assert free["actuators"]["on left_finger"]["forcerange"] == pytest.approx([-38.03, 38.03],
                                                                             abs=0.01)
    assert free["bodies"]["link_2"]["gravcomp"] == 0.0  # weighing, as mjlab's
    weightless = model_diff.dump(model_diff.lab_model(
        "yam-lift", ["env.robot.gravity_compensation=true"]))
    assert "bodies link_2: gravcomp 0.0 | 1.0" in model_diff.compare(free, weightless)
