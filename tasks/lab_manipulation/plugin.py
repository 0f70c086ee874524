"""Registers the manipulation tasks through the same hook a third-party package would use."""

from lab_manipulation import panda
from labcli.envs.spec import TaskSpec
from labcli.plugins.hookspecs import hookimpl

TASK = "labcli.envs.mdp.task:RobotTask"
REACH_SUCCESS = ("at the 12 s time-out, the hand within 5 cm and 0.35 rad of the pose "
                 "commanded last")
# Isaac Lab's reach agents (config/franka/agents): 24 steps per env, [64, 64] ELU networks, 8
# epochs of 4 mini-batches, lr 1e-3 adapted to a KL of 0.01, entropy 0.001, 1,000 iterations at
# 4,096 envs.
NETWORK = [64, 64]


def _reach_defaults(num_envs: int, max_iterations: int) -> dict:
    """rsl_rl's and skrl's PPO as Isaac Lab's agents; on the GPU (warp backend) at Isaac Lab's
    4,096 envs and 1,000 iterations, not yet measured there."""
    env = {"env": {"num_envs": num_envs}}
    defaults = {
        "rsl_rl": {**env, "agent": {
            "max_iterations": max_iterations, "num_steps_per_env": 24,
            "actor_hidden_dims": NETWORK, "critic_hidden_dims": NETWORK, "activation": "elu",
            "learning_rate": 1e-3, "desired_kl": 0.01, "num_learning_epochs": 8,
            "num_mini_batches": 4, "entropy_coef": 0.001, "empirical_normalization": False}},
        "skrl": {**env, "agent": {
            "max_iterations": max_iterations, "rollouts": 24, "learning_epochs": 8,
            "mini_batches": 4, "learning_rate": 1e-3, "desired_kl": 0.01,
            "entropy_loss_scale": 0.001, "value_loss_scale": 1.0, "hidden_sizes": NETWORK,
            "activation": "elu", "normalize_obs": False, "normalize_value": False}},
    }
    for settings in defaults.values():
        settings["warp"] = {"env": {"num_envs": 4096}, "agent": {"max_iterations": 1000}}
    return defaults


LIFT_SUCCESS = "at the 5 s time-out, the cube within 5 cm of the position commanded"
# Isaac Lab's lift agents (lift/config/franka/agents): rsl_rl's 24 steps per env, [256, 128,
# 64] ELU networks, 5 epochs of 4 mini-batches, lr 1e-4 adapted to a KL of 0.01, entropy 0.006,
# gamma 0.98, lambda 0.95, 1,500 iterations at 4,096 envs; skrl's the same PPO in its keys.
LIFT_NETWORK = [256, 128, 64]


def _lift_defaults(num_envs: int, max_iterations: int) -> dict:
    env = {"env": {"num_envs": num_envs}}
    defaults = {
        "rsl_rl": {**env, "agent": {
            "max_iterations": max_iterations, "num_steps_per_env": 24,
            "actor_hidden_dims": LIFT_NETWORK, "critic_hidden_dims": LIFT_NETWORK,
            "activation": "elu", "learning_rate": 1e-4, "desired_kl": 0.01,
            "num_learning_epochs": 5, "num_mini_batches": 4, "entropy_coef": 0.006,
            "gamma": 0.98, "lam": 0.95, "empirical_normalization": False}},
        "skrl": {**env, "agent": {
            "max_iterations": max_iterations, "rollouts": 24, "learning_epochs": 5,
            "mini_batches": 4, "learning_rate": 1e-4, "desired_kl": 0.01,
            "entropy_loss_scale": 0.006, "discount_factor": 0.98, "gae_lambda": 0.95,
            "value_loss_scale": 1.0, "hidden_sizes": LIFT_NETWORK, "activation": "elu",
            "normalize_obs": False, "normalize_value": False}},
    }
    for settings in defaults.values():
        settings["warp"] = {"env": {"num_envs": 4096}, "agent": {"max_iterations": 1500}}
    return defaults


@hookimpl
def register_tasks(register):
    register(TaskSpec(
        name="panda-reach", task=TASK, config="lab_manipulation.config:PandaReachConfig",
        model=panda.MODEL,
        description="Isaac Lab's Reach-Franka: MuJoCo Menagerie's Franka Panda moves its hand "
                    "to commanded poses",
        success=REACH_SUCCESS,
        framework_defaults=_reach_defaults(num_envs=256, max_iterations=1000)))
    register(TaskSpec(
        name="panda-lift", task=TASK, config="lab_manipulation.config:PandaLiftConfig",
        model=panda.CUBE_MODEL,
        description="Isaac Lab's Lift-Cube-Franka: MuJoCo Menagerie's Franka Panda picks a "
                    "cube off the floor and carries it to commanded positions",
        success=LIFT_SUCCESS,
        framework_defaults=_lift_defaults(num_envs=256, max_iterations=1500)))
