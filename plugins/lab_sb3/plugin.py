"""Registers SB3 through the same hook a third-party framework plugin would use. Its classes are
named, not imported: stable-baselines3 and torch load only when a command trains or plays."""

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


@hookimpl
def register_frameworks(register):
    register(SPEC)
