"""Command terms: what the robot is asked to do, drawn per env and shown to the policy
(observation `generated_commands`), tracked by rewards and judged by success."""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from labcli.envs.mdp import config as c
from labcli.envs.mdp import math
from labcli.envs.mdp.events import Uniform

if TYPE_CHECKING:
    from labcli.envs.mdp.task import RobotTask

# A forward-only command's least forward speed (m/s), mjlab's.
FORWARD_MIN_SPEED = 0.3


class UniformVelocityCommand:
    """`command` `[n, 3]`: lin x, lin y (m/s) and yaw rate (rad/s) in the base's frame.

    Isaac Lab's order within a step: the step's rewards see the command the policy saw; then
    (`after_step`) the errors are counted, expired commands drawn again and the heading
    envs' yaw rates steered from the new state, which the next observation shows."""

    names = ["lin_vel_x", "lin_vel_y", "ang_vel_z"]
    units = ["m/s, root frame", "m/s, root frame", "rad/s"]
    carried = ("command", "heading", "time_left", "heading_env", "standing_env", "forward_env",
               "errors", "steps", "mean_errors", "averaged_error")

    def __init__(self, task: RobotTask, cfg: c.UniformVelocityCommand):
        self.task, self.cfg, self.robot = task, cfg, task.robot
        n, like = task.num_envs, task.ones
        self.command = like.new_zeros(n, 3)
        if task.terrain is not None:  # its curriculum asks for the distance commanded
            task.terrain.follow_command(self.command)
        self.heading = like.new_zeros(n)
        self.time_left = like.new_zeros(n)
        self.heading_env = torch.zeros(n, dtype=torch.bool, device=like.device)
        self.standing_env = torch.zeros_like(self.heading_env)
        self.forward_env = torch.zeros_like(self.heading_env)
        # The forward-only draw is made only where some envs may be: a task without them draws
        # the numbers it always drew.
        self.forwards = cfg.rel_forward_envs > 0.0
        self.draw = Uniform(task, [cfg.lin_vel_x, cfg.lin_vel_y, cfg.ang_vel_z, cfg.heading,
                                   cfg.resampling_time_range, (0.0, 1.0), (0.0, 1.0),
                                   *([(0.0, 1.0)] if self.forwards else [])])
        self._forward = like.new_zeros(n, 3)  # lin x set at each draw; lin y, yaw rate 0
        # Per-episode sums of the tracking errors, the steps they sum, and their means (once
        # per step: success and the logged metrics read them).
        self.errors = like.new_zeros(n, 2)
        self.steps = like.new_zeros(n)
        self.mean_errors = like.new_zeros(n, 2)
        # The error averaged over cfg.error_window s, and its weight on each new step's error.
        self.window = cfg.error_window > 0.0
        self.averaged_error = like.new_zeros(n, 3)
        self._averaged_lin = self.averaged_error[:, :2]
        self._averaged_yaw = self.averaged_error[:, 2]
        self._new_weight = min(1.0, task.step_dt / cfg.error_window) if self.window else 1.0
        # Views taken once: each step reads them, and indexing costs as much as an op.
        self._lin_xy, self._yaw_rate = self.command[:, :2], self.command[:, 2]
        self._robot_lin_xy = self.robot.root_lin_vel_b[:, :2]
        self._robot_yaw_rate = self.robot.root_ang_vel_b[:, 2]
        self._errors_lin, self._errors_yaw = self.errors.unbind(1)
        self._standing = self.standing_env[:, None]

    def __call__(self) -> torch.Tensor:
        return self.command

    def lin_vel_error(self) -> torch.Tensor:
        """The command's planar velocity minus the base's, `[n, 2]`, once per state: the
        tracking reward and the episode's error both read it."""
        return self.robot.per_state(("lin_vel_error", self), lambda: (
            torch.sub(self._lin_xy, self._robot_lin_xy)))

    def yaw_rate_error(self) -> torch.Tensor:
        """The command's yaw rate minus the base's, `[n]`, once per state."""
        return self.robot.per_state(("yaw_rate_error", self), lambda: (
            torch.sub(self._yaw_rate, self._robot_yaw_rate)))

    def reset(self, mask: torch.Tensor) -> None:
        self.errors.masked_fill_(mask[:, None], 0.0)
        self.mean_errors.masked_fill_(mask[:, None], 0.0)
        self.steps.masked_fill_(mask, 0.0)
        self._resample(mask)
        # The env recomputes what the robot derives after the reset, not yet: the heading is
        # the root quaternion's.
        self._steer(math.yaw_of(self.robot.root_quat))
        # An episode starts from rest (up to its reset's push): its error is the command.
        torch.where(mask[:, None], self.command, self.averaged_error, out=self.averaged_error)

    def after_step(self) -> None:
        if self.window:
            lin, yaw = self._averaged_lin, self._averaged_yaw
            lin.lerp_(self.lin_vel_error(), self._new_weight)
            yaw.lerp_(self.yaw_rate_error(), self._new_weight)
        else:
            lin, yaw = self.lin_vel_error(), self.yaw_rate_error()
        self._errors_lin.add_(torch.linalg.vector_norm(lin, dim=1))
        self._errors_yaw.add_(yaw.abs())
        self.steps.add_(1.0)
        torch.div(self.errors, self.steps[:, None], out=self.mean_errors)
        self.time_left.sub_(self.task.step_dt)
        expired = self.time_left <= 0.0
        # Most steps no command expires: on the CPU the draw and its masked writes are skipped.
        with self.task.rng.only_for(expired) as some:
            if some:
                self._resample(expired)
        self._steer(self.robot.yaw)

    def metrics(self) -> dict[str, torch.Tensor]:
        return {"error_vel_xy": self.mean_errors[:, 0], "error_vel_yaw": self.mean_errors[:, 1]}

    def _resample(self, mask: torch.Tensor) -> None:
        cfg, drawn = self.cfg, self.draw()
        m = mask[:, None]
        torch.where(m, drawn[:, :3], self.command, out=self.command)
        torch.where(mask, drawn[:, 3], self.heading, out=self.heading)
        torch.where(mask, drawn[:, 4], self.time_left, out=self.time_left)
        torch.where(mask, drawn[:, 5] <= cfg.rel_heading_envs, self.heading_env,
                    out=self.heading_env)
        torch.where(mask, drawn[:, 6] <= cfg.rel_standing_envs, self.standing_env,
                    out=self.standing_env)
        if self.forwards:  # mjlab's forward-only envs: |lin x|, at least 0.3 m/s, straight on
            torch.where(mask, drawn[:, 7] <= cfg.rel_forward_envs, self.forward_env,
                        out=self.forward_env)
            torch.clamp(self._lin_xy[:, 0].abs(), min=FORWARD_MIN_SPEED, out=self._forward[:, 0])
            torch.where((mask & self.forward_env)[:, None], self._forward, self.command,
                        out=self.command)

    def _steer(self, yaw: torch.Tensor) -> None:
        """The heading envs' yaw rate toward their heading, from the root's `yaw`; the standing
        envs' command 0."""
        cfg = self.cfg
        if cfg.heading_command:
            error = math.wrap_to_pi(self.heading - yaw)
            rate = (error * cfg.heading_control_stiffness).clamp(*cfg.ang_vel_z)
            torch.where(self.heading_env, rate, self._yaw_rate, out=self._yaw_rate)
        self.command.masked_fill_(self._standing, 0.0)
