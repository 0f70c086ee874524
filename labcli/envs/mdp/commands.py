"""Command terms: what the robot is asked to do, drawn per env and shown to the policy
(observation `generated_commands`), tracked by rewards and judged by success."""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import torch

from labcli.envs.markers import Marker
from labcli.envs.mdp import config as c
from labcli.envs.mdp import math, names, objects, sensors
from labcli.envs.mdp.events import Uniform, offset_pose, pose_ranges, turns
from labcli.errors import LabError

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
    mirror_signs = (1.0, -1.0, -1.0)  # in the robot's left-right mirror image (symmetry.py)
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


class UniformPoseCommand:
    """`command` `[n, 7]`: the site's target position (m) and orientation (unit quaternion w, x,
    y, z) in the base body's frame; the site's own pose from frame sensors the task adds.

    A fixed base's body does not move: its pose is read once from the model's kinematics at
    qpos0 (`objects.FixedFrame`). The errors are computed once per state (rewards read them);
    `errors` keeps each step's against the command the policy pursued in it, taken before a
    command expiring at that step is drawn again (as at a 12 s time-out with 4 s commands):
    success and the logged metrics judge those. With `reached_within`, `closest` is likewise
    the step's closest distance to the command it pursued since that was drawn."""

    names = ["pos_x", "pos_y", "pos_z", "quat_w", "quat_x", "quat_y", "quat_z"]
    units = ["m, base frame"] * 3 + ["unit quaternion, base frame"] * 4
    carried = ("command", "time_left", "errors", "to_drop")

    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.UniformPoseCommand) -> list[sensors.Sensor]:
        return [sensors.frame("framepos", *cfg.frame), sensors.frame("framequat", *cfg.frame)]

    def __init__(self, task: RobotTask, cfg: c.UniformPoseCommand):
        if task.robot.floating:
            raise LabError(f"a pose command's frame is a fixed base's body ('{cfg.base_body}'), "
                           f"and model '{names.model_name(task.model)}' floats (a free joint)",
                           "command a site of a fixed robot (env.robot.base: fixed)")
        self.task, self.cfg, self.robot = task, cfg, task.robot
        n, like = task.num_envs, task.ones
        self.command = like.new_zeros(n, 7)
        self.command[:, 3] = 1.0
        self.time_left = like.new_zeros(n)
        self.errors = like.new_zeros(n, 2)  # position (m), orientation (rad)
        self.draw = Uniform(task, [cfg.pos_x, cfg.pos_y, cfg.pos_z, cfg.roll, cfg.pitch,
                                   cfg.yaw, cfg.resampling_time_range])
        self.base = objects.fixed_frame(task, cfg.base_body)
        self._site = sensors.columns(task, [[s.name for s in self.sensors(task.model, cfg)]])
        self._target_pos, self._target_quat = self.command[:, :3], self.command[:, 3:]
        # Envs whose object the next step's physics drops anew (`place`).
        self.to_drop = torch.zeros(n, dtype=torch.bool, device=like.device)
        if cfg.place is not None:
            ranges = pose_ranges(cfg.place)
            self._drop = Uniform(task, ranges)
            self._turns = turns(ranges)
            self._object = objects.free_body(task, cfg.body)
            self._home = task.robot.default_qpos[:, self._object.qpos]
        if cfg.reached_within is not None:
            self.closest = like.new_full((n,), torch.inf)
            # Since the current target was drawn: `closest` keeps the step's before a draw.
            self.since_drawn = self.closest.clone()
            self.carried = (*self.carried, "closest", "since_drawn")

    def __call__(self) -> torch.Tensor:
        return self.command

    def site_pose(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The site's (or body's) position `[n, 3]` and orientation `[n, 4]` in the base's
        frame."""
        def compute() -> torch.Tensor:
            pose = self._site()
            return torch.cat((self.base.local(pose[:, :3]),
                              math.quat_mul(self.base.quat_inverse, pose[:, 3:])), dim=1)
        pose = self.robot.per_state(("site_pose", self), compute)
        return pose[:, :3], pose[:, 3:]

    def target_world(self) -> torch.Tensor:
        """The target position in the world frame, `[n, 3]`, once per state."""
        return self.robot.per_state(("target_world", self),
                                    lambda: self.base.world(self._target_pos))

    def markers(self, env: int) -> list[Marker]:
        """The target of env `env`, for videos: its position and orientation in the world."""
        quat = math.quat_mul(self.base.quat[env:env + 1], self._target_quat[env:env + 1])
        return [Marker(self.target_world()[env].tolist(), quat[0].tolist())]

    def position_error(self) -> torch.Tensor:
        """The distance (m) from the site to its target position, `[n]`, once per state."""
        return self.robot.per_state(("position_error", self), lambda: torch.linalg.vector_norm(
            self._target_pos - self.site_pose()[0], dim=1))

    def orientation_error(self) -> torch.Tensor:
        """The rotation angle (rad) from the site's orientation to the target's, `[n]`."""
        def compute() -> torch.Tensor:
            dot = (self._target_quat * self.site_pose()[1]).sum(dim=1).abs().clamp_(max=1.0)
            return torch.acos(dot).mul_(2.0)
        return self.robot.per_state(("orientation_error", self), compute)

    def reset(self, mask: torch.Tensor) -> None:
        # The episode's start places the object itself (a reset event).
        self.to_drop.logical_and_(mask.logical_not())
        self._resample(mask)

    def after_step(self) -> None:
        torch.stack((self.position_error(), self.orientation_error()), dim=1, out=self.errors)
        if self.cfg.reached_within is not None:
            torch.minimum(self.since_drawn, self.errors[:, 0], out=self.since_drawn)
            self.closest.copy_(self.since_drawn)
        self.time_left.sub_(self.task.step_dt)
        expired = self.time_left <= 0.0
        with self.task.rng.only_for(expired) as some:
            if some:
                self._resample(expired)
                if self.cfg.place is not None:
                    self.to_drop.logical_or_(expired)

    def pre_physics(self) -> None:
        """Drops the objects of the envs that drew a target in the last step, before this
        step's physics: the state the terms read after it is the physics' own."""
        if self.cfg.place is None:
            return
        with self.task.rng.only_for(self.to_drop) as some:
            if some:
                home = self._home
                pose = offset_pose(home[:, :3], home[:, 3:], self._drop(), self._turns)
                qpos, qvel = self.task.sim.qpos[:, self._object.qpos], self.task.sim.qvel
                torch.where(self.to_drop[:, None], pose, qpos, out=qpos)
                qvel[:, self._object.qvel].masked_fill_(self.to_drop[:, None], 0.0)
                self.to_drop.zero_()

    def metrics(self) -> dict[str, torch.Tensor]:
        figures = {"position_error": self.errors[:, 0], "orientation_error": self.errors[:, 1]}
        if self.cfg.reached_within is not None:
            figures["reached"] = (self.closest < self.cfg.reached_within).to(self.closest)
        return figures

    def _resample(self, mask: torch.Tensor) -> None:
        if self.cfg.reached_within is not None:
            self.since_drawn.masked_fill_(mask, torch.inf)
        drawn = self.draw()
        quat = math.quat_from_rpy(drawn[:, 3], drawn[:, 4], drawn[:, 5])
        target = torch.cat((drawn[:, :3], quat), dim=1)
        torch.where(mask[:, None], target, self.command, out=self.command)
        torch.where(mask, drawn[:, 6], self.time_left, out=self.time_left)
