"""Registers rl_games through the same hook a third-party framework plugin would use. Its classes
are named, not imported: rl-games and torch load only when a command trains or plays."""

from labcli.envs.wrappers import Stage, WrapperSpec
from labcli.plugins.framework import FrameworkSpec
from labcli.plugins.hookspecs import hookimpl

ADAPTER = WrapperSpec(
    "rl_games.adapter", Stage.ADAPTER, "lab_rl_games.adapter:RlGamesVecEnv",
    framework="rl_games",
    description="torch VectorEnv → rl_games IVecEnv (torch), time-outs flagged")

SPEC = FrameworkSpec(
    name="rl_games", framework="lab_rl_games.framework:RlGamesFramework",
    agent_config="lab_rl_games.config:RlGamesPPOConfig",
    wrappers=(ADAPTER,), library="rl-games", checkpoint_suffix=".pth",
    description="rl_games PPO (torch end to end; running input and value normalization)")


@hookimpl
def register_frameworks(register):
    register(SPEC)
