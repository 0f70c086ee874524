"""PPO, SAC and TD3 from skrl behind lab's Framework API.

lab drives the loop itself (what skrl's SequentialTrainer does: `rollouts` steps an iteration,
then the update) so that it can report each iteration, checkpoint through lab and stop on
Ctrl-C. A checkpoint is skrl's own agent checkpoint (a dict of state dicts: policy, value or
critics, optimizers, preprocessors) plus a `lab` entry with the sizes and network shape needed
to rebuild the policy; SAC's and TD3's replay memory is a file beside it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import torch
from skrl.agents.torch import ExperimentCfg
from skrl.agents.torch.ppo import PPO_CFG
from skrl.memories.torch import RandomMemory
from skrl.models.torch import GaussianMixin, Model
from skrl.resources.schedulers.torch import KLAdaptiveLR
from torch import nn

from lab_skrl import offpolicy, sac, td3
from lab_skrl.adapter import SkrlEnv
from lab_skrl.config import OffPolicyConfig, SkrlPPOConfig
from lab_skrl.networks import Critic, mlp
from lab_skrl.ppo import OBS_EPSILON, LabSkrlPPO, RankedScaler, join_ranks
from labcli.errors import LabError, first_line
from labcli.plugins.framework import Framework, TrainContext
from labcli.plugins.policy import (
    ObsNormalizer,
    Policy,
    check_mlp,
    one_torch_thread,
    read_torch_file,
)

META = "lab"  # checkpoint entry with what lab needs besides skrl's modules
META_KEYS = {"observation_size", "action_size", "hidden_sizes", "activation", "obs_clip",
             "obs_epsilon", "steps"}
SkrlAgent = LabSkrlPPO | offpolicy.OffPolicy


class Actor(GaussianMixin, Model):
    """Gaussian policy: `net` gives the mean action, a free parameter the log std."""

    def __init__(self, observation_space: gym.Space, action_space: gym.Space, device: Any,
                 hidden_sizes: list[int], activation: str, init_log_std: float):
        Model.__init__(self, observation_space=observation_space, action_space=action_space,
                       device=device)
        GaussianMixin.__init__(self, clip_actions=False, clip_log_std=True, min_log_std=-20.0,
                               max_log_std=2.0, reduction="sum")
        self.net = mlp(self.num_observations, hidden_sizes, self.num_actions, activation)
        self.log_std_parameter = nn.Parameter(torch.full((self.num_actions,), init_log_std))

    def compute(self, inputs: dict[str, Any], role: str = "") -> tuple[torch.Tensor, dict]:
        return self.net(inputs["observations"]), {"log_std": self.log_std_parameter}


class _ScaleRewards:
    """skrl's rewards_shaper. It also hands skrl a new tensor, which matters because skrl adds
    the time-out bootstrap to the rewards it is given in place."""

    def __init__(self, scale: float):
        self.scale = scale

    def __call__(self, rewards: torch.Tensor, timestep: int, timesteps: int) -> torch.Tensor:
        return rewards * self.scale


def make_agent(cfg: SkrlPPOConfig, env: SkrlEnv, device: str, run_dir: Path) -> LabSkrlPPO:
    obs_space, act_space, state_space = env.observation_space, env.action_space, env.state_space
    models = {
        "policy": Actor(obs_space, act_space, device, cfg.hidden_sizes, cfg.activation,
                        cfg.init_log_std),
        # A task's critic observations, where it has them, are the value model's input.
        "value": Critic(obs_space, act_space, device, cfg.hidden_sizes, cfg.activation,
                        state_space=state_space),
    }
    ppo_cfg = PPO_CFG(
        rollouts=cfg.rollouts, learning_epochs=cfg.learning_epochs,
        mini_batches=cfg.mini_batches, discount_factor=cfg.discount_factor,
        gae_lambda=cfg.gae_lambda, learning_rate=cfg.learning_rate,
        learning_rate_scheduler=KLAdaptiveLR if cfg.kl_adaptive_lr else None,
        learning_rate_scheduler_kwargs={"kl_threshold": cfg.desired_kl} if cfg.kl_adaptive_lr
        else {},
        # skrl 2.x: `observation_preprocessor` normalizes what the policy sees (1.x called it
        # `state_preprocessor`; 2.x keeps that name for a separate critic state, unused here).
        observation_preprocessor=RankedScaler if cfg.normalize_obs else None,
        observation_preprocessor_kwargs={"size": obs_space, "clip_threshold": cfg.clip_obs,
                                         "epsilon": OBS_EPSILON, "device": device},
        state_preprocessor=RankedScaler if cfg.normalize_obs and state_space else None,
        state_preprocessor_kwargs={"size": state_space, "clip_threshold": cfg.clip_obs,
                                   "epsilon": OBS_EPSILON, "device": device},
        value_preprocessor=RankedScaler if cfg.normalize_value else None,
        value_preprocessor_kwargs={"size": 1, "device": device},
        grad_norm_clip=cfg.grad_norm_clip, ratio_clip=cfg.ratio_clip, value_clip=cfg.value_clip,
        entropy_loss_scale=cfg.entropy_loss_scale, value_loss_scale=cfg.value_loss_scale,
        # Time-outs are not failures: bootstrap from the value of the true last observation.
        time_limit_bootstrap=True,
        rewards_shaper=_ScaleRewards(cfg.reward_scale),
        # lab writes checkpoints and the common TensorBoard tags; skrl's own writer and
        # checkpointer stay off (its per-step reward tracking would also sync every step).
        experiment=ExperimentCfg(directory=str(run_dir.parent), experiment_name=run_dir.name,
                                 write_interval=0, checkpoint_interval=0),
    )
    memory = RandomMemory(memory_size=cfg.rollouts, num_envs=env.num_envs, device=device)
    agent = LabSkrlPPO(models=models, memory=memory, observation_space=obs_space,
                       state_space=state_space, action_space=act_space, device=device, cfg=ppo_cfg,
                       cuda_graph=cfg.cuda_graph)
    agent.init()
    return agent


class SkrlFramework(Framework):
    """skrl's PPO; the off-policy frameworks below change what differs for SAC and TD3 (the
    agent, what a checkpoint holds besides skrl's modules, the policy it plays)."""

    def make_agent(self, env: SkrlEnv, ctx: TrainContext) -> Any:
        return make_agent(ctx.cfg, env, ctx.device, ctx.run_dir)  # type: ignore[arg-type]

    def restore(self, agent: Any, saved: dict[str, Any], ctx: TrainContext) -> None:
        load_agent(agent, saved, ctx.resume.path)  # type: ignore[union-attr]
        if "learning_rate" in ctx.changed:  # the optimizer came back with the old one
            agent.set_learning_rate(ctx.cfg.learning_rate)  # type: ignore[attr-defined]

    def networks(self, agent: Any) -> tuple[nn.Module, ...]:
        return agent.policy, agent.value

    def describe(self, cfg: Any) -> dict[str, Any]:
        """What the policy's network is, beside its weights: load_policy rebuilds it from
        this alone."""
        return {"hidden_sizes": list(cfg.hidden_sizes), "activation": cfg.activation,
                "obs_clip": cfg.clip_obs, "obs_epsilon": OBS_EPSILON}

    def save_beside(self, agent: Any, checkpoint: Path) -> None:
        """Files a checkpoint holds besides skrl's modules: none for PPO."""

    def train(self, env: SkrlEnv, ctx: TrainContext) -> None:
        cfg = ctx.cfg
        join_ranks(ctx.rank, torch.device(ctx.device).index or 0, ctx.world_size)
        agent = self.make_agent(env, ctx)
        agent.update_threads = ctx.update_threads
        steps = 0
        if ctx.resume is not None:
            saved = read_checkpoint(ctx.resume.path)
            self.restore(agent, saved, ctx)
            steps = saved[META]["steps"]
        meta = {"observation_size": _size(env.observation_space),
                "action_size": _size(env.action_space), **self.describe(cfg)}

        def save_agent(path: Path) -> None:
            modules = {name: module.state_dict()
                       for name, module in agent.checkpoint_modules.items()}
            torch.save({**modules, META: {**meta, "steps": steps}}, path)

        def save(path: Path) -> None:
            save_agent(path)
            self.save_beside(agent, path)

        agent.enable_training_mode(True)
        ctx.watch(*self.networks(agent))
        ctx.set_actor(lambda obs: _act(agent, obs))
        # A stop mid-rollout raises StopTraining from env.step: that rollout is dropped, and
        # ctx.training checkpoints the last complete iteration.
        with one_torch_thread(ctx.device), ctx.training(save):
            obs, _ = env.reset()
            ctx.restore_rng()
            for iteration in range(ctx.start_iteration + 1, cfg.max_iterations + 1):
                obs = _collect_and_update(agent, env, obs, ctx, iteration)
                steps += cfg.rollouts * env.num_envs
                # The last good state kept each iteration: the agent without what is saved
                # beside it (a replay memory, rewritten whole at every save).
                if ctx.end_iteration(iteration, steps, save, _pop_tracking(agent),
                                     last_good=save_agent):
                    break

    def actor(self, checkpoint: Path, saved: dict[str, Any], env: Any) -> nn.Module:
        """The deterministic actor of a checkpoint, its weights loaded."""
        meta = saved[META]
        hidden = check_mlp(checkpoint, meta["observation_size"], meta["hidden_sizes"],
                           meta["action_size"])
        actor = Actor(env.single_observation_space, env.single_action_space, "cpu", hidden,
                      meta["activation"], 0.0)
        _load_policy_weights(actor, saved, checkpoint)
        return actor.net

    def load_policy(self, checkpoint: Path, env: Any, cfg: Any = None) -> Policy:
        # The checkpoint describes its own networks (see save): `cfg` is not needed.
        saved = read_checkpoint(checkpoint)
        meta = saved[META]
        _check_sizes(checkpoint, meta, env)
        actor = self.actor(checkpoint, saved, env)
        normalizer = None
        scaler = saved.get("observation_preprocessor")
        if scaler is not None:
            # skrl computes (x - mean) / (sqrt(var) + eps); ObsNormalizer divides by
            # sqrt(var' + 0), so var' = (sqrt(var) + eps)² gives the same numbers.
            std = scaler["running_variance"].sqrt() + meta["obs_epsilon"]
            normalizer = ObsNormalizer(scaler["running_mean"], std.square(), 0.0, meta["obs_clip"])
        return Policy(actor, normalizer).eval()


