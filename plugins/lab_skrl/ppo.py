"""skrl's PPO with its update's epochs replayed as one CUDA graph on a GPU.

skrl's update reads three losses per mini-batch and the adaptive learning rate's KL per epoch
from the device. Here the returns and advantages are skrl's own (`compute_gae`), and every
mini-batch step of every epoch (the observation scaler's update, forward, losses, backward,
gradient clipping, Adam, the KL-adaptive learning rate) runs without host syncs and is replayed
as one graph (`labcli.plugins.update_graph`); on several GPUs the gradients, the KL and the
observation scaler's statistics are averaged over the ranks inside it. The numbers are skrl's
(GPU tests compare updates with the library's own, on one GPU and on two,
tests/test_skrl_graph.py); on the CPU, or with what the graph leaves out (KL early stopping,
other schedulers, mixed precision, a shared policy and value model), the update is the
library's, with its Adam fused.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from skrl import config
from skrl.agents.torch.ppo import PPO
from skrl.agents.torch.ppo.ppo import compute_gae
from skrl.resources.preprocessors.torch import RunningStandardScaler
from skrl.resources.schedulers.torch import KLAdaptiveLR
from torch import nn

from labcli.plugins.policy import torch_threads
from labcli.plugins.update_graph import (
    UpdateGraph,
    adapt_adam,
    average_over_ranks,
    eager_adam_state,
)


def join_ranks(rank: int, local_rank: int, world_size: int) -> None:
    """Tell skrl's config the ranks of a data-parallel run. skrl reads them from torchrun's
    variables once, when imported, and then sets up NCCL itself; lab has set up the process
    group (gloo on the CPU) and kept the variables from it. With the ranks known, skrl's agents
    broadcast rank 0's parameters and average gradients and the KL over the ranks. Its config
    has no setter for them. Its notes of each broadcast are left out: lab says what runs."""
    logging.getLogger("skrl").setLevel(logging.WARNING if world_size > 1 else logging.DEBUG)
    cfg = config.torch
    cfg._rank, cfg._local_rank, cfg._world_size = rank, local_rank, world_size
    cfg._is_distributed = world_size > 1


OBS_EPSILON = 1e-8  # RunningStandardScaler's default, stored so the frozen copy matches


class RankedScaler(RunningStandardScaler):
    """skrl's running standard scaler, whose statistics take in the batches of every rank of a
    data-parallel run (skrl's own updates from its rank's alone, so the ranks' scalers, and the
    policies they feed, would drift apart). Alone, it is skrl's."""

    def _parallel_variance(self, input_mean: torch.Tensor, input_var: torch.Tensor,
                           input_count: int) -> None:
        if config.torch.is_distributed:
            # Every rank's batch is as large: the union's mean, and its unbiased variance
            # (torch.var's, as skrl computes it) from each rank's sums of squares.
            n, world = input_count, config.torch.world_size
            sums = torch.stack([input_mean * n, input_var * (n - 1) + input_mean**2 * n])
            torch.distributed.all_reduce(sums)
            total = n * world
            input_mean = sums[0] / total
            input_var = (sums[1] - input_mean**2 * total) / (total - 1)
            input_count = total
        super()._parallel_variance(input_mean, input_var, input_count)


