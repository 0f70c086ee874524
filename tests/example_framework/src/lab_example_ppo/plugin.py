"""The plugin module named by the entry point: one hook, one framework. Its classes are named as
"module:Class" strings, imported only when a command trains or plays: `lab list` and tab
completion stay instant, without torch."""

from labcli.envs.wrappers import Stage, WrapperSpec
from labcli.plugins.framework import FrameworkSpec
from labcli.plugins.hookspecs import hookimpl

ADAPTER = WrapperSpec(
    "example_ppo.adapter", Stage.ADAPTER, "lab_example_ppo.adapter:PPOEnv",
    framework="example_ppo", description="torch VectorEnv → the example PPO's env")


@hookimpl
def register_frameworks(register):
    register(FrameworkSpec(
        name="example_ppo",
        framework="lab_example_ppo.framework:ExamplePPO",
        agent_config="lab_example_ppo.config:ExamplePPOConfig",
        wrappers=(ADAPTER,),  # the adapter first; lab registers them with the framework
        description="a small PPO that owns its training loop (an example plugin)",
        library="lab-example-ppo",  # the library's distribution, for `lab info` and manifests
        # Defaults for tasks this framework knows; a task's own defaults for it would win.
        task_defaults={
            "cartpole": {"env": {"num_envs": 128},
                         "agent": {"max_iterations": 150, "steps_per_env": 32, "epochs": 8,
                                   "minibatches": 8, "learning_rate": 1e-3}},
        },
    ))
