"""Bad input: a damaged run dir, a checkpoint of another task, a run dir that cannot be written,
and any --set or --num-envs. Each is one line on stderr, exit code 2 and nothing written; no
input gives a traceback."""

from __future__ import annotations

import dataclasses
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest
import torch
import yaml
from conftest import needs_menagerie
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from lab_cartpole.cartpole import Cartpole
from lab_cartpole.config import CartpoleConfig
from lab_sb3.config import Sb3PPOConfig
from oneline import assert_one_line_error
from pydantic import model_validator
from runfiles import copy_checkpoint, snapshot_of
from typer.testing import CliRunner

from labcli.commands.app import app
from labcli.envs.env import LabVecEnv
from labcli.errors import LabError
from labcli.plugins import registry
from labcli.plugins.hookspecs import hookimpl
from labcli.runs import config, rundir

SMALL = ["--num-envs", "4", "--max-iterations", "1", "--set", "agent.n_steps=8",
         "--set", "agent.batch_size=16", "--set", "agent.n_epochs=1",
         "--set", "agent.normalize_obs=true"]


def lab(*args: str, logs: Path):
    return CliRunner().invoke(app, list(args), env={"LAB_LOGS_DIR": str(logs), "COLUMNS": "300"})




@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    logs = tmp_path_factory.mktemp("logs")
    result = lab("train", "--task", "cartpole", "--framework", "sb3", *SMALL, logs=logs)
    assert result.exit_code == 0, result.output
    return logs


@pytest.fixture
def run_copy(trained, tmp_path) -> Path:
    """A copy of the trained run to damage."""
    (source,) = trained.glob("sb3/cartpole/*")
    target = tmp_path / "logs" / "sb3" / "cartpole" / source.name
    shutil.copytree(source, target)
    return target


USES = {
    "play": lambda run: ["play", "--run", str(run)],
    "export": lambda run: ["export", "onnx", "--run", str(run)],
    "resume": lambda run: ["train", "--task", "cartpole", "--framework", "sb3",
                           "--checkpoint", str(run), "--max-iterations", "2"],
}
DAMAGE = {
    "not YAML": ("num_envs: [4\n", "is not valid YAML"),
    "a boolean count": ("num_envs: true\n", "a boolean where a number is expected"),
    "an unknown key": ("num_env: 4\n", "unknown key 'env.num_env'"),
}


@pytest.mark.parametrize("use", USES)
@pytest.mark.parametrize("damage", DAMAGE)
def test_a_damaged_env_yaml_is_named_and_nothing_is_written(run_copy, use, damage):
    text, complaint = DAMAGE[damage]
    (run_copy / rundir.ENV_PARAMS).write_text(text)
    before = snapshot_of(run_copy)
    result = lab(*USES[use](run_copy), logs=run_copy.parents[2])
    assert_one_line_error(result, "params/env.yaml", complaint)
    assert snapshot_of(run_copy) == before


# A task whose observations are the positions only: its checkpoints do not fit cartpole.
class PositionsOnly(Cartpole):
    observation_names = ["cart_pos", "pole_angle"]

    def observations(self) -> torch.Tensor:
        return super().observations()[:, :2]


class ShortTask:
    @hookimpl
    def register_tasks(self, register):
        register(dataclasses.replace(registry.get_task("cartpole"), name="cartpole_short",
                                     task=PositionsOnly, config=CartpoleConfig))


class _EvenBatchConfig(Sb3PPOConfig):
    """A plugin's config with a check across its settings: a pydantic model validator."""

    @model_validator(mode="after")
    def _even(self):
        if self.batch_size % 2:
            raise ValueError(f"batch_size must be even, got {self.batch_size}")
        return self


class EvenBatchSb3:
    @hookimpl
    def register_frameworks(self, register):
        sb3 = registry.get_framework("sb3")
        adapter = dataclasses.replace(sb3.adapter, name="sb3_even.adapter", framework="sb3_even")
        register(dataclasses.replace(sb3, name="sb3_even", agent_config=_EvenBatchConfig,
                                     wrappers=(adapter,)))


def test_a_config_s_model_validator_that_refuses_a_value_is_one_line(register_plugin, tmp_path):
    register_plugin(EvenBatchSb3(), "even")
    result = lab("train", "--task", "cartpole", "--framework", "sb3_even",
                 "--set", "agent.batch_size=17", logs=tmp_path / "logs")
    assert_one_line_error(result, "bad agent settings", "batch_size must be even, got 17")
    assert not (tmp_path / "logs").exists()


