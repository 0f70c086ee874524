"""Plugin discovery and the registry: a real out-of-tree package installed with pip and trained,
plugins registered into the manager for one test (as simonw/llm's tests do), broken plugins
reported without breaking the others, and clashes named with both distributions."""

from __future__ import annotations

import dataclasses
import io
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch
import yaml
from installed import on_sys_path, pip_install
from rich.console import Console
from typer.testing import CliRunner

from labcli import testing
from labcli.commands import app as cli
from labcli.envs import metrics
from labcli.envs.env import LabVecEnv
from labcli.envs.wrappers import Stage, WrapperSpec
from labcli.errors import LabError
from labcli.plugins import registry
from labcli.plugins.hookspecs import hookimpl
from labcli.plugins.registry import PluginFailure, Provider
from labcli.runs import rundir, training

EXAMPLE = Path(__file__).with_name("example_plugin")
EXAMPLE_DIST, EXAMPLE_VERSION = "lab-example-reach", "0.1.0"
EXAMPLE_PLUGIN, EXAMPLE_TASK = "example_reach", "point_reach"
NOT_INSTALLED = "(not installed)"  # the version shown for a plugin registered by hand


def write_dist(site: Path, dist: str, version: str, entry_point: str, source: str) -> None:
    """An installed distribution as pip leaves it (dist-info with METADATA and entry points)
    whose plugin module is `source`: cheaper than a pip install, and just as real to
    importlib.metadata."""
    module = dist.replace("-", "_")
    (site / f"{module}.py").write_text(source)
    info = site / f"{module}-{version}.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: {version}\n")
    (info / "entry_points.txt").write_text(f"[lab]\n{entry_point} = {module}\n")


