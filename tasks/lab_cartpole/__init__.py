"""The cartpole task that ships with lab."""