def test_a_checkpoint_of_another_task_or_size_names_the_mismatch(register_plugin, tmp_path):
    register_plugin(ShortTask(), "short")
    logs = tmp_path / "logs"
    for task in ("cartpole_short", "cartpole"):
        assert lab("train", "--task", task, "--framework", "sb3", *SMALL, logs=logs).exit_code == 0
    (short,) = logs.glob("sb3/cartpole_short/*")
    (full,) = logs.glob("sb3/cartpole/*")
    result = lab("train", "--task", "cartpole", "--framework", "sb3", "--checkpoint",
                 str(short / "model_1.zip"), "--max-iterations", "2", logs=logs)
    assert_one_line_error(result, "sb3 run of 'cartpole_short', not a sb3 run of 'cartpole'")
    # The same checkpoint copied into a cartpole run, whole: the sizes tell.
    copy_checkpoint(short, 1, full, 7)
    before = snapshot_of(logs)
    for args in (["play", "--run", str(full)],
                 ["train", "--task", "cartpole", "--framework", "sb3", "--checkpoint",
                  str(full), "--max-iterations", "9"]):
        result = lab(*args, logs=logs)
        assert_one_line_error(result, "model_7.zip has observation size 2",
                              "'cartpole' has 4")
    assert snapshot_of(logs) == before


def refuse_simulation(monkeypatch) -> None:
    def fail(*args, **kwargs):
        raise AssertionError("the env was built before the run dir was checked")

    monkeypatch.setattr(LabVecEnv, "__init__", fail)


def test_logs_dir_that_cannot_hold_runs_is_found_before_simulating(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("")
    refuse_simulation(monkeypatch)
    result = lab("train", "--task", "cartpole", "--framework", "sb3", *SMALL,
                 "--logs-dir", str(blocker / "logs"), logs=tmp_path)
    assert_one_line_error(result, "is not a directory", "--logs-dir")


def make_read_only(path: Path) -> bool:
    """Read-only for this process, root included (chattr +i); False where that cannot be done."""
    if subprocess.run(["chattr", "+i", str(path)], capture_output=True).returncode != 0:
        path.chmod(0o555)
    try:
        (path / ".probe").write_text("")
    except OSError:
        return True
    (path / ".probe").unlink()
    return False


def test_a_run_dir_that_cannot_be_written_is_found_before_resuming(run_copy, monkeypatch):
    if not make_read_only(run_copy):
        pytest.skip("cannot make a directory read-only here")
    try:
        before = snapshot_of(run_copy)
        refuse_simulation(monkeypatch)
        result = lab(*USES["resume"](run_copy), logs=run_copy.parents[2])
        assert_one_line_error(result, "is not writable", str(run_copy))
        assert snapshot_of(run_copy) == before
    finally:
        subprocess.run(["chattr", "-i", str(run_copy)], capture_output=True)
        run_copy.chmod(0o755)


def test_a_boolean_for_a_count_is_refused():
    result = lab("train", "--task", "cartpole", "--framework", "sb3", "--set",
                 "env.num_envs=true", logs=Path("unused"))
    assert_one_line_error(result, "env.num_envs", "a boolean where a number is expected",
                          "expected int")


@pytest.fixture(scope="module")
def mujoco_log_dir(tmp_path_factory):
    """Exploding configs make MuJoCo append warnings to ./MUJOCO_LOG.TXT outside training."""
    cwd = os.getcwd()
    os.chdir(tmp_path_factory.mktemp("cwd"))
    yield
    os.chdir(cwd)


# Any --set and --num-envs: a working env, or one LabError line ------------------------------
KEYS = {"env": sorted(CartpoleConfig.model_fields), "agent": sorted(Sb3PPOConfig.model_fields)}
yaml_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats()
    | st.text(st.characters(blacklist_categories=("Cc", "Cs")), max_size=8),
    lambda inner: st.lists(inner, max_size=3), max_leaves=4)
