"""Actuator models whose torques lab computes at every physics step (a robot description's
groups with `model` other than `implicit`), as Isaac Lab's explicit actuators and mjlab's:

- `ideal_pd`: tau = kp (target - q) - kd qd, clipped to +-effort_limit;
- `dc_motor`: that torque within the motor's torque-speed line, from `saturation_effort` at
  rest to 0 at `velocity_limit` (and capped at +-effort_limit): a motor that runs with the
  load can push less, one braking it more;
- `mlp`: a learned actuator net (TorchScript) over the position errors and velocities of the
  last few physics steps, its output times `torque_scale`, within the same line.

The policy's actions stay position targets; the model's actuators of these groups are motors
(`robot_model.apply`) that take the torque as their control. Everything is batched torch over
all envs and runs between the physics steps on both backends (on a GPU inside the step's CUDA
graph), so the sims step one physics step at a time for it (`Sim.step(..., substep=)`).
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from labcli.envs.mdp.description import ActuatorNet, Actuators
from labcli.errors import LabError

if TYPE_CHECKING:
    from labcli.envs.mdp.task import RobotTask


def load_network(net: ActuatorNet, device: torch.device) -> torch.jit.ScriptModule:
    path = Path(net.file).expanduser()
    try:
        with warnings.catch_warnings():
            # torch 2.13 deprecates TorchScript; actuator nets (Isaac Lab's, mjlab's) are such.
            warnings.simplefilter("ignore", DeprecationWarning)
            module = torch.jit.load(str(path), map_location=device)
    except (OSError, RuntimeError, ValueError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise LabError(f"actuator net '{path}' could not be loaded as TorchScript ({first})",
                       "give env.robot.actuators.<group>.network.file a file that "
                       "torch.jit.save wrote") from None
    for parameter in module.parameters():
        parameter.requires_grad_(False)  # its torques are physics, not part of any gradient
    return module.eval()


class _Net:
    """One `mlp` group's network and its history: per env, the position errors and velocities
    of its joints at the last `max(input_idx) + 1` physics steps, newest first."""

    carried = ("errors", "velocities")

    def __init__(self, task: RobotTask, net: ActuatorNet, columns: list[int]):
        n, dev, dtype = task.num_envs, task.sim.qpos.device, task.sim.qpos.dtype
        self.cfg, self.columns = net, torch.tensor(columns, device=dev)
        self.module = load_network(net, dev)
        self.net_dtype = next(iter(self.module.parameters()), torch.empty(0)).dtype
        length = max(net.input_idx) + 1
        self.errors = torch.zeros(n, length, len(columns), dtype=dtype, device=dev)
        self.velocities = torch.zeros_like(self.errors)
        self.index = torch.tensor(net.input_idx, device=dev)

    def reset(self, mask: torch.Tensor) -> None:
        self.errors.masked_fill_(mask[:, None, None], 0.0)
        self.velocities.masked_fill_(mask[:, None, None], 0.0)

    def __call__(self, error: torch.Tensor, velocity: torch.Tensor) -> torch.Tensor:
        """The group's torques `[num_envs, joints]` from this physics step's error and velocity
        (of all explicit joints; this group's columns are taken here)."""
        for history, now in ((self.errors, error), (self.velocities, velocity)):
            history.copy_(history.roll(1, dims=1))
            history[:, 0] = now.index_select(1, self.columns)
        n, joints = self.errors.shape[0], self.errors.shape[2]
        # Per joint, its steps side by side: [num_envs * joints, len(input_idx)] each half.
        pos = self.errors.index_select(1, self.index).transpose(1, 2).reshape(n * joints, -1)
        vel = self.velocities.index_select(1, self.index).transpose(1, 2).reshape(n * joints, -1)
        pos, vel = pos * self.cfg.pos_scale, vel * self.cfg.vel_scale
        halves = (pos, vel) if self.cfg.input_order == "pos_vel" else (vel, pos)
        out = self.module(torch.cat(halves, dim=1).to(self.net_dtype))
        return out.reshape(n, joints).to(error.dtype) * self.cfg.torque_scale


class ExplicitMotors:
    """The torques of every explicit group's joints, written into `sim.ctrl` before each
    physics step; the implicit groups' servos get their targets as they are. `targets` are the
    position targets the action term writes, `[num_envs, nu]`, or (a motor latency) each
    physics step's, `[decimation, num_envs, nu]` in `delayed`."""

    # Per env: the gains, which `randomize_actuator_gains` may draw per env.
    carried = ("kp", "kd")

    def __init__(self, task: RobotTask, targets: torch.Tensor,
                 delayed: torch.Tensor | None = None):
        robot = task.cfg.robot
        assert robot is not None  # made only where a description has explicit groups
        sim, model = task.sim, task.model
        dev, dtype = sim.qpos.device, sim.qpos.dtype
        self.sim, self.targets, self.delayed = sim, targets, delayed
        groups: list[tuple[str, Actuators]] = []
        for joint in task.robot.joint_names:
            found = robot.group_of(joint)
            assert found is not None  # robot_model.apply refused such a joint
            groups.append(found)
        explicit = [i for i, (_, g) in enumerate(groups) if g.explicit]
        self.explicit = torch.tensor(explicit, device=dev)
        self._columns = {actuator: k for k, actuator in enumerate(explicit)}
        self.implicit = torch.tensor([i for i, (_, g) in enumerate(groups) if not g.explicit],
                                     dtype=torch.long, device=dev)
        ids = [task.robot.joint_ids[i] for i in explicit]
        self.qadr = torch.tensor([int(model.jnt_qposadr[j]) for j in ids], device=dev)
        self.dadr = torch.tensor([int(model.jnt_dofadr[j]) for j in ids], device=dev)
        f, zeta = robot.natural_frequency_hz, robot.damping_ratio
        chosen = [groups[i][1] for i in explicit]
        self.groups = [groups[i][0] for i in explicit]
        self.models = [g.model for g in chosen]

        def row(values: list[float]) -> torch.Tensor:
            return torch.tensor(values, dtype=dtype, device=dev)

        self.gains = [g.gains(f, zeta) for g in chosen]  # nominal, as the export states them
        n = sim.num_envs
        self.kp = row([kp for kp, _ in self.gains]).expand(n, len(explicit)).contiguous()
        self.kd = row([kd for _, kd in self.gains]).expand(n, len(explicit)).contiguous()
        self.effort = row([g.effort_limit for g in chosen])
        # An ideal PD has a flat torque-speed line: its effort at rest, no speed limit.
        self.saturation = row([g.effort_limit if g.model == "ideal_pd"
                               else g.saturation_effort or g.effort_limit for g in chosen])
        self.velocity = row([math.inf if g.model == "ideal_pd" else g.velocity_limit or math.inf
                             for g in chosen])
        self.nets: dict[str, _Net] = {}
        for name in dict.fromkeys(self.groups):
            group = robot.actuators[name]
            if group.model == "mlp":
                assert group.network is not None  # the description's validator
                self.nets[name] = _Net(task, group.network,
                                       [k for k, g in enumerate(self.groups) if g == name])
        self._q = torch.empty(n, len(explicit), dtype=dtype, device=dev)
        self._qd = torch.empty_like(self._q)

    def __call__(self, k: int) -> None:
        """Before physics step `k` of an env step: the controls from the state now."""
        target = self.targets if self.delayed is None else self.delayed[k]
        torch.index_select(self.sim.qpos, 1, self.qadr, out=self._q)
        torch.index_select(self.sim.qvel, 1, self.dadr, out=self._qd)
        error = target.index_select(1, self.explicit) - self._q
        torque = self.kp * error - self.kd * self._qd
        for net in self.nets.values():
            torque[:, net.columns] = net(error, self._qd)
        ctrl = self.sim.ctrl
        ctrl[:, self.explicit] = self.limited(torque, self._qd)
        if len(self.implicit):
            ctrl[:, self.implicit] = target.index_select(1, self.implicit)

    def limited(self, torque: torch.Tensor, velocity: torch.Tensor) -> torch.Tensor:
        """`torque` within each motor's torque-speed line and effort limit (Isaac Lab's
        `DCMotor._clip_effort`; for an ideal PD, +-effort_limit)."""
        speed = velocity / self.velocity
        high = (self.saturation * (1.0 - speed)).clamp_(min=0.0).minimum(self.effort)
        low = (self.saturation * (-1.0 - speed)).clamp_(max=0.0).maximum(-self.effort)
        return torque.clamp(low, high)

    def column(self, actuator: int) -> int | None:
        """Where actuator `actuator` is among the explicit ones; None: an implicit servo."""
        return self._columns.get(actuator)

    def describe(self, actuator: int) -> dict[str, object] | None:
        """What a deployer must know of actuator `actuator`'s model (None: an implicit servo):
        its law's numbers, nominal, for the export's metadata."""
        k = self.column(actuator)
        if k is None:
            return None
        # A net's torque is its own: no PD gains.
        kp, kd = self.gains[k] if self.models[k] != "mlp" else (None, None)
        row: dict[str, object] = {"model": self.models[k], "stiffness": kp, "damping": kd}
        if self.models[k] != "ideal_pd":
            row |= {"saturation_effort": float(self.saturation[k]),
                    "velocity_limit": (None if math.isinf(self.velocity[k])
                                       else float(self.velocity[k]))}
        if self.models[k] == "mlp":
            row["network"] = self.nets[self.groups[k]].cfg.model_dump()
        return row
