"""TensorBoard tags that every framework logs the same way, so runs compare across libraries."""

EPISODES = "Train/episodes"
MEAN_RETURN = "Train/mean_reward"
MEAN_LENGTH = "Train/mean_episode_length"
SUCCESS_RATE = "Metrics/success_rate"
# On a terrain with a curriculum: the mean level (row) of the ended episodes.
TERRAIN_LEVEL = "Metrics/terrain/level"
# + a task's episode metric (Task.episode_metrics), e.g. "base_velocity/error_vel_xy".
TASK_METRIC = "Metrics/"
REWARD_TERM = "Episode_Reward/"
TERMINATION = "Episode_Termination/"
INSTABILITIES = "sim/instabilities"
# + a MuJoCo Warp buffer's name (NEFC, NARROWPHASE...): env steps that overflowed it.
OVERFLOW = "sim/overflow/"
STEPS_PER_S = "Perf/steps_per_s"
TOTAL_STEPS = "Perf/total_steps"
NONFINITE_ACTIONS = "sim/nonfinite_actions"
MUJOCO_WARNINGS = "sim/mujoco_warnings"
