"""Stable-Baselines3 as a lab framework plugin."""
