"""A run's life (config, run dirs, training, checkpoints, resume, signals, progress) and the other
library calls the commands make (play, export, bench, plot, info)."""
