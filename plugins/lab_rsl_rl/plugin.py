"""Registers RSL-RL through the same hook a third-party framework plugin would use. Its classes
are named, not imported: rsl-rl-lib and torch load only when a command trains or plays."""

from labcli.envs.wrappers import Stage, WrapperSpec
from labcli.plugins.framework import FrameworkSpec
from labcli.plugins.hookspecs import hookimpl

ADAPTER = WrapperSpec(
    "rsl_rl.adapter", Stage.ADAPTER, "lab_rsl_rl.adapter:RslRlVecEnv", framework="rsl_rl",
    description="torch VectorEnv → RSL-RL VecEnv (TensorDict), time-outs flagged")

SPEC = FrameworkSpec(
    name="rsl_rl", framework="lab_rsl_rl.framework:RslRlFramework",
    agent_config="lab_rsl_rl.config:RslRlPpoConfig",
    wrappers=(ADAPTER,), library="rsl-rl-lib", data_parallel=True, critic_observations=True,
    description="RSL-RL PPO (torch end to end; empirical observation normalization)")


@hookimpl
def register_frameworks(register):
    register(SPEC)
