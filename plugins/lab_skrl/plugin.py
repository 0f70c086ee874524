"""Registers skrl through the same hook a third-party framework plugin would use. Its classes are
named, not imported: skrl and torch load only when a command trains or plays."""

from labcli.envs.wrappers import Stage, WrapperSpec
from labcli.plugins.framework import FrameworkSpec
from labcli.plugins.hookspecs import hookimpl

ADAPTER = WrapperSpec("skrl.adapter", Stage.ADAPTER, "lab_skrl.adapter:SkrlEnv", framework="skrl",
                      description="torch VectorEnv → skrl env wrapper (torch), time-outs flagged")

SPEC = FrameworkSpec(
    name="skrl", framework="lab_skrl.framework:SkrlFramework",
    agent_config="lab_skrl.config:SkrlPPOConfig",
    wrappers=(ADAPTER,), library="skrl", data_parallel=True,
    description="skrl PPO (torch end to end; running observation normalizer)")


@hookimpl
def register_frameworks(register):
    register(SPEC)
