"""rl_games as a lab framework plugin."""
