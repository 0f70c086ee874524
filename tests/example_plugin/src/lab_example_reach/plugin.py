"""The plugin module named by the entry point: one hook, one task. The task's classes are named
as "module:Class" strings, imported only when the task is used: `lab list` and tab completion
stay instant, without torch."""

from pathlib import Path

from labcli.envs.spec import TaskSpec
from labcli.plugins.hookspecs import hookimpl


@hookimpl
def register_tasks(register):
    register(TaskSpec(
        name="point_reach",
        task="lab_example_reach.reach:Reach",
        config="lab_example_reach.reach:ReachConfig",
        model=Path(__file__).with_name("reach.xml"),
        description="push a point mass to a random target on a plane and stay there",
        success="within 0.1 m of the target at the 4 s time-out",
        # Per framework, overrides of the env config and the framework's agent config.
        framework_defaults={
            "sb3": {"env": {"num_envs": 64},
                    "agent": {"max_iterations": 60, "n_steps": 64, "batch_size": 512,
                              "gamma": 0.98}},
            "rsl_rl": {"env": {"num_envs": 256},
                       "agent": {"max_iterations": 100, "num_steps_per_env": 32}},
            "skrl": {"env": {"num_envs": 256},
                     "agent": {"max_iterations": 100, "rollouts": 32}},
        },
    ))