class _OffPolicyFramework(SkrlFramework):
    """skrl's SAC or TD3 (lab_skrl.offpolicy): each checkpoint also saves the replay memory,
    and the policy played and exported is the actor's deterministic, bounded action."""

    algorithm: Any  # the module with the agent's make_agent and actor class
    actor_class: type[offpolicy.BoundedActor]

    def make_agent(self, env: SkrlEnv, ctx: TrainContext) -> Any:
        cfg: OffPolicyConfig = ctx.cfg  # type: ignore[assignment]
        return self.algorithm.make_agent(cfg, env, ctx.device, ctx.run_dir,
                                         _ScaleRewards(cfg.reward_scale))

    def restore(self, agent: Any, saved: dict[str, Any], ctx: TrainContext) -> None:
        load_agent(agent, saved, ctx.resume.path)  # type: ignore[union-attr]
        agent.fuse_adam()
        offpolicy.load_memory(agent.memory, ctx.resume.path)  # type: ignore[union-attr]
        if "learning_rate" in ctx.changed:  # the optimizers came back with the old one
            agent.set_learning_rate(ctx.cfg.learning_rate)  # type: ignore[attr-defined]

    def networks(self, agent: Any) -> tuple[nn.Module, ...]:
        return agent.policy, agent.critic_1, agent.critic_2

    def describe(self, cfg: Any) -> dict[str, Any]:
        return {**super().describe(cfg), "action_bound": cfg.action_bound}

    def save_beside(self, agent: Any, checkpoint: Path) -> None:
        offpolicy.save_memory(agent.memory, offpolicy.memory_path(checkpoint))

    def actor(self, checkpoint: Path, saved: dict[str, Any], env: Any) -> nn.Module:
        meta = saved[META]
        bound = meta.get("action_bound")
        if isinstance(bound, bool) or not isinstance(bound, (int, float)) or not bound > 0:
            raise LabError(f"checkpoint {checkpoint.name} is not a {self.spec.name} checkpoint "
                           "(it has no action bound)",
                           "play it with the framework it was trained with")
        hidden = check_mlp(checkpoint, meta["observation_size"], meta["hidden_sizes"],
                           self.actor_class.outputs * meta["action_size"])
        actor = self.actor_class(env.single_observation_space, env.single_action_space, "cpu",
                                 hidden, meta["activation"], float(bound))
        _load_policy_weights(actor, saved, checkpoint)
        return actor.deterministic


