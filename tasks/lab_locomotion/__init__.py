"""Built-in locomotion tasks: Isaac Lab's classic Ant and Humanoid, assembled from lab's robot
task building blocks (labcli.envs.mdp)."""
