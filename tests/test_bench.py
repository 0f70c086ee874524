"""`lab bench`'s protocol: the cpu backend timed in turns with the rollout of what it steps."""

from __future__ import annotations

import functools
import itertools

import torch

from labcli.envs.env import LabVecEnv
from labcli.plugins import registry
from labcli.runs import bench


def test_the_env_and_its_rollout_take_turns_and_each_rate_is_a_median(monkeypatch):
    spec = registry.get_task("cartpole")
    cfg = spec.config_class(num_envs=8, threads=2)
    env, reference = LabVecEnv(spec, cfg, backend="cpu"), LabVecEnv(spec, cfg, backend="cpu")
    timed, figures = [], itertools.count(1)
    after_first_window = {}

    def fake_rate(step, seconds):
        """Steps once for real and reports the next figure: which stepper, in which order."""
        step()
        lab = not isinstance(step, functools.partial)  # the rollout's steppers are partials
        if lab and not timed:
            after_first_window["qpos"] = env.sim.qpos.clone()
        timed.append(("lab" if lab else "rollout", seconds))
        return float(next(figures))

    monkeypatch.setattr(bench, "rate", fake_rate)
    try:
        lab, pool = bench.beside_rollout(env, reference, seconds=1.5, windows=3)
        assert timed == [("lab", 0.5), ("rollout", 0.5), ("rollout", 0.5)] * 3
        # Figures 1, 4, 7 were the env's; 2, 5, 8 and 3, 6, 9 the two chunkings'.
        assert (lab, pool) == (4.0, 6.0)
        # The rollout started from the states the env reached in its first window.
        assert torch.equal(reference.sim.qpos, after_first_window["qpos"])
        assert not torch.equal(env.sim.qpos, after_first_window["qpos"])
    finally:
        env.close()
        reference.close()
