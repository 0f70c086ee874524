"""The MLPs of lab's skrl models (PPO's actor and value, SAC's and TD3's actors and critics),
and the critic they share."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import torch
from skrl.models.torch import DeterministicMixin, Model
from torch import nn

ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}


def mlp(n_in: int, hidden: list[int], n_out: int, activation: str) -> nn.Sequential:
    layers: list[nn.Module] = []
    for size in hidden:
        layers += [nn.Linear(n_in, size), ACTIVATIONS[activation]()]
        n_in = size
    return nn.Sequential(*layers, nn.Linear(n_in, n_out))


class Critic(DeterministicMixin, Model):
    """V(observation), PPO's value, or with `of_actions` Q(observation, action), SAC's and
    TD3's critics. Given a `state_space` it reads skrl's states (a task's critic observations)
    instead of the observations."""

    def __init__(self, observation_space: gym.Space, action_space: gym.Space, device: Any,
                 hidden_sizes: list[int], activation: str, of_actions: bool = False,
                 state_space: gym.Space | None = None):
        Model.__init__(self, observation_space=state_space or observation_space,
                       action_space=action_space, device=device)
        DeterministicMixin.__init__(self, clip_actions=False)
        self.of_actions = of_actions
        self.reads = "observations" if state_space is None else "states"
        inputs = self.num_observations + (self.num_actions if of_actions else 0)
        self.net = mlp(inputs, hidden_sizes, 1, activation)

    def compute(self, inputs: dict[str, Any], role: str = "") -> tuple[torch.Tensor, dict]:
        x = inputs[self.reads]
        if self.of_actions:
            x = torch.cat([x, inputs["taken_actions"]], -1)
        return self.net(x), {}
