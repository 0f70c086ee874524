"""RSL-RL's PPO with its update replayed as one CUDA graph on a GPU.

All mini-batch steps of an update (forward, losses, backward, gradient clipping, Adam, the
adaptive learning rate) run without host syncs and are replayed as one graph
(`labcli.plugins.update_graph`); on several GPUs the gradients and the KL are averaged over
the ranks inside it. The numbers are RSL-RL's (GPU tests compare updates with the library's own,
on one GPU and on two, tests/test_rsl_rl_graph.py), symmetric data augmentation and the mirror
loss included; on the CPU, or with what the graph leaves out (recurrent models, RND, mixed
precision), the update is the library's, with its Adam fused.
"""

from __future__ import annotations

from typing import Any

import torch
from rsl_rl.algorithms import PPO
from tensordict import TensorDict
from torch import nn

from labcli.plugins.policy import torch_threads
from labcli.plugins.update_graph import (
    UpdateGraph,
    adapt_adam,
    average_over_ranks,
    eager_adam_state,
)


class LabPPO(PPO):
    """PPO whose `update` replays one CUDA graph where it can (`cuda_graph`), whose Adam is
    fused everywhere, and which updates on `update_threads` torch threads on the CPU."""

    update_threads = 1  # the run's TrainContext.update_threads, set by lab's runner

    def __init__(self, *args: Any, cuda_graph: bool = True, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.graphed = (cuda_graph and torch.device(self.device).type == "cuda"
                        and isinstance(self.optimizer, torch.optim.Adam)
                        and not (self.rnd or self.use_mixed_precision or self.actor.is_recurrent
                                 or self.critic.is_recurrent))
        self._batch: dict[str, Any] = {}
        self.fused = isinstance(self.optimizer, torch.optim.Adam)
        if self.graphed:
            self._lr = torch.zeros((), device=self.device)
            # value, surrogate, entropy and, with symmetry, the mirror loss
            self._sums = torch.zeros(4 if self.symmetry else 3, device=self.device)
            self._parameters = [*self.actor.parameters(), *self.critic.parameters()]
            self._graph = UpdateGraph(self._steps, self.optimizer, [self.actor, self.critic],
                                      [self._lr])
        self._adapt_adam()

    def _adapt_adam(self) -> None:
        if self.fused:
            adapt_adam(self.optimizer, self._lr if self.graphed else None)

    def set_learning_rate(self, lr: float) -> None:
        self.learning_rate = lr
        if self.graphed:
            self._lr.fill_(lr)
        else:
            for group in self.optimizer.param_groups:
                group["lr"] = lr

    def save(self) -> dict:
        saved = super().save()
        if self.fused:  # an eager Adam's state: a checkpoint resumes anywhere
            saved["optimizer_state_dict"] = eager_adam_state(saved["optimizer_state_dict"])
        return saved

    def load(self, loaded_dict: dict, load_cfg: dict | None, strict: bool) -> bool:
        done = super().load(loaded_dict, load_cfg, strict)
        self._adapt_adam()
        return done

    def update(self) -> dict[str, float]:
        with torch_threads(self.device, self.update_threads):
            return self._update()

    def _update(self) -> dict[str, float]:
        if not self.graphed:
            return super().update()
        self._load_batch()
        self._graph.replay()
        lr, *sums = torch.cat([self._lr[None], self._sums]).tolist()
        self.learning_rate = lr
        obs = self.storage.observations.flatten(0, 1)
        self.actor.update_normalization(obs)
        self.critic.update_normalization(obs)
        self.storage.clear()
        updates = self.num_learning_epochs * self.num_mini_batches
        names = ("value", "surrogate", "entropy", "symmetry")
        return {name: total / updates for name, total in zip(names, sums, strict=False)}

    def _load_batch(self) -> None:
        """The rollout and this update's shuffle into the graph's fixed buffers: the same
        draw as RSL-RL's mini-batch generator, from the same generator."""
        st = self.storage
        size = st.num_envs * st.num_transitions_per_env // self.num_mini_batches
        indices = torch.randperm(self.num_mini_batches * size, requires_grad=False,
                                 device=self.device)
        fields = {"indices": indices, "actions": st.actions, "values": st.values,
                  "returns": st.returns, "advantages": st.advantages,
                  "old_log_prob": st.actions_log_prob,
                  **{f"obs/{k}": v for k, v in st.observations.items()},
                  **{f"old_param/{i}": p for i, p in enumerate(st.distribution_params)}}
        for name, tensor in fields.items():
            flat = tensor if name == "indices" else tensor.flatten(0, 1)
            if name in self._batch:
                self._batch[name].copy_(flat)
            else:
                self._batch[name] = flat.clone()

    def _steps(self) -> None:
        """Every mini-batch step of an update, as RSL-RL's update does them."""
        self._sums.zero_()
        size = self._batch["indices"].shape[0] // self.num_mini_batches
        for _ in range(self.num_learning_epochs):
            for i in range(self.num_mini_batches):
                self._step(self._batch["indices"][i * size:(i + 1) * size])

    def _step(self, idx: torch.Tensor) -> None:
        b = self._batch
        obs = TensorDict({k.removeprefix("obs/"): v[idx] for k, v in b.items()
                          if k.startswith("obs/")}, batch_size=[idx.shape[0]])
        old_params = tuple(v[idx] for k, v in b.items() if k.startswith("old_param/"))
        actions, old_log_prob = b["actions"][idx], b["old_log_prob"][idx]
        advantages, returns, old_values = b["advantages"][idx], b["returns"][idx], b["values"][idx]
        if self.normalize_advantage_per_mini_batch:
            advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        size = idx.shape[0]
        augmented = self.symmetry is not None and self.symmetry.use_data_augmentation
        if augmented:  # the mirror images appended, as RSL-RL's Symmetry.augment_batch does
            obs, actions = self._mirrored(obs, actions)
            copies = obs.batch_size[0] // size
            old_log_prob, advantages, returns, old_values = (
                t.repeat(copies, 1) for t in (old_log_prob, advantages, returns, old_values))

        # The actor's stochastic forward without its sample, which the update never reads
        # (and whose random draw a graph would have to own).
        output = self.actor.mlp(self.actor.get_latent(obs))
        self.actor.distribution.update(output)
        log_prob = self.actor.get_output_log_prob(actions)
        values = self.critic(obs)
        # The KL and the entropy of the rollout's own samples only, as RSL-RL takes them.
        params = tuple(p[:size] for p in self.actor.output_distribution_params)
        entropy = self.actor.output_entropy[:size]

        if self.desired_kl is not None and self.schedule == "adaptive":
            with torch.no_grad():
                kl = self.actor.get_kl_divergence(old_params, params).mean()
                if self.is_multi_gpu:
                    average_over_ranks([kl])
                lr = self._lr
                lowered = torch.clamp(lr / 1.5, min=1e-5)
                raised = torch.clamp(lr * 1.5, max=1e-2)
                lr.copy_(torch.where(kl > self.desired_kl * 2.0, lowered, torch.where(
                    (kl < self.desired_kl / 2.0) & (kl > 0.0), raised, lr)))

        ratio = torch.exp(log_prob - torch.squeeze(old_log_prob))
        advantages = torch.squeeze(advantages)
        surrogate_loss = torch.max(-advantages * ratio, -advantages * torch.clamp(
            ratio, 1.0 - self.clip_param, 1.0 + self.clip_param)).mean()
        if self.use_clipped_value_loss:
            clipped = old_values + (values - old_values).clamp(-self.clip_param, self.clip_param)
            value_loss = torch.max((values - returns).pow(2), (clipped - returns).pow(2)).mean()
        else:
            value_loss = (returns - values).pow(2).mean()
        loss = (surrogate_loss + self.value_loss_coef * value_loss
                - self.entropy_coef * entropy.mean())
        losses = [value_loss, surrogate_loss, entropy.mean()]
        if self.symmetry is not None:
            mirror_loss = self._mirror_loss(obs, output, size, augmented)
            if self.symmetry.use_mirror_loss:
                loss = loss + self.symmetry.mirror_loss_coeff * mirror_loss
            losses.append(mirror_loss.detach())

        self.optimizer.zero_grad(set_to_none=False)
        loss.backward()
        if self.is_multi_gpu:
            average_over_ranks([p.grad for p in self._parameters if p.grad is not None])
        nn.utils.clip_grad_norm_(self.actor.parameters(), self.max_grad_norm)
        nn.utils.clip_grad_norm_(self.critic.parameters(), self.max_grad_norm)
        self.optimizer.step()
        with torch.no_grad():
            self._sums.add_(torch.stack(losses))

    def _mirrored(self, obs: TensorDict | None, actions: torch.Tensor | None
                  ) -> tuple[TensorDict | None, torch.Tensor | None]:
        """The batch and its mirror images, from the run's symmetry function."""
        return self.symmetry.data_augmentation_func(env=self.symmetry.env, obs=obs,
                                                    actions=actions)

    def _mirror_loss(self, obs: TensorDict, output: torch.Tensor, size: int,
                     augmented: bool) -> torch.Tensor:
        """RSL-RL's mirror loss: the actor's mean on the mirrored observations against the
        mirror image of its mean on the originals (held fixed). An augmented batch already
        holds both means; otherwise the mirrored observations take one more forward."""
        mean = self.actor.distribution.deterministic_output(output)
        if augmented:
            mean_of_mirrored = mean[size:]
        else:
            mirrored, _ = self._mirrored(obs, None)
            mean_of_mirrored = self.actor.distribution.deterministic_output(
                self.actor.mlp(self.actor.get_latent(mirrored[size:])))
        _, mirrored_mean = self._mirrored(None, mean[:size].detach())
        return nn.functional.mse_loss(mean_of_mirrored, mirrored_mean[size:])
