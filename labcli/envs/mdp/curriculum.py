"""Curriculum terms: settings that change as training goes on, by how far it has come."""

from __future__ import annotations

from typing import TYPE_CHECKING

from labcli.envs.mdp import config as c
from labcli.errors import LabError

if TYPE_CHECKING:
    from labcli.envs.mdp.task import RobotTask


class modify_reward_weight:  # noqa: N801 - a term, named as Isaac Lab's
    """Writes the term's weight into the env's weights (`task.reward_weights`) after each step:
    the configured one before `num_steps` env steps, the new one from then on (and each later
    stage's from its own count). The count is the task's `steps`, carried with the env's
    state: a resumed run weighs as the one that never stopped."""

    def __init__(self, task: RobotTask, cfg: c.RewardWeight):
        terms = [name for name, _ in task.cfg.rewards.terms()]
        if cfg.term not in terms:
            raise LabError(f"env.curriculum names reward term '{cfg.term}', which env.rewards "
                           "does not have", f"name one of {terms}")
        self.task = task
        self.index = terms.index(cfg.term)
        per_step = task.step_dt if task.cfg.rewards_per_second else 1.0
        self.start = task.cfg.weights(task.step_dt)[cfg.term]
        self.stages = [(count, weight * per_step)
                       for count, weight in [(cfg.num_steps, cfg.weight), *cfg.then]]

    def __call__(self) -> None:
        weights = self.task.reward_weights
        if weights is not None:  # None: no env weighs this task's rewards
            column = weights[:, self.index]
            column.fill_(self.start)
            for count, weight in self.stages:
                column.masked_fill_(self.task.steps >= count, weight)
