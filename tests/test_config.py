"""Config resolution: --set parsing, YAML files, the merge order and the errors a user sees.

The order under test is model defaults ← the framework's defaults for the task ← the task's
defaults for the framework ← --config FILE ← --set ← explicit flags, with dict-valued settings
(reward weights) merged key by key.
"""

from __future__ import annotations

import contextlib
import dataclasses
from pathlib import Path

import pytest
import yaml
from hypothesis import example, given
from hypothesis import strategies as st
from lab_cartpole.config import CartpoleConfig
from lab_sb3.config import Sb3PPOConfig

from labcli.errors import LabError
from labcli.plugins import registry
from labcli.runs import config
from labcli.runs.config import resolve as resolve_configs

DEFAULT_WEIGHTS = CartpoleConfig().reward_weights
ENV_KEYS = sorted(CartpoleConfig.model_fields)
AGENT_KEYS = sorted(Sb3PPOConfig.model_fields)

identifiers = st.from_regex(r"[a-z][a-z0-9_]{0,11}", fullmatch=True)
key_paths = st.lists(identifiers, min_size=1, max_size=3).map(".".join)
sections = st.sampled_from(config.SECTIONS)
# What a user can type after "=": anything YAML reads back as itself.
yaml_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False)
    | st.text(st.characters(blacklist_categories=("Cc", "Cs")), max_size=12),
    lambda inner: st.lists(inner, max_size=3),
    max_leaves=6,
)


def typed(value: object) -> str:
    """`value` as YAML on one line, as a user would write it after '='."""
    return yaml.safe_dump(value, default_flow_style=True, width=float("inf")) \
        .removesuffix("...\n").strip()


def nested(path: str, value: object) -> dict:
    out: dict = {}
    tree = out
    keys = path.split(".")
    for key in keys[:-1]:
        tree = tree.setdefault(key, {})
    tree[keys[-1]] = value
    return out


def resolve(spec=None, framework: str = "sb3", **kwargs):
    spec = spec or registry.get_task("cartpole")
    return resolve_configs(spec, registry.get_framework(framework), **kwargs)


# --set parsing ---------------------------------------------------------------------------------
def test_set_values_are_read_as_yaml():
    out = config.parse_set([
        "env.num_envs=8", "env.action_scale=2.5", "agent.normalize_obs=false",
        "agent.net_arch=[16, 16]", "agent.target_kl=null", "env.reward_weights.alive=2",
        "agent.activation=relu", " env.cart_bound = 1.5", "env.tag=a=b", "env.empty=",
    ])
    assert out == {
        "env": {"num_envs": 8, "action_scale": 2.5, "reward_weights": {"alive": 2},
                "cart_bound": 1.5, "tag": "a=b", "empty": ""},
        "agent": {"normalize_obs": False, "net_arch": [16, 16], "target_kl": None,
                  "activation": "relu"},
    }


def test_exponent_without_a_dot_still_becomes_a_float():
    # YAML 1.1 reads "3e-4" as a string; pydantic must still turn it into the float.
    _, agent = resolve(overrides=["agent.learning_rate=3e-4"])
    assert agent.learning_rate == 3e-4 and isinstance(agent.learning_rate, float)


@pytest.mark.parametrize("item", ["num_envs=8", "envs.num_envs=8", "env.num_envs", "env.=8",
                                  "=8", "agent"])
def test_malformed_set_items_are_lab_errors(item):
    with pytest.raises(LabError) as err:
        config.parse_set([item])
    assert f"'{item}'" in err.value.message and "SECTION.KEY=VALUE" in err.value.message
    assert "--set" in err.value.hint


@given(sections, key_paths, yaml_values)
def test_any_yaml_value_round_trips_through_set(section, path, value):
    out = config.parse_set([f"{section}.{path}={typed(value)}"])
    assert out[section] == nested(path, value)
    assert all(out[s] == {} for s in config.SECTIONS if s != section)


@given(sections, key_paths, yaml_values, yaml_values)
def test_the_last_set_of_a_key_wins(section, path, first, last):
    out = config.parse_set([f"{section}.{path}={typed(first)}", f"{section}.{path}={typed(last)}"])
    assert out[section] == nested(path, last)


