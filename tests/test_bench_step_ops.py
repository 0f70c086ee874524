"""bench/bench_step_ops.py: the ops of an env step as a GPU runs it, counted on the CPU."""

from __future__ import annotations

from benchscripts import load

from labcli.envs.env import LabVecEnv

ops = load("bench_step_ops")


def test_a_term_draws_once_with_one_generator_and_once_a_block_with_16():
    reads_on_the_host = LabVecEnv._reads_on_the_host
    one, blocks = (ops.count("cartpole", 32, steps=2, blocks=b) for b in (1, 16))
    random_one = sum(n for name, n in one.items() if name in ops.RANDOM)
    random_blocks = sum(n for name, n in blocks.items() if name in ops.RANDOM)
    assert random_one > 0 and random_blocks == 16 * random_one
    assert sum(blocks.values()) - sum(one.values()) == 15 * random_one
    assert LabVecEnv._reads_on_the_host is reads_on_the_host  # the CPU's own step comes back
