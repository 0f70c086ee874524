"""RSL-RL (rsl-rl-lib 5.x) as a lab framework plugin."""
