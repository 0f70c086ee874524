"""The commands around training, through the command surface: help examples, completion,
config show/--config, info, runs, plot, sanity agents, the viewer's headless refusal."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import pytest
import typer
import yaml
from oneline import assert_one_line_error
from typer.testing import CliRunner

from labcli.commands.app import app
from labcli.plugins import registry

SMALL = ["--num-envs", "4", "--max-iterations", "2", "--set", "agent.n_steps=8",
         "--set", "agent.batch_size=16", "--set", "agent.n_epochs=1",
         "--set", "agent.normalize_obs=true"]
HEADLESS = {"DISPLAY": None, "WAYLAND_DISPLAY": None}


def lab(*args: str, logs: Path, **env: str | None) -> object:
    return CliRunner().invoke(app, [*args], env={"LAB_LOGS_DIR": str(logs), "COLUMNS": "200",
                                                  **env})




def all_commands(group, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    """The command paths of a group, itself included: ("",), ("train",), ("config", "show")..."""
    found = [prefix]
    for name, cmd in group.commands.items():
        if hasattr(cmd, "commands"):  # a group
            found += all_commands(cmd, (*prefix, name))
        else:
            found.append((*prefix, name))
    return found


@pytest.mark.parametrize("command", all_commands(typer.main.get_command(app)),
                         ids=lambda path: " ".join(path) or "lab")
def test_every_command_and_group_has_an_example_in_its_help(command):
    result = CliRunner().invoke(app, [*command, "--help"])
    assert result.exit_code == 0 and "Example: lab" in result.stdout


@pytest.mark.parametrize("words, expected", [
    ("lab train --task car", "cartpole\n"),
    ("lab train --framework s", "sb3\nsb3_sac\nsb3_td3\nskrl\nskrl_sac\nskrl_td3\n"),
    ("lab play --task gym:InvertedPendulum-v", "gym:InvertedPendulum-v5"),
])
def test_shell_completion_offers_registered_names(words, expected):
    result = CliRunner().invoke(app, [], prog_name="lab", env={
        "_LAB_COMPLETE": "complete_bash", "COMP_WORDS": words,
        "COMP_CWORD": str(len(words.split()) - 1)})
    assert result.exit_code == 0 and expected in result.output


def test_config_show_is_a_config_file_train_reproduces(tmp_path):
    shown = lab("config", "show", "--task", "cartpole", "--framework", "sb3", "--set",
                "agent.n_epochs=3", "--set", "env.num_envs=4", logs=tmp_path)
    assert shown.exit_code == 0, shown.output
    resolved = yaml.safe_load(shown.stdout)
    assert resolved["agent"]["n_epochs"] == 3 and resolved["env"]["num_envs"] == 4
    assert resolved["agent"]["learning_rate"] == 5e-4  # cartpole's own default for sb3
    file = tmp_path / "my.yaml"
    file.write_text(shown.stdout)
    trained = lab("train", "--task", "cartpole", "--framework", "sb3", "--config", str(file),
                  "--max-iterations", "1", "--set", "agent.n_steps=8", "--set",
                  "agent.batch_size=16", logs=tmp_path / "logs")
    assert trained.exit_code == 0, trained.output
    (run,) = (tmp_path / "logs" / "sb3" / "cartpole").iterdir()
    agent = yaml.safe_load((run / "params" / "agent.yaml").read_text())
    assert agent == {**resolved["agent"], "max_iterations": 1, "n_steps": 8, "batch_size": 16}


@pytest.mark.parametrize("backend, expected", [
    ("cpu", {"num_envs": 64, "num_steps_per_env": 24, "num_learning_epochs": 5,
             "num_mini_batches": 4, "actor_hidden_dims": [32, 32], "desired_kl": 0.005}),
    ("warp", {"num_envs": 4096, "num_steps_per_env": 24, "num_learning_epochs": 5,
              "num_mini_batches": 4, "actor_hidden_dims": [64, 64], "desired_kl": 0.005}),
])
def test_the_backend_picks_cartpoles_rsl_rl_scale(tmp_path, backend, expected):
    shown = lab("config", "show", "--task", "cartpole", "--framework", "rsl_rl", "--backend",
                backend, logs=tmp_path)
    assert shown.exit_code == 0, shown.output
    resolved = yaml.safe_load(shown.stdout)
    assert {k: {**resolved["env"], **resolved["agent"]}[k] for k in expected} == expected


@pytest.mark.parametrize("content, phrases", [
    (None, ["does not exist"]),
    ("dir", ["is not a regular file"]),
    ("env: [unclosed", ["not valid YAML"]),
    ("agent:\n  learning_rat: 1\n", ["unknown key 'agent.learning_rat'", "learning_rate"]),
    # A control character is a line break to splitlines: the error quotes it escaped.
    ('agent:\n  "a\\x1cb": 1\n', ["unknown key 'agent.a\\x1cb'"]),
    ("- a list\n", ["must be a mapping"]),
])
def test_a_bad_config_file_is_one_line_exit_2_and_writes_nothing(tmp_path, content, phrases):
    file = tmp_path / "bad.yaml"
    if content == "dir":
        file.mkdir()
    elif content is not None:
        file.write_text(content)
    logs = tmp_path / "logs"
    for command in (["train"], ["config", "show"]):
        result = lab(*command, "--task", "cartpole", "--framework", "sb3", "--config", str(file),
                     logs=logs)
        assert_one_line_error(result, *phrases)
    assert not logs.exists()


def test_info_names_versions_gl_backend_and_what_works(tmp_path):
    result = lab("info", logs=tmp_path)
    assert result.exit_code == 0, result.output
    for phrase in ("mujoco", "torch", "MUJOCO_GL", "offscreen rendering", "works", "CUDA",
                   "mujoco_warp"):
        assert phrase in result.stdout
    # Each framework's library and its version, as the plugin declares it (FrameworkSpec.library).
    for name in ("sb3", "rsl_rl", "skrl", "rl_games"):
        library = registry.get_framework(name).library
        assert re.search(rf"framework {name} +{library} {re.escape(version(library))}, plugin "
                         r"from lab", result.stdout), result.stdout


def test_the_viewer_without_a_display_says_what_to_do(tmp_path):
    result = lab("play", "--agent", "zero", "--task", "cartpole", "--viewer", logs=tmp_path,
                 **HEADLESS)
    assert_one_line_error(result, "--viewer needs a display", "--video")


def test_sanity_agent_prints_returns_and_termination_causes(tmp_path):
    result = lab("play", "--agent", "random", "--task", "cartpole", "--episodes", "4",
                 "--set", "env.episode_length_s=0.5", logs=tmp_path)
    assert result.exit_code == 0, result.output
    assert "random agent · cartpole" in result.stdout
    assert "4 episodes: mean return" in result.stdout
    assert "ended by time_out" in result.stdout or "ended by cart_out_of_bounds" in result.stdout
    assert not tmp_path.exists() or not any(tmp_path.rglob("*.*"))  # no video asked, none made


@pytest.mark.parametrize("args, phrases", [
    (["play", "--agent", "zero"], ["--agent zero plays a task", "--task"]),
    (["play", "--agent", "zero", "--task", "cartpole", "--set", "agent.n_steps=3"],
     ["no agent settings"]),
    (["train", "--task", "cartpole", "--framework", "sb3", "--video", "--video-length", "1"],
     ["--video-length"]),
    (["train", "--task", "gym:NoSuchEnv-v0", "--framework", "sb3"],
     ["unknown gymnasium env 'NoSuchEnv-v0'"]),
    (["train", "--task", "gym:CartPole-v1", "--framework", "sb3"], ["Discrete(2)"]),
    (["train", "--task", "gym:InvertedPendulum-v5", "--framework", "sb3", "--num-envs", "2",
      "--video", "--set", "env.vectorization=async"], ["cannot render images here"]),
    (["plot"], ["no runs found"]),
])
def test_bad_input_is_one_line_exit_2_and_writes_nothing(tmp_path, args, phrases):
    logs = tmp_path / "logs"
    assert_one_line_error(lab(*args, logs=logs), *phrases)
    assert not logs.exists() or not any(logs.rglob("*.*"))


def test_runs_and_plot_from_the_command_line(tmp_path):
    logs = tmp_path / "logs"
    trained = lab("train", "--task", "cartpole", "--framework", "sb3", *SMALL, "--set",
                  "env.episode_length_s=0.1", logs=logs)
    assert trained.exit_code == 0, trained.output
    listed = lab("runs", "--json", logs=logs)
    (row,) = json.loads(listed.stdout)
    assert row["state"] == "finished" and row["steps"] == 64 and row["framework"] == "sb3"
    table = lab("runs", "--state", "finished", logs=logs)
    assert "cartpole" in table.stdout and "finished" in table.stdout
    assert f"1 run in {logs}" in table.stdout
    assert json.loads(lab("runs", "--json", "--state", "running", logs=logs).stdout) == []
    png = tmp_path / "curves.png"
    plotted = lab("plot", "-o", str(png), logs=logs)
    assert plotted.exit_code == 0 and png.stat().st_size > 10_000
    unknown = lab("plot", "--metric", "Train/nope", "-o", str(tmp_path / "x.png"), logs=logs)
    assert_one_line_error(unknown, "Train/nope", "Train/mean_reward")


def test_a_table_piped_or_redirected_keeps_every_cell_whole(tmp_path):
    """stdout not a terminal and no $COLUMNS (`lab list | grep g1`): each cell whole on its
    line, where rich would fit the table to 80 columns; the user's $COLUMNS still rules."""
    description = registry.get_task("g1-flat").description
    assert len(description) > 80
    piped = lab("list", logs=tmp_path, COLUMNS=None)
    assert piped.exit_code == 0 and description in piped.stdout
    assert description not in lab("list", logs=tmp_path, COLUMNS="80").stdout


@pytest.mark.skipif(shutil.which("xvfb-run") is None, reason="needs Xvfb (apt-get install xvfb)")
def test_the_viewer_opens_on_a_virtual_display(tmp_path):
    """MuJoCo's viewer (GLFW) on Xvfb follows the rollout to its end and closes."""
    # Not this process's MUJOCO_GL (egl, lab's headless default): with a display lab keeps GLFW.
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    # Its own session, so that a hang kills Xvfb and lab too, not only the xvfb-run script.
    proc = subprocess.Popen(
        ["xvfb-run", "-a", sys.executable, "-m", "labcli", "play", "--agent", "zero", "--task",
         "cartpole", "--viewer", "--episodes", "1", "--set", "env.episode_length_s=0.4"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
        env={**env, "LAB_LOGS_DIR": str(tmp_path)})
    try:
        stdout, stderr = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        raise
    result = subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)
    assert result.returncode == 0, result.stderr
    assert "1 episodes: mean return" in result.stdout and "time_out" in result.stdout