class LabSkrlPPO(PPO):
    """PPO whose `update` replays one CUDA graph where it can (`cuda_graph`), whose Adam is
    fused everywhere, and which updates on `update_threads` torch threads on the CPU."""

    update_threads = 1  # the run's TrainContext.update_threads, set by lab's framework

    def __init__(self, *args: Any, cuda_graph: bool = True, **kwargs: Any):
        super().__init__(*args, **kwargs)
        cfg = self.cfg
        self.graphed = (
            cuda_graph and torch.device(self.device).type == "cuda"
            and isinstance(self.optimizer, torch.optim.Adam) and self.policy is not self.value
            and (self.scheduler is None or isinstance(self.scheduler, KLAdaptiveLR))
            and not (cfg.kl_threshold or cfg.mixed_precision))
        self.fused = isinstance(self.optimizer, torch.optim.Adam)
        if self.graphed:
            self._lr = torch.zeros((), device=self.device)
            self._sums = torch.zeros(4, device=self.device)  # policy, value, entropy, std
            modules = [self.policy, self.value, self._observation_preprocessor,
                       self._state_preprocessor]
            self._graph = UpdateGraph(self._epochs, self.optimizer,
                                      [m for m in modules if isinstance(m, nn.Module)],
                                      [self._lr])
            self._shuffles: torch.Tensor | None = None
        if self.fused:
            self._adapt_adam()
            self.checkpoint_modules["optimizer"] = _AdamState(self)

    def _adapt_adam(self) -> None:
        adapt_adam(self.optimizer, self._lr if self.graphed else None)

    def set_learning_rate(self, lr: float) -> None:
        if self.graphed:
            self._lr.fill_(lr)
        else:
            for group in self.optimizer.param_groups:
                group["lr"] = lr

    def record_transition(self, **transition: Any) -> None:
        """skrl's, with its time-out bootstrap added at every step. skrl adds it under `if
        truncated.any()`, which reads the device back at every env step; the same sum (nothing
        added where no env timed out) waits for nothing."""
        cfg = self.cfg
        if not (self.training and cfg.time_limit_bootstrap):
            super().record_transition(**transition)
            return
        rewards = transition["rewards"]
        if cfg.rewards_shaper is not None:  # skrl shapes the rewards before the bootstrap
            rewards = cfg.rewards_shaper(rewards, transition["timestep"], transition["timesteps"])
        with torch.no_grad():
            next_values, _ = self.value.act({
                "observations": self._observation_preprocessor(transition["next_observations"]),
                "states": self._state_preprocessor(transition["next_states"])}, role="value")
            next_values = self._value_preprocessor(next_values, inverse=True)
        bootstrap = cfg.discount_factor * next_values * transition["truncated"]
        transition["rewards"] = rewards + bootstrap
        shaper, cfg.rewards_shaper, cfg.time_limit_bootstrap = cfg.rewards_shaper, None, False
        try:  # skrl's own shaping and bootstrap off: done above
            super().record_transition(**transition)
        finally:
            cfg.rewards_shaper, cfg.time_limit_bootstrap = shaper, True

    def update(self, *, timestep: int, timesteps: int) -> None:
        with torch_threads(self.device, self.update_threads):
            self._update(timestep=timestep, timesteps=timesteps)

    def _update(self, *, timestep: int, timesteps: int) -> None:
        if not self.graphed:
            return super().update(timestep=timestep, timesteps=timesteps)
        self._returns_and_advantages()
        self._load_shuffles()
        self._graph.replay()
        lr, policy, value, entropy, std = torch.cat([self._lr[None], self._sums]).tolist()
        updates = self.cfg.learning_epochs * self.cfg.mini_batches
        self.track_data("Loss / Policy loss", policy / updates)
        self.track_data("Loss / Value loss", value / updates)
        if self.cfg.entropy_loss_scale:
            self.track_data("Loss / Entropy loss", entropy / updates)
        self.track_data("Policy / Standard deviation", std)
        if self.scheduler:
            self.scheduler._last_lr = [lr] * len(self.optimizer.param_groups)
            self.track_data("Learning / Learning rate", lr)

    def _returns_and_advantages(self) -> None:
        """What skrl's update does before its epochs, with skrl's functions."""
        with torch.no_grad():
            inputs = {
                "observations": self._observation_preprocessor(self._current_next_observations),
                "states": self._state_preprocessor(self._current_next_states),
            }
            self.value.enable_training_mode(False)
            last_values, _ = self.value.act(inputs, role="value")
            self.value.enable_training_mode(True)
            last_values = self._value_preprocessor(last_values, inverse=True)
        memory = self.memory
        values = memory.get_tensor_by_name("values")
        returns, advantages = compute_gae(
            rewards=memory.get_tensor_by_name("rewards"),
            terminated=memory.get_tensor_by_name("terminated"),
            truncated=memory.get_tensor_by_name("truncated"),
            values=values, last_values=last_values, discount_factor=self.cfg.discount_factor,
            lambda_coefficient=self.cfg.gae_lambda,
            time_limit_bootstrap=self.cfg.time_limit_bootstrap)
        memory.set_tensor_by_name("values", self._value_preprocessor(values, train=True))
        memory.set_tensor_by_name("returns", self._value_preprocessor(returns, train=True))
        memory.set_tensor_by_name("advantages", advantages)

    def _load_shuffles(self) -> None:
        """Each epoch's shuffle into the graph's index buffer: the draws of skrl's
        RandomMemory.sample, from the same (CPU) generator."""
        size = len(self.memory)
        drawn = torch.stack([torch.randperm(size, dtype=torch.long)
                             for _ in range(self.cfg.learning_epochs)])
        if self._shuffles is None:
            self._shuffles = drawn.to(self.device)
            # np.array_split's mini-batch bounds, as skrl's sample_by_index splits
            ends = np.cumsum([len(b) for b in np.array_split(np.arange(size),
                                                              self.cfg.mini_batches)])
            self._bounds = list(zip([0, *ends[:-1].tolist()], ends.tolist(), strict=True))
        else:
            self._shuffles.copy_(drawn)

    def _epochs(self) -> None:
        """Every mini-batch step of an update, as skrl's update does them."""
        self._sums.zero_()
        for epoch in range(self.cfg.learning_epochs):
            kls = [self._step(self._shuffles[epoch, lo:hi], train=not epoch)
                   for lo, hi in self._bounds]
            if isinstance(self.scheduler, KLAdaptiveLR):
                kl = torch.stack(kls).mean()
                if config.torch.is_distributed:
                    average_over_ranks([kl])
                self._adapt_learning_rate(kl)
        with torch.no_grad():  # skrl reports the std of the last mini-batch's distribution
            self._sums[3] = self.policy.distribution(role="policy").stddev.mean()

    def _adapt_learning_rate(self, kl: torch.Tensor) -> None:
        """KLAdaptiveLR.step on the device."""
        s, lr = self.scheduler, self._lr
        lowered = torch.clamp(lr / s._lr_factor, min=s.min_lr)
        raised = torch.clamp(lr * s._lr_factor, max=s.max_lr)
        lr.copy_(torch.where(kl > s.kl_threshold * s._kl_factor, lowered, torch.where(
            kl < s.kl_threshold / s._kl_factor, raised, lr)))

    def _step(self, idx: torch.Tensor, train: bool) -> torch.Tensor:
        """One mini-batch step; returns its approximate KL."""
        cfg, batch = self.cfg, self.memory.tensors_view
        states = batch.get("states")  # a task's critic observations, where it has them
        inputs = {
            "observations": self._observation_preprocessor(batch["observations"][idx],
                                                           train=train),
            "states": self._state_preprocessor(None if states is None else states[idx],
                                               train=train),
        }
        _, outputs = self.policy.act({**inputs, "taken_actions": batch["actions"][idx]},
                                     role="policy")
        log_prob, old_log_prob = outputs["log_prob"], batch["log_prob"][idx]
        with torch.no_grad():
            ratio = log_prob - old_log_prob
            kl = ((torch.exp(ratio) - 1) - ratio).mean()
        if cfg.entropy_loss_scale:
            entropy_loss = (-cfg.entropy_loss_scale
                            * self.policy.get_entropy(role="policy").mean())
        else:
            entropy_loss = torch.zeros((), device=self.device)
        advantages = batch["advantages"][idx]
        ratio = torch.exp(log_prob - old_log_prob)
        surrogate = advantages * ratio
        clipped = advantages * torch.clip(ratio, 1.0 - cfg.ratio_clip, 1.0 + cfg.ratio_clip)
        policy_loss = -torch.min(surrogate, clipped).mean()
        predicted, _ = self.value.act(inputs, role="value")
        if cfg.value_clip > 0:
            old_values = batch["values"][idx]
            predicted = old_values + torch.clip(predicted - old_values, min=-cfg.value_clip,
                                                max=cfg.value_clip)
        value_loss = cfg.value_loss_scale * F.mse_loss(batch["returns"][idx], predicted)

        self.optimizer.zero_grad(set_to_none=False)
        (policy_loss + entropy_loss + value_loss).backward()
        parameters = [*self.policy.parameters(), *self.value.parameters()]
        if config.torch.is_distributed:
            average_over_ranks([p.grad for p in parameters if p.grad is not None])
        if cfg.grad_norm_clip > 0:
            nn.utils.clip_grad_norm_(parameters, cfg.grad_norm_clip)
        self.optimizer.step()
        with torch.no_grad():
            self._sums[:3] += torch.stack([policy_loss, value_loss, entropy_loss])
        return kl


class _AdamState:
    """The agent's Adam as a checkpoint module: saved as an eager Adam's state, so that a
    checkpoint resumes anywhere (skrl's own agent included); loaded back as this agent's."""

    def __init__(self, agent: LabSkrlPPO):
        self.agent = agent

    def state_dict(self) -> dict[str, Any]:
        return eager_adam_state(self.agent.optimizer.state_dict())

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.agent.optimizer.load_state_dict(state)
        self.agent._adapt_adam()
