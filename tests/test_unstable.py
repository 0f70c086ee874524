"""Unstable physics and diverged policies while training: exploding envs are reset and counted
and nothing non-finite reaches the learner; a policy that acts with NaN stops the run with one
line, exit code 3, and its last good checkpoint kept."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch
from typer.testing import CliRunner

from labcli import testing
from labcli.commands.app import app
from labcli.envs import metrics
from labcli.errors import TrainingDiverged
from labcli.plugins import registry
from labcli.runs import checkpoints, rundir, snapshot
from labcli.runs.context import physics_summary
from labcli.runs.plot import read_scalars

SMALL = testing.SMALL_AGENTS
# 1e8 N on a 1 kg cart: strong pushes blow past MuJoCo's limits (or lab's) at once, weak ones
# do not, so envs explode in every iteration and rewards still vary.
EXPLODING = "env.action_scale=1e9"


def finite_policy(name: str, checkpoint: Path) -> bool:
    env = testing.make_env()
    try:
        policy = testing.load_policy(name, checkpoint, env)
    finally:
        env.close()
    return all(torch.isfinite(t).all() for t in [*policy.parameters(), *policy.buffers()])


@pytest.mark.parametrize("name", list(SMALL))
def test_exploding_envs_are_reset_counted_and_keep_nan_from_the_learner(name, tmp_path,
                                                                        monkeypatch, capfd):
    monkeypatch.chdir(tmp_path)  # where MuJoCo would write MUJOCO_LOG.TXT
    outcome = testing.train_small(name, tmp_path / "logs", 3, [*SMALL[name], EXPLODING])
    assert outcome.summary["state"] == rundir.FINISHED
    scalars = read_scalars(outcome.run.dir)
    assert sum(v for _, v in scalars[metrics.INSTABILITIES]) > 0
    assert sum(v for _, v in scalars[metrics.MUJOCO_WARNINGS]) > 0
    assert sum(v for _, v in scalars.get(metrics.NONFINITE_ACTIONS, [])) == 0
    for tag, values in scalars.items():  # losses and learning rates included
        if tag == "train/explained_variance":
            continue  # SB3's diagnostic is NaN by definition when every return is the same
        assert all(math.isfinite(v) for _, v in values), f"{tag}: {values}"
    assert finite_policy(name, registry.get_framework(name).checkpoints(outcome.run.dir)[-1].path)
    # Counted, not printed: no flood on stderr, no log file in the working directory.
    assert "WARNING" not in capfd.readouterr().err
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


UPDATES = {
    "sb3": ("stable_baselines3.ppo.ppo", "PPO", "train"),
    "sb3_sac": ("stable_baselines3.sac.sac", "SAC", "train"),
    "sb3_td3": ("stable_baselines3.td3.td3", "TD3", "train"),
    "rsl_rl": ("rsl_rl.algorithms.ppo", "PPO", "update"),
    "skrl": ("skrl.agents.torch.ppo.ppo", "PPO", "update"),
    # An iteration's updates, one after each of its steps' transitions.
    "skrl_sac": ("lab_skrl.offpolicy", "OffPolicy", "learn"),
    "skrl_td3": ("lab_skrl.offpolicy", "OffPolicy", "learn"),
    # rl_games' rollout and update are one call; the rollout steps no optimizer.
    "rl_games": ("rl_games.common.a2c_common", "ContinuousA2CBase", "train_epoch"),
}


def fill_nan(optimizer: torch.optim.Optimizer) -> None:
    with torch.no_grad():
        for group in optimizer.param_groups:
            for p in group["params"]:
                p.fill_(float("nan"))


def poison_update(monkeypatch, name: str, on_call: int) -> None:
    """The `on_call`-th update of the library's PPO leaves NaN in every parameter it optimizes,
    as a diverged update does."""
    module, cls, method = UPDATES[name]
    owner = getattr(__import__(module, fromlist=[cls]), cls)
    original = getattr(owner, method)
    calls = 0
    step = torch.optim.Adam.step

    def poisoned_step(optimizer, *args, **kwargs):
        out = step(optimizer, *args, **kwargs)
        fill_nan(optimizer)
        return out

    def update(self, *args, **kwargs):
        nonlocal calls
        calls += 1
        if calls != on_call:
            return original(self, *args, **kwargs)
        # From inside the update, where a library may then fail on its NaN (RSL-RL samples
        # with a NaN std) ...
        monkeypatch.setattr(torch.optim.Adam, "step", poisoned_step)
        try:
            out = original(self, *args, **kwargs)
        finally:
            monkeypatch.setattr(torch.optim.Adam, "step", step)
        # ... and after it, for a library whose optimizer steps another way (skrl).
        fill_nan(getattr(self, "optimizer", None) or getattr(self, "policy_optimizer", None)
                 or getattr(getattr(self, "actor", None), "optimizer", None)
                 or self.policy.optimizer)
        return out

    monkeypatch.setattr(owner, method, update)


@pytest.mark.parametrize("name", list(SMALL))
def test_a_diverged_update_stops_training_and_keeps_the_last_good_checkpoint(
        name, tmp_path, monkeypatch):
    poison_update(monkeypatch, name, on_call=3)
    with pytest.raises(TrainingDiverged) as err:  # no checkpoint due before iteration 10
        testing.train_small(name, tmp_path, 10, [*SMALL[name], "agent.save_interval=10"])
    message = str(err.value)
    assert "iteration 3:" in message and "non-finite values" in message
    assert "\n" not in message
    (run_dir,) = {p.parent for p in tmp_path.glob("*/cartpole/*/run.json")}
    fw = registry.get_framework(name)
    good = fw.checkpoints(run_dir)[-1]
    assert good.iteration == 2 and good.path.name in message  # kept since, saved on failure
    assert finite_policy(name, good.path)
    # It resumes exactly, too: iteration 2's env state, held in memory until now, beside it.
    assert snapshot.load(run_dir / "state_2.pt")["iteration"] == 2
    assert checkpoints.complete(fw, good)
    assert not list(run_dir.glob(".candidate")) and not list(run_dir.glob(".good"))
    summary = json.loads((run_dir / rundir.SUMMARY).read_text())
    assert summary["state"] == rundir.FAILED and summary["checkpoint"] == good.path.name
    assert summary["error"] == err.value.message
    assert rundir.run_state(rundir.Run(run_dir)) == rundir.FAILED
    assert not list(run_dir.glob(".tmp_*"))


def test_nan_actions_from_finite_weights_stop_training(tmp_path, monkeypatch):
    """Weights can stay finite while actions overflow: the env sees the NaN and training stops
    at the end of that iteration, naming it."""
    from stable_baselines3.common.policies import ActorCriticPolicy

    forward = ActorCriticPolicy.forward
    calls = 0

    def nan_from_the_third_rollout(self, obs, deterministic=False):
        nonlocal calls
        calls += 1
        actions, values, log_prob = forward(self, obs, deterministic)
        return (actions * float("nan") if calls > 16 else actions), values, log_prob

    monkeypatch.setattr(ActorCriticPolicy, "forward", nan_from_the_third_rollout)
    with pytest.raises(TrainingDiverged) as err:
        testing.train_small("sb3", tmp_path, 10, [*SMALL["sb3"], "agent.save_interval=10"])
    assert str(err.value).startswith("iteration 3: the policy emitted non-finite actions (NaN "
                                     "or inf) in 32 env steps")
    # The weights after update 2 acted in the bad rollout; those after update 1 did well.
    assert "The last good checkpoint is model_1.zip." in str(err.value)
    (run_dir,) = {p.parent for p in tmp_path.glob("sb3/cartpole/*/run.json")}
    assert [c.iteration for c in registry.get_framework("sb3").checkpoints(run_dir)] == [1]
    assert (run_dir / "vecnormalize_1.json").is_file()


def test_a_diverging_cli_run_is_one_line_and_exit_code_3(tmp_path):
    logs = tmp_path / "logs"
    result = CliRunner().invoke(app, [
        "train", "--task", "cartpole", "--framework", "sb3", "--num-envs", "8",
        "--max-iterations", "20", "--set", "agent.n_steps=8", "--set", "agent.batch_size=16",
        "--set", "agent.learning_rate=1e30"], env={"LAB_LOGS_DIR": str(logs)})
    assert result.exit_code == 3, result.output
    error = result.stderr.splitlines()[-1]
    assert error.startswith("error: iteration ") and "non-finite" in error
    assert "Traceback" not in result.stderr
    assert "Traceback" not in result.output
    (summary,) = logs.glob("sb3/cartpole/*/summary.json")
    assert json.loads(summary.read_text())["state"] == rundir.FAILED


def test_kept_states_of_a_killed_run_are_never_committed(tmp_path, monkeypatch):
    """A SIGKILL leaves the hidden kept states behind; a resumed run that diverges at once must
    not bring them back as checkpoints."""
    first = testing.train_small("sb3", tmp_path, 2, SMALL["sb3"])
    run_dir = first.run.dir
    for stale in (".candidate", ".good"):
        (run_dir / stale).mkdir()
        (run_dir / stale / "model_9.zip").write_bytes((run_dir / "model_2.zip").read_bytes())
    poison_update(monkeypatch, "sb3", on_call=1)
    with pytest.raises(TrainingDiverged) as err:
        testing.train_small("sb3", tmp_path, 5, SMALL["sb3"], checkpoint="latest")
    assert "iteration 3:" in str(err.value) and "model_2.zip" in str(err.value)
    assert [c.iteration for c in registry.get_framework("sb3").checkpoints(run_dir)] == [2]


def test_what_the_physics_warned_of_is_one_line_at_the_end(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(app, [
        "train", "--task", "cartpole", "--framework", "rsl_rl", "--num-envs", "8",
        "--max-iterations", "2", "--logs-dir", str(tmp_path), "--set", EXPLODING])
    assert result.exit_code == 0, result.output
    lines = [line for line in result.output.splitlines() if line.startswith("physics: ")]
    assert len(lines) == 1 and "MuJoCo warned" in lines[0], result.output


def test_the_end_line_names_each_overflow_and_the_setting_that_quiets_it():
    line = physics_summary({"NEFC": 12.0, "LS_ITERATIONS": 3400.0, "ITERATIONS": 5.0}, 0, None)
    assert line == (
        "physics: MuJoCo Warp's ITERATIONS limit was reached in 5 env steps (its last iterate "
        "kept; raise env.solver_iterations); MuJoCo Warp's LS_ITERATIONS limit was reached in "
        "3,400 env steps (its last iterate kept; raise env.ls_iterations); MuJoCo Warp's NEFC "
        "buffer overflowed in 12 env steps (those envs reset; raise env.nconmax or env.njmax); "
        "per iteration in TensorBoard (sim/overflow/<name>)")
    assert physics_summary({}, 0, None) is None
