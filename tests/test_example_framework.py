"""The out-of-tree framework example (tests/example_framework, `lab-example-ppo`): a library
that owns its training loop, pip-installed as a user would install it, listed with its library,
giving defaults for cartpole, and passing the whole conformance suite."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
import torch
from installed import on_sys_path, pip_install
from typer.testing import CliRunner

from labcli import testing
from labcli.commands.app import app
from labcli.plugins import registry
from labcli.runs.config import resolve

EXAMPLE = Path(__file__).with_name("example_framework")
NAME, DIST, VERSION = "example_ppo", "lab-example-ppo", "0.1.0"
SMALL = ["agent.steps_per_env=8", "agent.epochs=2", "agent.minibatches=2", "agent.hidden=[16]"]


@pytest.fixture(scope="module")
def example(tmp_path_factory) -> Iterator[None]:
    with on_sys_path(pip_install(EXAMPLE, tmp_path_factory.mktemp("example_framework"))):
        registry.reload()
        yield


def probe(env, actions: torch.Tensor) -> testing.ProbeStep:
    obs, reward, done, timeout = env.step(actions)
    return testing.ProbeStep(obs, reward, done.bool() & ~timeout.bool(), timeout.bool())


def test_the_example_passes_the_conformance_suite(example, tmp_path):
    testing.check_framework(NAME, tmp_path, SMALL, probe)


def test_the_example_is_listed_with_its_library(example):
    result = CliRunner().invoke(app, ["info"], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    assert f"framework {NAME}" in result.stdout
    row = next(line for line in result.stdout.splitlines() if f"framework {NAME}" in line)
    assert f"{DIST} {VERSION}, plugin from {DIST} {VERSION}" in row


def test_the_example_s_defaults_for_cartpole_apply(example):
    env, agent = resolve(registry.get_task("cartpole"), registry.get_framework(NAME))
    assert env.num_envs == 128
    assert (agent.max_iterations, agent.steps_per_env, agent.learning_rate) == (150, 32, 1e-3)


@pytest.mark.parametrize("path", ["pyproject.toml", "src/lab_example_ppo/plugin.py",
                                  "src/lab_example_ppo/config.py",
                                  "src/lab_example_ppo/adapter.py",
                                  "src/lab_example_ppo/framework.py"])
def test_docs_show_the_example_files_as_they_are(path):
    docs = (Path(__file__).parents[1] / "docs" / "frameworks.md").read_text()
    assert (EXAMPLE / path).read_text().rstrip("\n") in docs, f"docs/frameworks.md lacks {path}"