class SkrlSACFramework(_OffPolicyFramework):
    algorithm = sac
    actor_class = sac.SquashedActor


class SkrlTD3Framework(_OffPolicyFramework):
    algorithm = td3
    actor_class = td3.TanhActor


def _load_policy_weights(actor: nn.Module, saved: dict[str, Any], checkpoint: Path) -> None:
    try:
        actor.load_state_dict(saved["policy"])
    except (KeyError, RuntimeError) as exc:
        raise LabError(f"checkpoint {checkpoint.name} has no policy matching its own "
                       f"description: {first_line(exc)}", "pick another checkpoint") from exc


def _act(agent: SkrlAgent, obs: torch.Tensor) -> torch.Tensor:
    """The policy's mean action, through skrl's own (frozen) observation preprocessor."""
    with torch.no_grad():
        inputs = {"observations": agent._observation_preprocessor(obs)}
        return agent.policy.compute(inputs, role="policy")[0]


def _collect_and_update(agent: SkrlAgent, env: SkrlEnv, obs: torch.Tensor, ctx: TrainContext,
                        iteration: int) -> torch.Tensor:
    """One rollout of `cfg.rollouts` steps; skrl updates inside the last `post_interaction`.
    Returns the next observations."""
    cfg: SkrlPPOConfig | OffPolicyConfig = ctx.cfg  # type: ignore[assignment]
    total = cfg.max_iterations * cfg.rollouts
    with_states = agent.state_space is not None  # PPO's value model on critic observations
    for step in range(cfg.rollouts):
        t = (iteration - 1) * cfg.rollouts + step
        agent.pre_interaction(timestep=t, timesteps=total)
        with torch.no_grad():
            states = env.state() if with_states else None
            actions, _ = agent.act(obs, states, timestep=t, timesteps=total)
            next_obs, rewards, terminated, truncated, info = env.step(actions)
            # Ended envs were reset in the same step, so next_obs holds their new first
            # observation; skrl bootstraps time-outs from `next_observations` (and
            # `next_states`): give it the true last ones.
            done = terminated | truncated
            last_obs = torch.where(done, info["final_obs"], next_obs)
            last_states = (torch.where(done, info["final_critic_obs"], env.state())
                           if with_states else None)
            agent.record_transition(
                observations=obs, states=states, actions=actions, rewards=rewards,
                next_observations=last_obs, next_states=last_states, terminated=terminated,
                truncated=truncated, infos=info, timestep=t, timesteps=total)
        agent.post_interaction(timestep=t, timesteps=total)  # the update needs gradients
        obs = next_obs
    return obs


