"""`--checkpoint best`: each checkpoint's manifest records the success and return of the
episodes that ended since the one before; play, export and a resume pick the complete
checkpoint with the highest success, then return; `lab runs` shows it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from oneline import assert_one_line_error
from typer.testing import CliRunner

from labcli import testing
from labcli.commands.app import app
from labcli.plugins import registry
from labcli.runs import checkpoints, play

SMALL = ["agent.num_steps_per_env=8", "agent.num_learning_epochs=1", "agent.num_mini_batches=1",
         "agent.actor_hidden_dims=[8]", "agent.critic_hidden_dims=[8]", "agent.save_interval=1",
         testing.SHORT_EPISODE]


def lab(*args: str, logs: Path):
    return CliRunner().invoke(app, list(args), env={"LAB_LOGS_DIR": str(logs), "COLUMNS": "250"})


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> Path:
    logs = tmp_path_factory.mktemp("logs")
    testing.train_small("rsl_rl", logs, 4, SMALL)
    return logs


def manifests(logs: Path) -> dict[int, Path]:
    (run,) = [p.parent for p in logs.rglob("run.json")]
    return {int(p.stem.removeprefix("checkpoint_")): p for p in run.glob("checkpoint_*.json")}


def record(path: Path, figures: object) -> None:
    data = json.loads(path.read_text())
    data["figures"] = figures
    path.write_text(json.dumps(data))


def test_each_checkpoint_records_the_episodes_since_the_one_before(logs):
    found = manifests(logs)
    assert sorted(found) == [1, 2, 3, 4]
    for path in found.values():
        figures = json.loads(path.read_text())["figures"]
        # 4 envs, 8 steps of 0.1 s episodes (5 steps): at least 4 episodes end per iteration.
        assert figures["episodes"] >= 4
        assert 0.0 <= figures["success_rate"] <= 1.0


def test_best_is_the_highest_success_then_return_then_the_newest(logs):
    found = manifests(logs)
    originals = {i: p.read_text() for i, p in found.items()}
    fw = registry.get_framework("rsl_rl")
    try:
        ranked = {1: (0.5, 9.0), 2: (0.9, 1.0), 3: (0.9, 3.0), 4: (0.2, 50.0)}
        for i, (success, ret) in ranked.items():
            record(found[i], {"success_rate": success, "mean_return": ret, "episodes": 8})
        assert checkpoints.find("best", logs, "cartpole", fw)[1].iteration == 3
        loaded = play.load(checkpoint=Path("best"), logs_dir=logs)
        assert loaded.checkpoint.iteration == 3
        loaded.env.close()
        played = lab("play", "--checkpoint", "best", "--episodes", "1", logs=logs)
        assert played.exit_code == 0, played.output
        assert "model_3.pt" in played.stdout
        listed = json.loads(lab("runs", "--json", logs=logs).stdout)
        assert listed[0]["best_checkpoint"] == {"iteration": 3, "success_rate": 0.9,
                                                "mean_return": 3.0, "episodes": 8}
        # A tie of success and return: the newer; figures that are not numbers: not ranked.
        record(found[4], {"success_rate": 0.9, "mean_return": 3.0, "episodes": 8})
        record(found[2], {"success_rate": "1.0", "mean_return": 99.0, "episodes": 8})
        assert checkpoints.find("best", logs, "cartpole", fw)[1].iteration == 4
    finally:
        for i, text in originals.items():
            found[i].write_text(text)


def test_a_run_whose_checkpoints_recorded_no_figures_is_one_line(logs):
    found = manifests(logs)
    originals = {i: p.read_text() for i, p in found.items()}
    try:
        for path in found.values():
            data = json.loads(path.read_text())
            data.pop("figures")
            path.write_text(json.dumps(data))
        result = lab("play", "--checkpoint", "best", "--episodes", "1", logs=logs)
        assert_one_line_error(result, "recorded its success and return",
                              "pass --checkpoint latest")
    finally:
        for i, text in originals.items():
            found[i].write_text(text)