set_items = st.one_of(
    st.tuples(st.sampled_from(["env"]), st.sampled_from(KEYS["env"]), yaml_values),
    st.tuples(st.sampled_from(["agent"]), st.sampled_from(KEYS["agent"]), yaml_values),
    st.tuples(st.sampled_from(["env", "agent"]), st.from_regex(r"[a-z_.]{1,12}", fullmatch=True),
              yaml_values),
).map(lambda t: f"{t[0]}.{t[1]}=" + yaml.safe_dump(t[2], default_flow_style=True,
                                                    width=float("inf")).removesuffix("...\n")
      .strip())


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(items=st.lists(set_items, max_size=3),
       num_envs=st.none() | st.integers(max_value=16) | st.integers(min_value=2**20))
@example(items=["env.num_envs=true"], num_envs=None)
@example(items=["env.episode_length_s=1e300", "env.sim_dt=1e-300"], num_envs=None)
@example(items=["env.decimation=1000000000"], num_envs=None)
@example(items=["env.sim_dt=.nan"], num_envs=None)
@example(items=[], num_envs=10**12)
def test_any_set_and_num_envs_work_or_are_one_lab_error(items, num_envs, mujoco_log_dir):
    spec, fw = registry.get_task("cartpole"), registry.get_framework("sb3")
    try:
        env_cfg, _ = config.resolve(spec, fw, overrides=items, num_envs=num_envs)
        # Within the bounds any count works; stepping a few of them tells as much as many.
        env = LabVecEnv(spec, env_cfg.model_copy(update={"num_envs": min(env_cfg.num_envs, 4)}))
    except LabError as err:
        assert "\n" not in str(err) and str(err)
        return
    try:
        env.reset(seed=0)
        for _ in range(3):
            obs, reward, *_ = env.step(torch.rand(env.num_envs, 1) * 2 - 1)
            assert torch.isfinite(obs).all() and torch.isfinite(reward).all()
    finally:
        env.close()


# A robot task's terms, and envs that cannot fit ------------------------------------------------
@pytest.mark.parametrize(("setting", "says"), [
    ("env.rewards.lin_vel_z_l2.weight=true", "'env.rewards.lin_vel_z_l2.weight': a boolean"),
    ("env.commands.base_velocity.lin_vel_x=[true, 1]", "a boolean where a number is expected"),
    ("env.rewards.lin_vel_z_l2={}", "--set env.rewards.lin_vel_z_l2={} sets nothing"),
    ("env.nconmax=-1", "nconmax is -1: it must be above 0"),
    ("env.njmax=70000", "njmax is 70000: it must be at most 65536"),
    ("env.terminations.base_contact.bodies=[]", "'env.terminations.base_contact.bodies'"),
])
def test_a_robot_term_setting_that_cannot_work_is_one_line(setting, says):
    spec, fw = registry.get_task("go1-flat"), registry.get_framework("rsl_rl")
    with pytest.raises(LabError, match=re.escape(says)) as caught:
        config.resolve(spec, fw, overrides=[setting])
    assert "\n" not in str(caught.value)


def test_a_robot_task_with_every_reward_left_out_is_one_line():
    spec, fw = registry.get_task("go1-flat"), registry.get_framework("rsl_rl")
    rewards = spec.config_class().rewards.terms()
    with pytest.raises(LabError, match="every reward term is left out"):
        config.resolve(spec, fw, overrides=[f"env.rewards.{name}=null" for name, _ in rewards])
    # One left, even at weight 0, is a task.
    config.resolve(spec, fw, overrides=[f"env.rewards.{name}=null" for name, _ in rewards[1:]])


@needs_menagerie("unitree_go1")
def test_envs_whose_physics_cannot_fit_are_one_line(monkeypatch):
    """go1-flat's envs each hold a copy of the model (their masses and centres of mass vary):
    a million of them asked MuJoCo for ~800 GiB, which failed deep in an allocation."""
    from labcli.envs.shards import ShardedVecEnv
    from labcli.envs.sim import cpu

    monkeypatch.setattr(cpu, "available_memory", lambda: 2**30)
    spec = registry.get_task("go1-flat")
    for make in (LabVecEnv, ShardedVecEnv):
        with pytest.raises(LabError, match=r"env.num_envs=65,536 needs about \d\.\d GiB for the "
                           r"cpu backend's physics .* more than the 1\.0 GiB free \(use at most "
                           r"\d\d,\d\d\d envs\)"):
            make(spec, spec.config_class(num_envs=65536))
