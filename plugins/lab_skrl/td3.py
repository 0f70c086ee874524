"""skrl's TD3 (Fujimoto et al., 2018) with a tanh-bounded deterministic actor (lab_skrl.offpolicy
has what it shares with SAC: the critics, the replay memory saved with each checkpoint). The
exploration and target-smoothing noises are skrl's Gaussian noise, in fractions of the bound."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from skrl.agents.torch.td3 import TD3, TD3_CFG
from skrl.resources.noises.torch import GaussianNoise

from lab_skrl.adapter import SkrlEnv
from lab_skrl.config import SkrlTD3Config
from lab_skrl.offpolicy import BoundedActor, OffPolicy, agent_settings, critics, replay_memory


class TanhActor(BoundedActor):
    """tanh(MLP(observation)) · bound."""

    def act(self, inputs: dict[str, Any], role: str = "") -> tuple[torch.Tensor, dict]:
        return self.compute(inputs, role)


class _UpdateCount:
    """TD3's count of critic updates as a checkpoint module: every policy_delay-th one also
    updates the actor, so a resume must go on counting where it stopped."""

    def __init__(self, agent: TD3):
        self.agent = agent

    def state_dict(self) -> dict[str, torch.Tensor]:
        return {"critic_updates": torch.tensor(self.agent._update_counter)}

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        self.agent._update_counter = int(state["critic_updates"])


class LabSkrlTD3(OffPolicy, TD3):
    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.checkpoint_modules["update_count"] = _UpdateCount(self)


def make_agent(cfg: SkrlTD3Config, env: SkrlEnv, device: str, run_dir: Path,
               scale_rewards: Any) -> LabSkrlTD3:
    obs_space, act_space = env.observation_space, env.action_space

    def actor() -> TanhActor:
        return TanhActor(obs_space, act_space, device, cfg.hidden_sizes, cfg.activation,
                         cfg.action_bound)

    def noise(fraction: float) -> dict[str, Any]:
        return {"mean": 0.0, "std": fraction * cfg.action_bound, "device": device}

    td3_cfg = TD3_CFG(
        exploration_noise=GaussianNoise if cfg.exploration_noise else None,
        exploration_noise_kwargs=noise(cfg.exploration_noise), policy_delay=cfg.policy_delay,
        smooth_regularization_noise=GaussianNoise if cfg.smoothing_noise else None,
        smooth_regularization_noise_kwargs=noise(cfg.smoothing_noise),
        smooth_regularization_clip=cfg.smoothing_clip * cfg.action_bound,
        **agent_settings(cfg, obs_space, device, run_dir, scale_rewards))
    models = {"policy": actor(), "target_policy": actor(),
              **critics(cfg, obs_space, act_space, device)}
    agent = LabSkrlTD3(models=models, memory=replay_memory(cfg, env.num_envs, device),
                       observation_space=obs_space, action_space=act_space, device=device,
                       cfg=td3_cfg, rollouts=cfg.rollouts)
    agent.init()
    return agent
