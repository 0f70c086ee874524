"""The task conformance suite (`labcli.testing.check_task`): the built-in tasks pass it, and a
task that breaks one of its rules fails it with a line that names the rule."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from conftest import needs_menagerie
from lab_cartpole.cartpole import Cartpole

from labcli.plugins import registry
from labcli.plugins.hookspecs import hookimpl
from labcli.testing import check_task, check_task_outputs, check_task_resume


@pytest.mark.parametrize("task", [
    "cartpole", "ant", "humanoid", "go1-rough",
    pytest.param("go1-flat", marks=needs_menagerie("unitree_go1")),
    pytest.param("go2-flat", marks=needs_menagerie("unitree_go2")),
    pytest.param("g1-flat", marks=needs_menagerie("unitree_g1")),
    pytest.param("g1-rough", marks=needs_menagerie("unitree_g1")),
    pytest.param("panda-reach", marks=needs_menagerie("franka_emika_panda")),
    pytest.param("panda-lift", marks=needs_menagerie("franka_emika_panda")),
    pytest.param("yam-lift", marks=needs_menagerie("i2rt_yam"))])
def test_the_built_in_tasks_pass_the_task_checks(task):
    check_task(task)


class ForgetfulCartpole(Cartpole):
    """Counts its steps into its first observation, a count its state leaves out: a resumed
    env starts counting again."""

    def __init__(self, cfg, sim):
        super().__init__(cfg, sim)
        self.steps = torch.zeros_like(self._cart_pos)

    def after_step(self) -> None:
        self.steps += 1

    def observations(self) -> torch.Tensor:
        obs = super().observations()
        obs[:, 0] += self.steps
        return obs


class NaNCartpole(Cartpole):
    """Its pole's velocity reads NaN in env 1 (which the env feeds the policy as 0)."""

    def observations(self) -> torch.Tensor:
        obs = super().observations()
        obs[1, 3] = float("nan")
        return obs


class BrokenTasks:
    """cartpole's spec under other names, with the tasks above."""

    def __init__(self, cartpole):
        self.cartpole = cartpole

    @hookimpl
    def register_tasks(self, register):
        for name, cls in (("forgetful", ForgetfulCartpole), ("nan", NaNCartpole)):
            register(dataclasses.replace(self.cartpole, name=name,
                                         task=f"{__name__}:{cls.__name__}"))


@pytest.fixture
def broken(register_plugin) -> None:
    register_plugin(BrokenTasks(registry.get_task("cartpole")), "broken-tasks")


def test_state_a_task_does_not_carry_fails_the_resume_check(broken):
    check_task_outputs("forgetful")  # its outputs are fine
    with pytest.raises(AssertionError, match="task 'forgetful': a resumed env differs at step 1 "
                                             "in its observations"):
        check_task_resume("forgetful")


def test_an_observation_that_is_not_finite_fails_the_outputs_check(broken):
    with pytest.raises(AssertionError, match=r"task 'nan': its observations \['pole_vel'\] at "
                                             "reset are not finite"):
        check_task("nan")
