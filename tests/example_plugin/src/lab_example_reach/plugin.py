"""The plugin module named by the entry point: one hook, one task."""

from lab_example_reach.reach import MODEL, Reach, ReachConfig
from labcli.hookspecs import hookimpl
from labcli.task import TaskSpec


@hookimpl
def register_tasks(register):
    register(TaskSpec(
        name="point_reach",
        task=Reach,
        config=ReachConfig,
        model=MODEL,
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