def lab_list() -> str:
    # Wide enough that no cell wraps, so that a name and its package stay on one line.
    result = CliRunner().invoke(cli.app, ["list"], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    return result.stdout


def line_with(name: str, output: str) -> str:
    """The table row whose first cell is `name`."""
    return next(line for line in output.splitlines() if line.split()[:1] == [name])


# A real out-of-tree package, installed with pip --------------------------------------------------
@pytest.fixture(scope="module")
def example_site(tmp_path_factory) -> Path:
    """The example package pip-installed (not editable) into a private --target dir."""
    return pip_install(EXAMPLE, tmp_path_factory.mktemp("example"))


@pytest.fixture
def example(example_site) -> Iterator[None]:
    with on_sys_path(example_site):
        registry.reload()
        yield


def test_the_example_task_passes_the_task_checks(example):
    testing.check_task(EXAMPLE_TASK)


def test_example_is_listed_with_its_distribution_and_version(example, monkeypatch):
    reg = registry.loaded()
    assert reg.provider("task", EXAMPLE_TASK) == Provider(EXAMPLE_PLUGIN, EXAMPLE_DIST,
                                                          EXAMPLE_VERSION)
    assert reg.failures == []
    row = line_with(EXAMPLE_TASK, lab_list())
    assert f"{EXAMPLE_DIST} {EXAMPLE_VERSION}" in row
    assert "random target" in row  # its description


def test_example_is_gone_once_uninstalled(example_site):
    with on_sys_path(example_site):
        registry.reload()
        assert EXAMPLE_TASK in registry.loaded().names("task")
    with pytest.raises(LabError, match=f"unknown task '{EXAMPLE_TASK}'"):
        registry.get_task(EXAMPLE_TASK)


def test_example_task_runs_in_a_lab_env(example, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    spec = registry.get_task(EXAMPLE_TASK)
    env = LabVecEnv(spec, spec.config_class(num_envs=8, episode_length_s=2.0), backend="cpu",
                    seed=1)
    try:
        obs, _ = env.reset()
        assert obs.shape == (8, 6) and env.single_action_space.shape == (2,)
        # A PD controller on the observed offset reaches every target: the task is solvable
        # and its success criterion sees it.
        for _ in range(env.max_episode_length):
            action = (4.0 * obs[:, 4:] - 1.5 * obs[:, 2:4]).clamp(-1, 1)
            obs, _, terminated, truncated, info = env.step(action)
            assert not terminated.any()
        assert truncated.all() and info["lab_episode"]["success"].all()
        stats = env.pop_stats()
        assert stats[metrics.SUCCESS_RATE] == 1.0
        assert {f"{metrics.REWARD_TERM}{t}" for t in ("near", "at_target", "effort", "leaving")} \
            <= set(stats)
    finally:
        env.close()


def test_example_task_ends_episodes_outside_its_arena(example, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    spec = registry.get_task(EXAMPLE_TASK)
    env = LabVecEnv(spec, spec.config_class(num_envs=4, arena=0.1, start_range=0.0), backend="cpu")
    try:
        env.reset()
        env.sim.qpos[:2] = 0.5
        _, _, terminated, truncated, _ = env.step(torch.zeros(4, 2))
        assert terminated.tolist() == [True, True, False, False] and not truncated.any()
        assert env.pop_stats()[metrics.TERMINATION + "left_arena"] == 1.0
    finally:
        env.close()


@pytest.mark.filterwarnings("ignore:The `render_mode` attribute:UserWarning")  # see test_wrappers
def test_example_trains_with_sb3(example, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    num_envs, n_steps = 8, 16
    outcome = training.train(
        EXAMPLE_TASK, "sb3", num_envs=num_envs, max_iterations=2, logs_dir=tmp_path / "logs",
        overrides=[f"agent.n_steps={n_steps}", "agent.batch_size=64", "agent.n_epochs=1",
                   "agent.net_arch=[16]"],
        console=Console(file=io.StringIO()))
    summary = outcome.summary
    assert summary["state"] == "finished" and summary["iterations"] == 2
    assert summary["steps"] == 2 * num_envs * n_steps
    assert summary["checkpoint"] == "model_2.zip"
    run_dir = outcome.run.dir
    assert run_dir.parent.name == EXAMPLE_TASK
    env_params = yaml.safe_load((run_dir / rundir.ENV_PARAMS).read_text())
    agent_params = yaml.safe_load((run_dir / rundir.AGENT_PARAMS).read_text())
    assert env_params["target_radius"] == 0.1  # the plugin's own config
    assert agent_params["gamma"] == 0.98  # the plugin's defaults for sb3
    spec = registry.get_task(EXAMPLE_TASK)
    policy = testing.load_policy("sb3", run_dir / "model_2.zip",
                                 LabVecEnv(spec, spec.config_class(num_envs=1), backend="cpu"))
    assert policy(torch.zeros(3, 6)).shape == (3, 2)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:The `render_mode` attribute:UserWarning")
def test_example_defaults_reach_success_with_sb3(example, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    outcome = training.train(EXAMPLE_TASK, "sb3", logs_dir=tmp_path / "logs",
                             console=Console(file=io.StringIO()))
    assert outcome.summary["success_rate"] >= 0.9


@pytest.mark.parametrize("path", ["pyproject.toml", "src/lab_example_reach/plugin.py",
                                  "src/lab_example_reach/reach.py",
                                  "src/lab_example_reach/reach.xml"])
def test_docs_show_the_example_files_as_they_are(path):
    docs = (Path(__file__).parents[1] / "docs" / "plugins.md").read_text()
    assert (EXAMPLE / path).read_text().rstrip("\n") in docs, f"docs/plugins.md lacks {path}"


# Plugins registered into the manager for one test ----------------------------------------------
def renamed_cartpole(name: str):
    return dataclasses.replace(registry.get_task("cartpole"), name=name)


class CartpoleCopy:
    @hookimpl
    def register_tasks(self, register):
        register(renamed_cartpole("cartpole_copy"))


NOISE = WrapperSpec("robot.noise", Stage.ENV, lambda env: env, description="does nothing")


class Broken:
    """Its task hook fails (as when a model file is missing); its wrapper hook works."""

    @hookimpl
    def register_tasks(self, register):
        raise RuntimeError("robot.xml not found\nsearched: /opt/robots")

    @hookimpl
    def register_wrappers(self, register):
        register(NOISE)


def test_a_registered_plugin_provides_its_task(register_plugin, tmp_path, monkeypatch):
    register_plugin(CartpoleCopy(), "copy")
    spec = registry.get_task("cartpole_copy")
    assert registry.loaded().provider("task", "cartpole_copy") == Provider("copy", "copy",
                                                                            NOT_INSTALLED)
    monkeypatch.chdir(tmp_path)
    env = LabVecEnv(spec, spec.config_class(num_envs=2), backend="cpu")
    env.reset()
    env.step(torch.zeros(2, 1))
    env.close()
    row = line_with("cartpole_copy", lab_list())
    assert f"copy {NOT_INSTALLED}" in row

    registry.pm.unregister(name="copy")
    registry.reload()
    with pytest.raises(LabError, match="unknown task 'cartpole_copy'"):
        registry.get_task("cartpole_copy")


def test_a_hook_that_raises_is_a_failure_and_the_rest_keeps_working(register_plugin):
    register_plugin(Broken(), "robot")
    reg = registry.loaded()
    assert reg.failures == [PluginFailure("robot", Provider("robot", "robot", NOT_INSTALLED),
                                          "RuntimeError: robot.xml not found")]
    assert registry.get_wrapper("robot.noise") is NOISE  # its other hook still registered
    assert "cartpole" in reg.names("task") and "sb3" in reg.names("framework")


def test_training_warns_of_a_plugin_that_failed(register_plugin, tmp_path):
    register_plugin(Broken(), "robot")
    out = io.StringIO()
    training.train("cartpole", "sb3", num_envs=2, max_iterations=1, logs_dir=tmp_path,
                   overrides=["agent.n_steps=4", "agent.batch_size=8"],
                   console=Console(file=out, width=300))
    assert (f"warning: plugin 'robot' (robot {NOT_INSTALLED}) failed to load: RuntimeError: "
            "robot.xml not found") in out.getvalue()


def test_a_task_from_a_failed_plugin_is_a_lab_error_naming_the_failure(register_plugin):
    register_plugin(Broken(), "robot")
    with pytest.raises(LabError) as err:
        registry.get_task("robot_arm")
    assert err.value.message == "unknown task 'robot_arm'"
    assert ("known tasks: ant, cartpole, g1-flat, g1-rough, go1-flat, go1-rough, go2-flat, "
            "humanoid") in err.value.hint
    assert ("plugins that failed to load, which may provide it: 'robot' from robot "
            f"{NOT_INSTALLED}: RuntimeError: robot.xml not found") in err.value.hint
    result = CliRunner().invoke(cli.app, ["train", "--task", "robot_arm", "--framework", "sb3"])
    assert result.exit_code == 2
    assert "RuntimeError: robot.xml not found" in result.stderr
    assert "Traceback" not in result.output


def test_lab_list_shows_tasks_frameworks_wrappers_and_failures(register_plugin, monkeypatch):
    output = lab_list()
    for title in ("Tasks", "Frameworks", "Wrappers"):
        assert title in output
    assert "lab 0.1.0" in line_with("cartpole", output)
    for name in ("sb3", "rsl_rl", "skrl", "sb3.adapter", "sb3.vec_normalize"):
        assert "lab" in line_with(name, output)
    assert "failed to load" not in output

    register_plugin(Broken(), "robot")
    output = lab_list()
    assert "Plugins that failed to load" in output
    row = line_with("robot", output)
    assert f"robot {NOT_INSTALLED}" in row and "RuntimeError: robot.xml not found" in row
    assert "robot.noise" in output and "cartpole" in output


# Broken and clashing installed distributions ---------------------------------------------------
def test_an_entry_point_that_fails_to_import_is_reported_by_name(tmp_path, monkeypatch):
    write_dist(tmp_path, "lab-needs-libfoo", "0.2.0", "needs_libfoo",
               "import lab_libfoo_that_is_not_installed  # noqa: F401\n")
    with on_sys_path(tmp_path):
        reg = registry.reload()
        assert reg.failures == [PluginFailure(
            "needs_libfoo", Provider("needs_libfoo", "lab-needs-libfoo", "0.2.0"),
            "ModuleNotFoundError: No module named 'lab_libfoo_that_is_not_installed'")]
        assert "cartpole" in reg.names("task")
        row = line_with("needs_libfoo", lab_list())
        assert "lab-needs-libfoo 0.2.0" in row and "ModuleNotFoundError" in row


CARTPOLE_FORK = """
import dataclasses
from lab_cartpole.plugin import register_tasks as cartpole_tasks
from labcli.plugins.hookspecs import hookimpl

@hookimpl
def register_tasks(register):
    found = []
    cartpole_tasks(found.append)
    register(dataclasses.replace(found[0], name={name!r}, description="a fork"))
"""


def test_two_distributions_registering_one_task_name_is_a_lab_error(tmp_path, monkeypatch):
    write_dist(tmp_path, "lab-cartpole-fork", "1.0", "cartpole_fork",
               CARTPOLE_FORK.format(name="cartpole"))
    with on_sys_path(tmp_path):
        with pytest.raises(LabError) as err:
            registry.reload()
        message = str(err.value)
        assert "task 'cartpole' is registered twice" in message
        assert "lab (plugin 'cartpole')" in message
        assert "lab-cartpole-fork (plugin 'cartpole_fork')" in message
        assert "uninstall one of the two packages" in err.value.hint
        result = CliRunner().invoke(cli.app, ["list"])
        assert result.exit_code == 2 and "lab-cartpole-fork" in result.stderr


def test_a_clashing_entry_point_name_is_loaded_or_reported(tmp_path):
    write_dist(tmp_path, "lab-cartpole-pro", "1.0", "cartpole",
               CARTPOLE_FORK.format(name="cartpole_pro"))
    with on_sys_path(tmp_path):
        reg = registry.reload()
        # Which of the two is dropped depends on sys.path order and on what was loaded before.
        assert reg.provider("task", "cartpole").dist == "lab"
        assert "cartpole_pro" in reg.names("task") or any(
            f.provider.dist == "lab-cartpole-pro" for f in reg.failures)
