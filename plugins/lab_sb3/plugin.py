"""Registers SB3's PPO, SAC and TD3 through the same hook a third-party framework plugin would
use. Their classes are named, not imported: stable-baselines3 and torch load only when a command
trains or plays."""

import dataclasses

from labcli.envs.wrappers import Stage, WrapperSpec
from labcli.plugins.framework import FrameworkSpec
from labcli.plugins.hookspecs import hookimpl

ADAPTER = WrapperSpec("sb3.adapter", Stage.ADAPTER, "lab_sb3.adapter:Sb3VecEnv", framework="sb3",
                      description="torch VectorEnv → SB3 VecEnv (numpy), time-outs flagged")
VEC_NORMALIZE = WrapperSpec(
    "sb3.vec_normalize", Stage.FRAMEWORK, "lab_sb3.adapter:BatchedVecNormalize",
    framework="sb3", description="SB3's running observation/reward normalization (VecNormalize)")

SPEC = FrameworkSpec(
    name="sb3", framework="lab_sb3.framework:Sb3Framework",
    agent_config="lab_sb3.config:Sb3PPOConfig",
    wrappers=(ADAPTER, VEC_NORMALIZE), library="stable-baselines3", checkpoint_suffix=".zip",
    description="Stable-Baselines3 PPO (numpy VecEnv; VecNormalize optional)")


# skrl's off-policy shapes (lab_skrl.plugin) in SB3's terms: few envs, train_freq steps each,
# then gradient_steps updates; the learner, not the physics, bounds an off-policy run on the
# CPU.
OFF_POLICY_DEFAULTS = {
    "cartpole": {"env": {"num_envs": 16}, "agent": {
        "max_iterations": 300, "train_freq": 32, "gradient_steps": 128, "net_arch": [64, 64]}},
    "ant": {"env": {"num_envs": 32}, "agent": {
        "max_iterations": 1000, "train_freq": 8, "gradient_steps": 16, "learning_starts": 3200}},
}


def _cartpole(**agent: object) -> dict:
    cartpole = OFF_POLICY_DEFAULTS["cartpole"]
    return {**OFF_POLICY_DEFAULTS, "cartpole": {
        "env": cartpole["env"], "agent": {**cartpole["agent"], **agent}}}


# Cartpole on 2 cores, 25 iterations, seeds 0-2: SAC's return rose by 166-204 with skrl's start
# (100 random steps of each env, the entropy coefficient learned from 0.2), by 84, 46 and -48
# with SB3's (100 random steps in all, from 1.0); TD3's rose by 81-114 after 512 random steps
# and by 20 after 100.
SAC_DEFAULTS = _cartpole(learning_starts=1600, ent_coef="auto_0.2")
TD3_DEFAULTS = _cartpole(learning_starts=512)


def _off_policy(algorithm: str, description: str,
                task_defaults: dict) -> FrameworkSpec:
    name = f"sb3_{algorithm}"

    def owned(wrapper: WrapperSpec) -> WrapperSpec:
        return dataclasses.replace(wrapper, name=wrapper.name.replace("sb3", name, 1),
                                   framework=name)

    return FrameworkSpec(
        name=name, framework=f"lab_sb3.framework:Sb3{algorithm.upper()}Framework",
        agent_config=f"lab_sb3.config:Sb3{algorithm.upper()}Config",
        wrappers=(owned(ADAPTER), owned(VEC_NORMALIZE)), library="stable-baselines3",
        checkpoint_suffix=".zip", task_defaults=task_defaults,
        newest_only={"memory_": "replay buffer"},
        description=f"Stable-Baselines3 {description} (off-policy; its replay buffer is saved "
                    "with the newest checkpoint)")


SAC_SPEC = _off_policy("sac", "SAC, tanh-squashed Gaussian actor", SAC_DEFAULTS)
TD3_SPEC = _off_policy("td3", "TD3, tanh-bounded deterministic actor", TD3_DEFAULTS)


@hookimpl
def register_frameworks(register):
    register(SPEC)
    register(SAC_SPEC)
    register(TD3_SPEC)
