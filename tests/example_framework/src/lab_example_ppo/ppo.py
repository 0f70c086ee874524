"""The library: a small PPO that owns its training loop, as most RL libraries do. It knows
nothing of lab. Its env is anything with `num_envs`, `observation_size`, `action_size`,
`reset() -> obs` and `step(actions) -> (obs, reward, done, timeout)`, all torch tensors."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch
from torch import nn
from torch.distributions import Normal

EPS, CLIP = 1e-8, 10.0  # RunningNorm's defaults


class RunningNorm(nn.Module):
    """Observation statistics: (x - mean) / sqrt(var + eps), clipped to ±clip."""

    def __init__(self, size: int, eps: float = EPS, clip: float = CLIP):
        super().__init__()
        self.eps, self.clip = eps, clip
        self.register_buffer("mean", torch.zeros(size))
        self.register_buffer("var", torch.ones(size))
        self.register_buffer("count", torch.tensor(1e-4))

    def update(self, x: torch.Tensor) -> None:
        mean, var, n = x.mean(0), x.var(0, unbiased=False), x.shape[0]
        delta, total = mean - self.mean, self.count + n
        self.var.copy_((self.var * self.count + var * n
                        + delta.square() * self.count * n / total) / total)
        self.mean.add_(delta * n / total)
        self.count.copy_(total)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return ((x - self.mean) / torch.sqrt(self.var + self.eps)).clamp(-self.clip, self.clip)


def mlp(sizes: Sequence[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for n_in, n_out in zip(sizes[:-2], sizes[1:-1], strict=True):
        layers += [nn.Linear(n_in, n_out), nn.Tanh()]
    return nn.Sequential(*layers, nn.Linear(sizes[-2], sizes[-1]))


class ActorCritic(nn.Module):
    def __init__(self, observations: int, actions: int, hidden: Sequence[int]):
        super().__init__()
        self.actor = mlp([observations, *hidden, actions])
        self.critic = mlp([observations, *hidden, 1])
        self.log_std = nn.Parameter(torch.zeros(actions))


class PPO:
    def __init__(self, env: Any, hidden: Sequence[int] = (64, 64), learning_rate: float = 3e-4,
                 steps: int = 16, epochs: int = 4, minibatches: int = 4, gamma: float = 0.99,
                 lam: float = 0.95, clip: float = 0.2, normalize: bool = True,
                 device: str = "cpu"):
        self.env, self.steps, self.epochs, self.minibatches = env, steps, epochs, minibatches
        self.gamma, self.lam, self.clip, self.device = gamma, lam, clip, device
        self.model = ActorCritic(env.observation_size, env.action_size, hidden).to(device)
        self.norm = RunningNorm(env.observation_size).to(device) if normalize else None
        self.optimizer = torch.optim.Adam(self.model.parameters(), lr=learning_rate)
        self.iteration = self.steps_done = 0

    def normalize(self, obs: torch.Tensor) -> torch.Tensor:
        return obs if self.norm is None else self.norm(obs)

    def act(self, obs: torch.Tensor, deterministic: bool = False) -> torch.Tensor:
        mean = self.model.actor(self.normalize(obs))
        return mean if deterministic else mean + torch.randn_like(mean) * self.model.log_std.exp()

    def learn(self, iterations: int,
              callback: Callable[[int, dict[str, float]], None] | None = None) -> None:
        """Train until `iterations` in all, calling `callback(iteration, figures)` after each
        rollout and update."""
        obs = self.env.reset()
        while self.iteration < iterations:
            obs, batch = self._collect(obs)
            figures = self._update(batch)
            if self.norm is not None:  # after the update, which used the rollout's statistics
                self.norm.update(batch["obs"])
            self.iteration += 1
            self.steps_done += self.steps * self.env.num_envs
            if callback is not None:
                callback(self.iteration, figures)

    def _collect(self, obs: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        names = ("obs", "actions", "log_probs", "values", "rewards", "dones")
        rollout: dict[str, list[torch.Tensor]] = {name: [] for name in names}
        with torch.no_grad():
            for _ in range(self.steps):
                x = self.normalize(obs)
                mean, value = self.model.actor(x), self.model.critic(x).squeeze(-1)
                dist = Normal(mean, self.model.log_std.exp())
                actions = dist.sample()
                next_obs, reward, done, timeout = self.env.step(actions)
                # A time-out is no failure: bootstrap it with the value of where it stopped.
                reward = reward + self.gamma * value * timeout
                for name, item in zip(names, (obs, actions, dist.log_prob(actions).sum(-1),
                                              value, reward, done), strict=True):
                    rollout[name].append(item)
                obs = next_obs
            next_value = self.model.critic(self.normalize(obs)).squeeze(-1)
        batch = {name: torch.stack(items) for name, items in rollout.items()}
        advantages = torch.zeros_like(batch["rewards"])
        last = torch.zeros_like(next_value)
        for t in reversed(range(self.steps)):
            following = next_value if t == self.steps - 1 else batch["values"][t + 1]
            alive = 1.0 - batch["dones"][t]
            delta = batch["rewards"][t] + self.gamma * following * alive - batch["values"][t]
            last = delta + self.gamma * self.lam * alive * last
            advantages[t] = last
        batch["returns"] = advantages + batch["values"]
        batch["advantages"] = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        return obs, {name: item.flatten(0, 1) for name, item in batch.items()}

    def _update(self, batch: dict[str, torch.Tensor]) -> dict[str, float]:
        losses = torch.zeros(2, device=self.device)
        count = len(batch["obs"])
        for _ in range(self.epochs):
            for idx in torch.randperm(count, device=self.device).chunk(self.minibatches):
                x = self.normalize(batch["obs"][idx])
                dist = Normal(self.model.actor(x), self.model.log_std.exp())
                ratio = (dist.log_prob(batch["actions"][idx]).sum(-1)
                         - batch["log_probs"][idx]).exp()
                advantages = batch["advantages"][idx]
                policy_loss = -torch.min(ratio * advantages, ratio.clamp(
                    1 - self.clip, 1 + self.clip) * advantages).mean()
                value = self.model.critic(x).squeeze(-1)
                value_loss = (value - batch["returns"][idx]).square().mean()
                self.optimizer.zero_grad()
                (policy_loss + 0.5 * value_loss).backward()
                nn.utils.clip_grad_norm_(self.model.parameters(), 1.0)
                self.optimizer.step()
                losses += torch.stack((policy_loss, value_loss)).detach()
        policy, value = (losses / (self.epochs * self.minibatches)).tolist()
        return {"loss/policy": policy, "loss/value": value}

    def state_dict(self) -> dict[str, Any]:
        return {"model": self.model.state_dict(), "optimizer": self.optimizer.state_dict(),
                "norm": None if self.norm is None else self.norm.state_dict(),
                "iteration": self.iteration, "steps_done": self.steps_done}

    def save(self, name: str | Path) -> None:
        """Writes `<name>.pt`."""
        torch.save(self.state_dict(), f"{name}.pt")

    def load(self, path: str | Path) -> None:
        state = torch.load(path, map_location=self.device, weights_only=True)
        self.model.load_state_dict(state["model"])
        self.optimizer.load_state_dict(state["optimizer"])
        if self.norm is not None:
            self.norm.load_state_dict(state["norm"])
        self.iteration, self.steps_done = state["iteration"], state["steps_done"]
