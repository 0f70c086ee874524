"""What lab's SAC and TD3 share on top of skrl's agents: twin Q critics, a tanh-bounded actor,
transitions that enter the replay memory at the end of each iteration, and the replay memory
saved beside every checkpoint, so that a resumed run continues as if it had never stopped."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import torch
from skrl.agents.torch import ExperimentCfg
from skrl.memories.torch import RandomMemory
from skrl.models.torch import Model
from torch import nn

from lab_skrl.config import OffPolicyConfig
from lab_skrl.networks import Critic, mlp
from lab_skrl.ppo import OBS_EPSILON, RankedScaler
from labcli.errors import LabError
from labcli.plugins.policy import read_torch_file, torch_threads
from labcli.plugins.update_graph import adapt_adam

OPTIMIZERS = ("policy_optimizer", "critic_optimizer", "entropy_optimizer")


class SquashedMean(nn.Module):
    """The deterministic action: tanh of the network's first `actions` outputs, scaled to the
    bound (SAC's network also gives log stds after them)."""

    def __init__(self, net: nn.Module, actions: int, bound: float):
        super().__init__()
        self.net, self.actions, self.bound = net, actions, bound

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self.net(obs)[..., :self.actions]) * self.bound


class BoundedActor(Model):
    """An actor whose actions lie in ±bound: its network gives `outputs` numbers per action,
    the first of them the squashed mean. Its random actions are uniform in ±bound (skrl's own
    sample the action space, which may be far wider)."""

    outputs = OffPolicyConfig.actor_outputs  # numbers per action

    def __init__(self, observation_space: gym.Space, action_space: gym.Space, device: Any,
                 hidden_sizes: list[int], activation: str, bound: float):
        Model.__init__(self, observation_space=observation_space, action_space=action_space,
                       device=device)
        self.net = mlp(self.num_observations, hidden_sizes, self.outputs * self.num_actions,
                       activation)
        self.deterministic = SquashedMean(self.net, self.num_actions, bound)
        self.bound = bound

    def compute(self, inputs: dict[str, Any], role: str = "") -> tuple[torch.Tensor, dict]:
        return self.deterministic(inputs["observations"]), {}

    def random_act(self, inputs: dict[str, Any], role: str = "") -> tuple[torch.Tensor, dict]:
        n = inputs["observations"].shape[0]
        uniform = torch.rand(n, self.num_actions, device=self.device)
        return (2 * uniform - 1) * self.bound, {}


def critics(cfg: OffPolicyConfig, obs_space: gym.Space, act_space: gym.Space,
            device: str) -> dict[str, Critic]:
    """Twin Q critics and their targets."""
    return {name: Critic(obs_space, act_space, device, cfg.hidden_sizes, cfg.activation,
                         of_actions=True)
            for name in ("critic_1", "critic_2", "target_critic_1", "target_critic_2")}


def agent_settings(cfg: OffPolicyConfig, obs_space: gym.Space, device: str, run_dir: Path,
                   scale_rewards: Any) -> dict[str, Any]:
    """The settings skrl's SAC_CFG and TD3_CFG share, from lab's config."""
    return dict(
        gradient_steps=cfg.gradient_steps, batch_size=cfg.batch_size,
        discount_factor=cfg.discount_factor, polyak=cfg.polyak, learning_rate=cfg.learning_rate,
        observation_preprocessor=RankedScaler if cfg.normalize_obs else None,
        observation_preprocessor_kwargs={"size": obs_space, "clip_threshold": cfg.clip_obs,
                                         "epsilon": OBS_EPSILON, "device": device},
        random_timesteps=cfg.learning_starts, learning_starts=cfg.learning_starts,
        grad_norm_clip=cfg.grad_norm_clip, rewards_shaper=scale_rewards,
        # lab writes checkpoints and the common TensorBoard tags; skrl's own writer and
        # checkpointer stay off.
        experiment=ExperimentCfg(directory=str(run_dir.parent), experiment_name=run_dir.name,
                                 write_interval=0, checkpoint_interval=0))


