"""skrl's Soft Actor-Critic with a tanh-squashed Gaussian actor (lab_skrl.offpolicy has what it
shares with TD3: the critics, the replay memory saved with each checkpoint).

skrl's SAC samples a plain Gaussian and lets the env clip it; here actions are squashed into
±`action_bound` with the change-of-variables term in their log-probability (Haarnoja et al.,
2018, appendix C), as SB3 and CleanRL do: the entropy target then means what it says. The
deterministic action, which lab plays and exports, is tanh(mean) · bound.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from skrl.agents.torch.sac import SAC, SAC_CFG

from lab_skrl.adapter import SkrlEnv
from lab_skrl.config import SkrlSACConfig
from lab_skrl.offpolicy import BoundedActor, OffPolicy, agent_settings, critics, replay_memory

LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0  # CleanRL's and FastTD3's bounds of the actor's log std


class SquashedActor(BoundedActor):
    """One MLP gives the mean and log std of a Gaussian whose samples are squashed by tanh."""

    outputs = SkrlSACConfig.actor_outputs  # a mean and a log std per action

    def act(self, inputs: dict[str, Any], role: str = "") -> tuple[torch.Tensor, dict]:
        mean, log_std = self.net(inputs["observations"]).chunk(2, dim=-1)
        log_std = log_std.clamp(LOG_STD_MIN, LOG_STD_MAX)
        noise = torch.randn_like(mean)
        unsquashed = mean + log_std.exp() * noise
        # log N(u) - log|d tanh(u)/du|, the latter as 2 (log 2 - u - softplus(-2u)): stable
        # where tanh saturates. The constant log(bound) leaves the gradients as they are.
        gaussian = -0.5 * noise.square() - log_std - 0.5 * math.log(2 * math.pi)
        jacobian = 2 * (math.log(2) - unsquashed - F.softplus(-2 * unsquashed))
        log_prob = (gaussian - jacobian).sum(dim=-1, keepdim=True)
        return torch.tanh(unsquashed) * self.bound, {
            "log_prob": log_prob, "mean_actions": torch.tanh(mean) * self.bound}


class _EntropyCoefficient:
    """The learned log entropy coefficient as a checkpoint module: skrl checkpoints its
    optimizer's state but not the value it optimizes."""

    def __init__(self, agent: SAC):
        self.agent = agent

    def state_dict(self) -> dict[str, torch.Tensor]:
        return {"log_value": self.agent.log_entropy_coefficient.detach().clone()}

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        value = self.agent.log_entropy_coefficient
        with torch.no_grad():
            value.copy_(state["log_value"].reshape(value.shape))
        self.agent._entropy_coefficient = torch.exp(value.detach())


class LabSkrlSAC(OffPolicy, SAC):
    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        if self.cfg.learn_entropy:
            self.checkpoint_modules["entropy_coefficient"] = _EntropyCoefficient(self)


def make_agent(cfg: SkrlSACConfig, env: SkrlEnv, device: str, run_dir: Path,
               scale_rewards: Any) -> LabSkrlSAC:
    obs_space, act_space = env.observation_space, env.action_space
    models = {"policy": SquashedActor(obs_space, act_space, device, cfg.hidden_sizes,
                                      cfg.activation, cfg.action_bound),
              **critics(cfg, obs_space, act_space, device)}
    sac_cfg = SAC_CFG(learn_entropy=cfg.learn_entropy,
                      initial_entropy_value=cfg.initial_entropy_value,
                      target_entropy=cfg.target_entropy,
                      **agent_settings(cfg, obs_space, device, run_dir, scale_rewards))
    agent = LabSkrlSAC(models=models, memory=replay_memory(cfg, env.num_envs, device),
                       observation_space=obs_space, action_space=act_space, device=device,
                       cfg=sac_cfg, rollouts=cfg.rollouts)
    agent.init()
    return agent
