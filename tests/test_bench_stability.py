"""bench/bench_stability.py counts the env steps whose speeds pass its limits, and the large
rewards, under random actions of a given size."""

from __future__ import annotations

import benchscripts


def test_it_counts_the_steps_past_each_speed_and_the_large_rewards():
    bench = benchscripts.load("bench_stability")
    still = bench.count("cartpole", [], envs=8, steps=20, sigma=0.0)
    assert still["past"] == {30: 0, 100: 0, 1000: 0}
    # 100 kN on the cart: it passes 30 and 100 m/s before its rail's end ends the episode.
    shoved = bench.count("cartpole", ["env.action_scale=1e5"], envs=8, steps=20, sigma=5.0)
    assert shoved["past"][30] >= shoved["past"][100] > 0
    assert shoved["past"][100] >= shoved["past"][1000]
    assert shoved["past"][30] <= 8 * 20
    for result in (still, shoved):
        assert 0 <= result["large"] <= 8 * 20 and (result["large"] > 0) == (result["worst"] > 1)
