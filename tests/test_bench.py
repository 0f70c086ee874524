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


def test_a_run_is_judged_by_its_first_checkpoint_that_plays_to_success(tmp_path):
    """`played_to_success`: the checkpoints in order, each played as `lab play --checkpoint`
    plays it (one at a time or several at once); the first that reaches the threshold, with the
    training seconds and steps at which it was saved, and the rate of each checkpoint played;
    where none reaches it, every checkpoint's rate."""
    import io
    import json

    from rich.console import Console

    from labcli.runs import play, training

    run = training.train("cartpole", "rsl_rl", num_envs=8, max_iterations=6, logs_dir=tmp_path,
                         console=Console(file=io.StringIO()),
                         overrides=["agent.save_interval=2", "agent.num_steps_per_env=8"]).run
    judged = bench.played_to_success(run.dir, 0.0, episodes=8)
    first = judged["reached"]
    assert first["iteration"] == 2
    _, played = play.play(checkpoint=run.dir / "model_2.pt", episodes=8, seed=1)
    assert first["success"] == played.success_rate
    assert judged["rates"] == [[2, played.success_rate]]
    # Saved after its second iteration's 2 x 8 x 8 steps were logged, within the training.
    summary = json.loads((run.dir / "summary.json").read_text())
    assert first["steps"] == 128 and 0 < first["seconds"] < summary["wall_time_s"]
    # Played two at a time, each in its own process: the same answer.
    assert bench.played_to_success(run.dir, 0.0, episodes=8, workers=2) == judged
    unreached = bench.played_to_success(run.dir, 1.01, episodes=8, workers=2)
    assert unreached["reached"] is None
    assert [iteration for iteration, _ in unreached["rates"]] == [2, 4, 6]
    assert unreached["rates"][0] == judged["rates"][0]
