"""RSL-RL's PPO with its update replayed as one CUDA graph on a GPU.

RSL-RL's update is launch-bound at lab's scale: each mini-batch step is a few hundred small
kernels and four host syncs (the adaptive learning rate's KL test, three loss reads), ~6 ms on
an H100 whatever the batch size. Here all mini-batch steps of an update (forward, losses,
backward, gradient clipping, Adam, the adaptive learning rate) are captured once and replayed
each iteration, with the learning rate a device tensor and the losses summed on the device: one
sync an update. The numbers are RSL-RL's (a GPU test compares updates with the library's own,
tests/test_rsl_rl_graph.py); on the CPU, or with what the graph leaves out (recurrent models,
RND, symmetry, several GPUs, mixed precision), the update is the library's.
"""

from __future__ import annotations

from itertools import chain
from typing import Any

import torch
from rsl_rl.algorithms import PPO
from tensordict import TensorDict
from torch import nn


class LabPPO(PPO):
    """PPO whose `update` replays one CUDA graph where it can (`cuda_graph`)."""

    def __init__(self, *args: Any, cuda_graph: bool = True, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.graphed = (cuda_graph and torch.device(self.device).type == "cuda"
                        and not (self.rnd or self.symmetry or self.is_multi_gpu
                                 or self.use_mixed_precision or self.actor.is_recurrent
                                 or self.critic.is_recurrent))
        self._graph: torch.cuda.CUDAGraph | None = None
        self._batch: dict[str, Any] = {}
        self._buffers: list[tuple[nn.Module, str, torch.Tensor]] = []
        if self.graphed:
            # Adam that reads its learning rate from the device, and may be captured.
            self._lr = torch.tensor(float(self.learning_rate), device=self.device)
            self.optimizer = torch.optim.Adam(
                chain(self.actor.parameters(), self.critic.parameters()), lr=self._lr,
                capturable=True, fused=True)
            self._sums = torch.zeros(3, device=self.device)  # value, surrogate, entropy

    def set_learning_rate(self, lr: float) -> None:
        self.learning_rate = lr
        if self.graphed:
            self._lr.fill_(lr)
        else:
            for group in self.optimizer.param_groups:
                group["lr"] = lr

    def save(self) -> dict:
        saved = super().save()
        if self.graphed:  # an eager Adam's state, so that a checkpoint resumes anywhere
            state = saved["optimizer_state_dict"]
            for group in state["param_groups"]:
                group.update(lr=float(self._lr), capturable=False, fused=None)
            # state_dict() hands out the live per-parameter dicts: copied, not changed.
            state["state"] = {i: {**entry, "step": entry["step"].to("cpu", torch.float32)}
                              for i, entry in state["state"].items()}
        return saved

    def load(self, loaded_dict: dict, load_cfg: dict | None, strict: bool) -> bool:
        done = super().load(loaded_dict, load_cfg, strict)
        if self.graphed:
            # Loading took the saved groups' settings: the device learning rate and the
            # capturable, fused Adam come back.
            self._lr.fill_(float(self.optimizer.param_groups[0]["lr"]))
            for group in self.optimizer.param_groups:
                group.update(lr=self._lr, capturable=True, fused=True)
            for entry in self.optimizer.state.values():
                entry["step"] = entry["step"].to(self.device, torch.float32)
            self.learning_rate = float(self._lr)
        return done

    def update(self) -> dict[str, float]:
        if not self.graphed:
            return super().update()
        self._load_batch()
        if self._graph is None:
            self._capture()
        self._graph.replay()
        lr, value, surrogate, entropy = torch.cat([self._lr[None], self._sums]).tolist()
        self.learning_rate = lr
        obs = self.storage.observations.flatten(0, 1)
        self.actor.update_normalization(obs)
        self.critic.update_normalization(obs)
        self._keep_buffers()
        self.storage.clear()
        updates = self.num_learning_epochs * self.num_mini_batches
        return {"value": value / updates, "surrogate": surrogate / updates,
                "entropy": entropy / updates}

    def _keep_buffers(self) -> None:
        """The graph reads the models' buffers where they were at capture; RSL-RL's normalizer
        rebinds its std to a new tensor on every update. The new values go where the graph
        reads them, and that tensor stays the buffer."""
        for module, name, captured in self._buffers:
            current = module._buffers[name]
            if current is not captured:
                captured.copy_(current)
                module._buffers[name] = captured

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

    def _capture(self) -> None:
        # A warm-up outside the graph creates what the capture needs (Adam's moments, the
        # gradients, library workspaces); then everything it changed is put back, so that the
        # first replay is the update the library would do.
        params = [p for group in self.optimizer.param_groups for p in group["params"]]
        before = [p.detach().clone() for p in params]
        state = {p: {k: v.clone() for k, v in s.items()} for p, s in self.optimizer.state.items()}
        lr = self._lr.clone()
        side = torch.cuda.Stream(self.device)
        side.wait_stream(torch.cuda.current_stream(self.device))
        with torch.cuda.stream(side):
            self._steps()
        torch.cuda.current_stream(self.device).wait_stream(side)
        self._buffers = [(m, name, b) for m in chain(self.actor.modules(), self.critic.modules())
                         for name, b in m._buffers.items() if b is not None]
        self._graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(self._graph):
            self._steps()
        with torch.no_grad():
            for p, value in zip(params, before, strict=True):
                p.copy_(value)
            for p, s in self.optimizer.state.items():
                for key, value in s.items():
                    value.copy_(state[p][key]) if p in state else value.zero_()
            self._lr.copy_(lr)

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
        advantages, returns, old_values = b["advantages"][idx], b["returns"][idx], b["values"][idx]
        if self.normalize_advantage_per_mini_batch:
            advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)

        # The actor's stochastic forward without its sample, which the update never reads
        # (and whose random draw a graph would have to own).
        self.actor.distribution.update(self.actor.mlp(self.actor.get_latent(obs)))
        log_prob = self.actor.get_output_log_prob(b["actions"][idx])
        values = self.critic(obs)
        params = self.actor.output_distribution_params
        entropy = self.actor.output_entropy

        if self.desired_kl is not None and self.schedule == "adaptive":
            with torch.no_grad():
                kl = self.actor.get_kl_divergence(old_params, params).mean()
                lr = self._lr
                lowered = torch.clamp(lr / 1.5, min=1e-5)
                raised = torch.clamp(lr * 1.5, max=1e-2)
                lr.copy_(torch.where(kl > self.desired_kl * 2.0, lowered, torch.where(
                    (kl < self.desired_kl / 2.0) & (kl > 0.0), raised, lr)))

        ratio = torch.exp(log_prob - torch.squeeze(b["old_log_prob"][idx]))
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

        self.optimizer.zero_grad(set_to_none=False)
        loss.backward()
        nn.utils.clip_grad_norm_(self.actor.parameters(), self.max_grad_norm)
        nn.utils.clip_grad_norm_(self.critic.parameters(), self.max_grad_norm)
        self.optimizer.step()
        with torch.no_grad():
            self._sums.add_(torch.stack([value_loss, surrogate_loss, entropy.mean()]))