@given(st.text(max_size=20).filter(lambda s: s not in config.SECTIONS and "=" not in s),
       key_paths, st.text(max_size=8))
def test_an_unknown_section_is_a_lab_error(section, path, raw):
    with pytest.raises(LabError, match="SECTION.KEY=VALUE"):
        config.parse_set([f"{section}.{path}={raw}"])


@given(sections, key_paths, st.text(max_size=20))
@example("env", "tag", "2020-13-45")  # a YAML timestamp with month 13
@example("agent", "x", "!!int x")
def test_any_well_keyed_set_item_parses_or_is_a_lab_error(section, path, raw):
    with contextlib.suppress(LabError):
        config.parse_set([f"{section}.{path}={raw}"])


def test_setting_below_a_value_is_a_lab_error():
    with pytest.raises(LabError, match="env.reward_weights"):
        config.parse_set(["env.reward_weights=1", "env.reward_weights.alive=2"])


# Errors that name the key ----------------------------------------------------------------------
@pytest.mark.parametrize(("item", "close"), [
    ("env.num_env=8", "env.num_envs"),
    ("env.cartbound=1", "env.cart_bound"),
    ("agent.learning_rat=0.1", "agent.learning_rate"),
    ("agent.nstep=8", "agent.n_steps"),
])
def test_an_unknown_key_suggests_the_closest(item, close):
    with pytest.raises(LabError) as err:
        resolve(overrides=[item])
    key = item.partition("=")[0]
    assert err.value.message == f"unknown key '{key}'"
    assert f"did you mean '{close}'?" in err.value.hint
    keys = ENV_KEYS if key.startswith("env.") else AGENT_KEYS
    assert err.value.hint.endswith(", ".join(keys))


@given(identifiers.filter(lambda k: k not in CartpoleConfig.model_fields))
def test_any_unknown_env_key_is_named(key):
    with pytest.raises(LabError) as err:
        config.build(CartpoleConfig, "env", [{key: 1}])
    assert err.value.message == f"unknown key 'env.{key}'"
    assert "keys of env: " + ", ".join(ENV_KEYS) in err.value.hint


@pytest.mark.parametrize(("item", "expected"), [
    ("env.num_envs=abc", "int"),
    ("env.num_envs=8.5", "int"),
    ("env.action_scale=[1]", "float"),
    ("env.sim_dt=fast", "float | None"),
    ("agent.target_kl=x", "float | None"),
    ("agent.normalize_obs=maybe", "bool"),
])
def test_an_ill_typed_value_names_the_key_and_the_expected_type(item, expected):
    key, _, raw = item.partition("=")
    with pytest.raises(LabError) as err:
        resolve(overrides=[item])
    assert err.value.message.startswith(f"bad value for '{key}': ")
    assert f"(got {yaml.safe_load(raw)!r})" in err.value.message
    assert err.value.hint == f"expected {expected}"
    assert "\n" not in str(err.value)


@given(st.integers())
def test_num_envs_is_a_positive_int_up_to_2_to_the_20(n):
    if 0 < n <= 2**20:
        env, _ = resolve(overrides=[f"env.num_envs={n}"])
        assert env.num_envs == n
    else:
        bound = "greater than 0" if n <= 0 else "less than or equal to 1048576"
        with pytest.raises(LabError, match=rf"bad value for 'env.num_envs': .*{bound}"):
            resolve(overrides=[f"env.num_envs={n}"])


def test_a_bad_reward_weight_names_float():
    with pytest.raises(LabError) as err:
        resolve(overrides=["env.reward_weights.alive=lots"])
    assert "'env.reward_weights.alive'" in err.value.message
    assert err.value.hint == "expected float"


@pytest.mark.parametrize("item", ["env.decimation=0", "env.episode_length_s=0"])
def test_task_config_keeps_the_base_constraints(item):
    with pytest.raises(LabError, match=item.partition("=")[0]):
        resolve(overrides=[item])


# Merge order -----------------------------------------------------------------------------------
def write_yaml(path: Path, data: dict) -> Path:
    path.write_text(yaml.safe_dump(data))
    return path


