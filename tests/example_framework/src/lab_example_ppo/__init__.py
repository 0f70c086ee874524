"""A small PPO library (`ppo.py`) and the lab plugin that brings it to lab's tasks."""
