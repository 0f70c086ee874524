"""Both backends from one state: the cpu env's state lifted off the floor and copied to the
warp env, then the same actions on both; the largest gaps of observations and rewards."""

from __future__ import annotations

import torch


def lift_and_copy(cpu, gpu, height: float = 1.0) -> None:
    """Lift every cpu env `height` m (the root's free joint comes first in qpos) and give the
    gpu env the same state, in float32 (its generator stays its own)."""
    lifted = cpu.get_state()
    lifted["qpos"][:, 2] += height
    cpu.set_state(lifted)
    state = {k: (v.to("cuda", torch.float32) if v.is_floating_point() else v.to("cuda"))
             for k, v in lifted.items() if k != "generator"}
    state["generator"] = gpu.get_state()["generator"]
    gpu.set_state(state)


def worst_gaps(cpu, gpu, steps: int = 10, seed: int = 1) -> tuple[float, float]:
    """The same `steps` of uniform random actions on both: the largest absolute differences of
    observations and of rewards."""
    shape = (steps, cpu.num_envs, len(cpu.action_names))
    actions = torch.rand(shape, generator=torch.Generator().manual_seed(seed)) * 2 - 1
    worst_obs = worst_reward = 0.0
    for a in actions:
        o_cpu, r_cpu, *_ = cpu.step(a)
        o_gpu, r_gpu, *_ = gpu.step(a.cuda())
        worst_obs = max(worst_obs, (o_gpu.cpu() - o_cpu).abs().max().item())
        worst_reward = max(worst_reward, (r_gpu.cpu().double() - r_cpu).abs().max().item())
    return worst_obs, worst_reward
