"""Registers skrl's PPO, SAC and TD3 through the same hook a third-party framework plugin would use.
Their classes are named, not imported: skrl and torch load only when a command trains or
plays."""

import dataclasses

from labcli.envs.wrappers import Stage, WrapperSpec
from labcli.plugins.framework import FrameworkSpec
from labcli.plugins.hookspecs import hookimpl

ADAPTER = WrapperSpec("skrl.adapter", Stage.ADAPTER, "lab_skrl.adapter:SkrlEnv", framework="skrl",
                      description="torch VectorEnv → skrl env wrapper (torch), time-outs flagged")

SPEC = FrameworkSpec(
    name="skrl", framework="lab_skrl.framework:SkrlFramework",
    agent_config="lab_skrl.config:SkrlPPOConfig",
    wrappers=(ADAPTER,), library="skrl", data_parallel=True, critic_observations=True,
    description="skrl PPO (torch end to end; running observation normalizer)")


# Few envs and several updates a step: the learner, not the physics, bounds an off-policy run
# on the CPU. Cartpole on 2 cores: SAC's return rose from -100 to 0-50 in 12,800 steps, where
# 8 steps an iteration took 25 iterations to get over the dip after its random actions.
OFF_POLICY_DEFAULTS = {
    "cartpole": {"env": {"num_envs": 16}, "agent": {
        "max_iterations": 300, "rollouts": 32, "gradient_steps": 4, "hidden_sizes": [64, 64]}},
    # On 2 cores, success 0.9 after a median 98 k steps and 122 s with SAC, 154 k and 147 s
    # with TD3 (rsl_rl's PPO: 516 k and 110.5 s; docs/benchmarks.md).
    "ant": {"env": {"num_envs": 32}, "agent": {"max_iterations": 1000, "gradient_steps": 2}},
}


def _off_policy(algorithm: str, framework: str, description: str) -> FrameworkSpec:
    name = f"skrl_{algorithm}"
    return FrameworkSpec(
        name=name, framework=f"lab_skrl.framework:{framework}",
        agent_config=f"lab_skrl.config:Skrl{algorithm.upper()}Config",
        wrappers=(dataclasses.replace(ADAPTER, name=f"{name}.adapter", framework=name),),
        library="skrl", task_defaults=OFF_POLICY_DEFAULTS,
        newest_only={"memory_": "replay memory"},
        description=f"skrl {description} (off-policy; its replay memory is saved with the "
                    "newest checkpoint)")


SAC_SPEC = _off_policy("sac", "SkrlSACFramework", "SAC, tanh-squashed Gaussian actor")
TD3_SPEC = _off_policy("td3", "SkrlTD3Framework", "TD3, tanh-bounded deterministic actor")


@hookimpl
def register_frameworks(register):
    register(SPEC)
    register(SAC_SPEC)
    register(TD3_SPEC)