def test_layers_apply_in_order(tmp_path):
    spec = dataclasses.replace(registry.get_task("cartpole"), framework_defaults={
        "sb3": {"env": {"num_envs": 128, "decimation": 3, "episode_length_s": 4.0},
                "agent": {"n_steps": 16, "batch_size": 64, "max_iterations": 7}},
        "skrl": {"env": {"cart_bound": 9.0}, "agent": {}},  # another framework's: never used
    })
    file = write_yaml(tmp_path / "cfg.yaml", {
        "env": {"decimation": 4, "action_scale": 10.0},
        "agent": {"n_steps": 8, "learning_rate": 1e-3, "max_iterations": 8}})
    env, agent = resolve(spec, config_file=file,
                         overrides=["env.action_scale=20", "agent.max_iterations=9"])
    assert env.cart_bound == CartpoleConfig().cart_bound  # model default
    assert env.num_envs == 128 and env.episode_length_s == 4.0  # task's sb3 defaults
    assert env.decimation == 4 and agent.n_steps == 8 and agent.learning_rate == 1e-3  # file
    assert env.action_scale == 20.0 and agent.max_iterations == 9  # --set
    assert agent.batch_size == 64 and agent.gamma == Sb3PPOConfig().gamma

    # The explicit flags (--num-envs, --max-iterations) come last.
    env, agent = resolve(spec, config_file=file, overrides=["env.num_envs=32"], num_envs=2,
                         max_iterations=1)
    assert env.num_envs == 2 and agent.max_iterations == 1


def test_built_in_framework_defaults_apply_to_their_framework_only():
    rsl_env, rsl_agent = resolve(framework="rsl_rl")
    sb3_env, _ = resolve(framework="sb3")
    defaults = registry.get_task("cartpole").framework_defaults
    assert rsl_env.num_envs == defaults["rsl_rl"]["env"]["num_envs"]
    assert rsl_agent.max_iterations == defaults["rsl_rl"]["agent"]["max_iterations"]
    assert sb3_env.num_envs == defaults["sb3"]["env"]["num_envs"]


def test_a_framework_gives_defaults_for_the_tasks_it_knows_and_the_task_s_own_win():
    fw = dataclasses.replace(registry.get_framework("sb3"), task_defaults={
        "cartpole": {"env": {"num_envs": 96, "decimation": 3, "reward_weights": {"alive": 2.0}},
                     "agent": {"n_steps": 48, "gamma": 0.97}},
        "other_task": {"env": {"num_envs": 7}, "agent": {}},  # another task's: never used
    })
    task = dataclasses.replace(registry.get_task("cartpole"), framework_defaults={
        "sb3": {"env": {"decimation": 4, "reward_weights": {"pole_angle": 3.0}},
                "agent": {"n_steps": 16}}})
    env, agent = resolve_configs(task, fw, overrides=["agent.batch_size=64"])
    assert env.num_envs == 96 and agent.gamma == 0.97  # the framework's, where the task is silent
    assert env.decimation == 4 and agent.n_steps == 16  # the task's own win
    assert env.reward_weights == {**DEFAULT_WEIGHTS, "alive": 2.0, "pole_angle": 3.0}
    assert agent.batch_size == 64  # and --set over both
    env, _ = resolve_configs(dataclasses.replace(task, framework_defaults={}), fw)
    assert env.num_envs == 96 and env.decimation == 3


ROBOT_TASKS = [name for name in registry.loaded().names(registry.TASK)
               if registry.get_task(name).task == "labcli.envs.mdp.task:RobotTask"]
# Each PPO framework's key of the policy's layers.
NETWORKS = {"rsl_rl": "actor_hidden_dims", "skrl": "hidden_sizes", "sb3": "net_arch",
            "rl_games": "units"}


