"""Building blocks of robot tasks (Isaac Lab's `mdp`): term configs (`config`), the robot's
named views (`robot`, `names`), observation, reward, termination, event, action and success
terms, the sensors they read, and `RobotTask`, which assembles a task from its config's terms.
See docs/plugins.md, "Writing a robot task"."""