def replay_memory(cfg: OffPolicyConfig, num_envs: int, device: str) -> RandomMemory:
    # Drawn with replacement: without, skrl permutes the whole memory for every batch.
    return RandomMemory(memory_size=max(1, cfg.buffer_size // num_envs), num_envs=num_envs,
                        device=device, replacement=True)


class OffPolicy:
    """Mixed into skrl's SAC and TD3: the transitions enter the replay memory, and the updates
    run, at the end of each iteration's rollout: step by step, as skrl's would have after each
    env step, with the same memory contents. A stop mid-rollout then leaves the memory and
    networks as the last complete iteration left them, which is what lab checkpoints and
    resumes from. It updates on `update_threads` torch threads on the CPU, and tracks its
    losses for lab to log (skrl tracks them only with its own writer on)."""

    update_threads = 1  # the run's TrainContext.update_threads, set by lab's framework

    def __init__(self, *args: Any, rollouts: int, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.rollouts = rollouts
        self._staged: list[dict[str, Any]] = []
        self.fuse_adam()

    def fuse_adam(self) -> None:
        """Each Adam steps its parameters in one fused kernel; again after a checkpoint's
        optimizer states are loaded, which bring back skrl's eager settings."""
        for name in OPTIMIZERS:
            if hasattr(self, name):
                adapt_adam(getattr(self, name))

    def set_learning_rate(self, lr: float) -> None:
        for name in OPTIMIZERS:
            for group in getattr(self, name).param_groups if hasattr(self, name) else ():
                group["lr"] = lr

    def record_transition(self, **transition: Any) -> None:
        # The env may reuse its tensors at the next step: a copy waits for the rollout's end.
        self._staged.append({name: value.clone() if isinstance(value, torch.Tensor) else value
                             for name, value in transition.items() if name != "infos"})

    def post_interaction(self, *, timestep: int, timesteps: int) -> None:
        # skrl's, without its own TensorBoard writing and checkpoints: lab does both.
        if len(self._staged) == self.rollouts:
            staged, self._staged = self._staged, []
            self.learn(staged, timesteps)

    def learn(self, staged: list[dict[str, Any]], timesteps: int) -> None:
        """The rollout's transitions into the memory, each followed by its updates."""
        self.enable_models_training_mode(True)
        with torch_threads(self.device, self.update_threads):
            for transition in staged:
                super().record_transition(infos=None, **transition)  # type: ignore[misc]
                if self.training and transition["timestep"] >= self.cfg.learning_starts:
                    self.update(timestep=transition["timestep"], timesteps=timesteps)
        self.enable_models_training_mode(False)

    def update(self, *, timestep: int, timesteps: int) -> None:
        # skrl's update tracks its figures only with a write interval, and its record of a
        # transition then tracks rewards too, which lab logs itself: on for the update alone.
        self.write_interval = 1
        try:
            super().update(timestep=timestep, timesteps=timesteps)  # type: ignore[misc]
        finally:
            self.write_interval = 0


# The replay memory beside each checkpoint -------------------------------------------------------

def memory_path(checkpoint: Path) -> Path:
    """memory_<N>.pt beside model_<N>.pt."""
    return checkpoint.with_name(checkpoint.name.replace("model_", "memory_", 1))


def save_memory(memory: RandomMemory, path: Path) -> None:
    """The memory's filled rows and where it writes next, as plain tensors and numbers."""
    rows = memory.memory_size if memory.filled else memory.memory_index
    torch.save({"tensors": {name: tensor[:rows].clone()
                            for name, tensor in memory.tensors.items()},
                "memory_index": memory.memory_index, "filled": memory.filled}, path)


def load_memory(memory: RandomMemory, checkpoint: Path) -> None:
    """Refill `memory` from the file beside `checkpoint`; without one (the last good state of
    a run that diverged, which lab keeps without its memory) it starts empty. A resume with
    another env count keeps the newest transitions that fill whole rows of the new layout; a
    LabError when they do not fit at all (another observation or action size)."""
    path = memory_path(checkpoint)
    if not path.exists() and not path.is_symlink():
        return
    saved = read_torch_file(path, str(memory.device), what="replay memory")
    try:
        tensors, index, filled = saved["tensors"], saved["memory_index"], bool(saved["filled"])
        if set(tensors) != set(memory.tensors):
            raise ValueError(f"it holds {sorted(tensors)}, this run {sorted(memory.tensors)}")
        for name, tensor in memory.tensors.items():
            if tensors[name].shape[2:] != tensor.shape[2:]:
                raise ValueError(f"its '{name}' are of size {tuple(tensors[name].shape[2:])}, "
                                 f"this run's {tuple(tensor.shape[2:])}")
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise LabError(f"replay memory {path} does not fit this run: {exc}",
                       "resume it on the task it was trained on") from None
    layout = (memory.memory_size if filled else index, memory.num_envs)
    if all(tensors[name].shape[:2] == layout for name in memory.tensors):
        # The same layout: row for row, so that sampling draws what it would have drawn.
        rows = tensors["observations"].shape[0]
        for name, tensor in memory.tensors.items():
            tensor[:rows].copy_(tensors[name])
        memory.memory_index, memory.filled, memory.env_index = index, filled, 0
        return
    # Oldest first, one transition after another, then the newest into whole rows.
    ordered = {name: (torch.cat([t[index:], t[:index]]) if filled else t).flatten(0, 1)
               for name, t in tensors.items()}
    envs, capacity = memory.num_envs, memory.memory_size
    rows = min(capacity, ordered["observations"].shape[0] // envs)
    for name, tensor in memory.tensors.items():
        kept = ordered[name][len(ordered[name]) - rows * envs:]
        tensor[:rows].copy_(kept.view(rows, envs, *tensor.shape[2:]))
    memory.filled = rows == capacity
    memory.memory_index, memory.env_index = (0 if memory.filled else rows), 0