def _pop_tracking(agent: SkrlAgent) -> dict[str, float]:
    """skrl's own figures (losses, policy std, learning rate), averaged over the iteration."""
    scalars = {tag.replace(" / ", "/"): float(sum(values) / len(values))
               for tag, values in agent.tracking_data.items() if values}
    agent.tracking_data.clear()
    return scalars


def read_checkpoint(path: Path) -> dict[str, Any]:
    """The saved dict, or a LabError for a missing, corrupt or foreign file."""
    saved = read_torch_file(path)  # data only: never runs pickled code
    meta = saved.get(META) if isinstance(saved, dict) else None
    if not isinstance(meta, dict) or not set(meta) >= META_KEYS or "policy" not in saved:
        raise LabError(f"checkpoint {path} is not a lab skrl checkpoint",
                       "pick a model_<iteration>.pt written by lab's skrl plugin")
    steps = meta["steps"]
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 0:
        raise LabError(f"checkpoint {path.name} records {steps!r} env steps, not a count",
                       "the checkpoint is damaged; pick another")
    return saved


def load_agent(agent: SkrlAgent, saved: dict[str, Any], path: Path) -> None:
    """Restore models, optimizer (with its learning rate) and preprocessors."""
    for name, module in agent.checkpoint_modules.items():
        if name not in saved:
            raise LabError(f"checkpoint {path.name} has no '{name}' state",
                           "resume with the settings it was trained with (e.g. normalize_obs)")
        try:
            module.load_state_dict(saved[name])
        except (RuntimeError, ValueError, KeyError) as exc:
            raise LabError(f"checkpoint {path.name}: '{name}' does not fit this agent: "
                           f"{first_line(exc)}", "resume with the settings it was trained with"
                           ) from exc


def _check_sizes(checkpoint: Path, meta: dict[str, Any], env: Any) -> None:
    for what, saved, current in (
        ("observation", meta["observation_size"], _size(env.single_observation_space)),
        ("action", meta["action_size"], _size(env.single_action_space)),
    ):
        if saved != current:
            raise LabError(f"checkpoint {checkpoint.name} has {what} size {saved}, but the env"
                           f" '{env.task_spec.name}' has {current}",
                           "use a checkpoint trained on this task")


def _size(space: gym.Space) -> int:
    return int(gym.spaces.flatdim(space))
