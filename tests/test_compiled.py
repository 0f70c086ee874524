"""The cpu backend's compiled env step (`env.compile`): what the eager step computes, the same
outputs in shards as in one process, and a step it cannot compile named in one line."""

from __future__ import annotations

import dataclasses
import re
import shutil

import pytest
import torch
from conftest import needs_menagerie
from lab_cartpole.cartpole import Cartpole
from test_shards import assert_same, build, trajectory

from labcli.envs.env import EPISODE, LabVecEnv
from labcli.errors import LabError
from labcli.gym import make_env
from labcli.plugins import registry

# Inductor compiles the step's C++ with the machine's compiler.
pytestmark = pytest.mark.skipif(not (shutil.which("g++") or shutil.which("c++")),
                                reason="no C++ compiler")


def test_a_compiled_step_gives_the_same_outputs_in_shards_and_in_one_process(tmp_path,
                                                                             monkeypatch, capfd):
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", str(tmp_path))
    # 60 steps of random pushes: episodes end and reset in both shards.
    one = build("cartpole", 128, compile=True)
    ended = []
    try:
        alone = trajectory(one, 60)
        ended = alone[6::10]  # every step's `_lab_episode`
    finally:
        one.close()
    assert torch.stack(ended).any()
    assert _notices(capfd.readouterr().err) == (1, 1)
    sharded = build("cartpole", 128, shards=2, compile=True)
    try:
        assert_same(alone, trajectory(sharded, 60))
    finally:
        sharded.close()
    # The sharded env says it compiles once, in the caller; its workers (their stderr is the
    # terminal's too) say nothing.
    assert _notices(capfd.readouterr().err) == (1, 1)
    # One entry a compiled part (before and after the physics) for each of the two shapes:
    # 128 envs alone, 64 a shard. The worker's shard loaded what the caller's compiled; had it
    # compiled again (another key, e.g. another thread count), it would have written its own.
    assert len([f for f in (tmp_path / "fxgraph").rglob("*") if f.is_file()]) == 4


def _notices(err: str) -> tuple[int, int]:
    """How many lines of `err` say that the env step compiles, and that it compiled."""
    lines = err.splitlines()
    return (sum(line.startswith("compiling the env step (env.compile=true;") for line in lines),
            sum(re.fullmatch(r"env step compiled in \d+ s", line) is not None for line in lines))


def test_a_compiled_step_computes_what_the_eager_step_computes():
    """Until an env resets (then the compiled step, which draws on every step, draws other
    numbers), its outputs are the eager step's up to the order of a float sum."""
    eager, compiled = build("cartpole", 64), build("cartpole", 64, compile=True)
    try:
        for env in (eager, compiled):
            env.reset(seed=3)
        actions = torch.linspace(-0.2, 0.2, 64)[:, None]
        for _ in range(15):  # the trace's step, then the compiled code's
            a, b = eager.step(actions), compiled.step(actions)
            assert not a[4][f"_{EPISODE}"].any()
            torch.testing.assert_close(b[0], a[0], rtol=1e-6, atol=1e-6)
            torch.testing.assert_close(b[1], a[1], rtol=1e-6, atol=1e-6)
            assert torch.equal(a[2], b[2]) and torch.equal(a[3], b[3])
            torch.testing.assert_close(b[4][EPISODE]["r"], a[4][EPISODE]["r"], rtol=1e-5,
                                       atol=1e-5)
        assert torch.equal(compiled.get_state()["episode_length"], torch.full((64,), 15))
    finally:
        eager.close()
        compiled.close()


@needs_menagerie("unitree_g1")
def test_a_compiled_step_gives_the_critic_observations_the_eager_step_gives(tmp_path,
                                                                            monkeypatch):
    """A task's critic observations, and an ended episode's last ones, are outputs of the
    compiled part too: the policy's terms without noise and the critic's own (the G1's feet;
    the compiled step takes the reset path every step, which the eager one skips). Without
    pushes nothing but the policy's noise is drawn over these steps, and the critic's have
    none: the eager step's exactly."""
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", str(tmp_path))
    settings = ["env.critic_observations=privileged", "env.events.push_robot=null"]
    eager, compiled = (make_env("g1-flat", num_envs=8, seed=0, backend="cpu", device="cpu",
                                overrides=[*settings, f"env.compile={str(c).lower()}"])
                       for c in (False, True))
    try:
        first = [env.reset(seed=3)[1]["critic_obs"] for env in (eager, compiled)]
        assert torch.equal(*first)
        actions = torch.full((8, eager.single_action_space.shape[0]), 0.2)
        for _ in range(4):  # the trace's step, then the compiled code's
            a, b = eager.step(actions)[4], compiled.step(actions)[4]
            for key in ("critic_obs", "final_critic_obs"):
                assert torch.equal(a[key], b[key]), key
    finally:
        eager.close()
        compiled.close()


class _HostReadingCartpole(Cartpole):
    def update(self) -> None:
        super().update()
        if self.out_of_bounds.any():  # a host read: fine eager, not in a traced step
            self.pole_angle.add_(0.0)


def test_a_step_that_reads_the_host_cannot_be_compiled_and_says_so():
    spec = dataclasses.replace(registry.get_task("cartpole"), name="cartpole_host",
                               task=_HostReadingCartpole)
    env = LabVecEnv(spec, spec.config_class(num_envs=4, compile=True), backend="cpu")
    try:
        env.reset(seed=0)
        with pytest.raises(LabError, match=r"could not be traced.*--set env.compile=false"):
            env.step(torch.zeros(4, 1))
    finally:
        env.close()