@pytest.mark.parametrize("gpu_scale", [False, True])
@pytest.mark.parametrize("task", ROBOT_TASKS)
def test_every_robot_task_gives_its_recipe_to_every_ppo_framework(task, gpu_scale):
    """The same envs, iterations and networks whichever PPO a user picks, not a framework's
    generic defaults (100 iterations of [32, 32] in rl_games's)."""
    spec = registry.get_task(task)
    runs = {name: resolve(spec, name, gpu_scale=gpu_scale) for name in NETWORKS}
    assert len({env.model_dump_json() for env, _ in runs.values()}) == 1
    assert len({agent.max_iterations for _, agent in runs.values()}) == 1
    assert len({tuple(getattr(agent, NETWORKS[name])) for name, (_, agent) in runs.items()}) == 1


def test_reward_weights_merge_key_by_key_across_layers(tmp_path):
    spec = dataclasses.replace(registry.get_task("cartpole"), framework_defaults={
        "sb3": {"env": {"reward_weights": {"cart_vel": -0.5}}, "agent": {}}})
    file = write_yaml(tmp_path / "cfg.yaml", {"env": {"reward_weights": {"pole_angle": 3.0}}})
    env, _ = resolve(spec, config_file=file, overrides=["env.reward_weights.alive=2"])
    assert env.reward_weights == {**DEFAULT_WEIGHTS, "cart_vel": -0.5, "pole_angle": 3.0,
                                  "alive": 2.0}
    assert list(env.reward_weights) == list(DEFAULT_WEIGHTS)  # the terms keep their order


@given(st.dictionaries(st.sampled_from(sorted(DEFAULT_WEIGHTS)),
                       st.floats(-100, 100, allow_nan=False), max_size=len(DEFAULT_WEIGHTS)))
def test_any_set_of_reward_weights_overrides_only_those(weights):
    items = [f"env.reward_weights.{term}={typed(w)}" for term, w in weights.items()]
    env, _ = resolve(overrides=items)
    assert env.reward_weights == {**DEFAULT_WEIGHTS, **weights}


# Files -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("text", ["", "env: null\nagent: null\n", "env:\n"])
def test_an_empty_file_or_section_changes_nothing(tmp_path, text):
    (tmp_path / "empty.yaml").write_text(text)
    assert config.load_file(tmp_path / "empty.yaml") == {"env": {}, "agent": {}}


@pytest.mark.parametrize(("text", "complaint"), [
    (None, "does not exist"),
    ("env: [unclosed", "is not valid YAML"),
    ("- env\n- agent\n", "must be a mapping"),
    ("envs:\n  num_envs: 8\n", "must be a mapping with keys 'env' and/or 'agent'"),
    ("[]\n", "must be a mapping"),
    ("env: [1]\n", "'env' holds list [1], not settings"),
    ("env: 3\n", "'env' holds int 3, not settings"),
    ("agent: x\n", "'agent' holds str 'x', not settings"),
])
def test_bad_files_are_lab_errors_naming_the_file(tmp_path, text, complaint):
    path = tmp_path / "cfg.yaml"
    if text is not None:
        path.write_text(text)
    with pytest.raises(LabError) as err:
        config.load_file(path)
    assert str(path) in err.value.message and complaint in err.value.message
    assert "\n" not in str(err.value)


def test_an_unknown_key_in_a_file_is_named_like_one_from_set(tmp_path):
    file = write_yaml(tmp_path / "cfg.yaml", {"agent": {"n_step": 8}})
    with pytest.raises(LabError, match=r"unknown key 'agent.n_step'") as err:
        resolve(config_file=file)
    assert "did you mean 'agent.n_steps'?" in err.value.hint


def test_saved_params_rebuild_the_same_config(tmp_path):
    # Run dirs keep params/env.yaml and agent.yaml; play and resume read them back.
    env, agent = resolve(overrides=["env.reset_cart_pos=[-0.5, 0.5]", "agent.net_arch=[8]",
                                    "env.reward_weights.alive=3"])
    file = tmp_path / "params.yaml"
    file.write_text("env:\n" + _indent(config.to_yaml(env)) + "agent:\n"
                    + _indent(config.to_yaml(agent)))
    env2, agent2 = resolve(config_file=file)
    assert env2 == env and agent2 == agent


def _indent(text: str) -> str:
    return "".join(f"  {line}\n" for line in text.splitlines())
