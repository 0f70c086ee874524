"""PPO from rl_games (its `a2c_continuous` agent) behind lab's Framework API.

rl_games owns its training loop (`A2CAgent.train()`); lab subclasses the agent only where it
must: `write_stats`, after each iteration, reports to lab, and `update_epoch`, before the next,
ends the loop once lab says so. A checkpoint is rl_games' own full state
(`get_full_state_weights()`: the model with its running mean/std, the optimizer, epoch and frame
counts), which rl_games users can `agent.restore()`. lab reads it back as data only
(`torch.load(weights_only=True)`), and rebuilds the network from the run's agent config, as
rl_games does from its YAML: the checkpoint holds no description of its network.
"""

from __future__ import annotations

import contextlib
import io
import sys
import tempfile
from pathlib import Path
from typing import Any

import torch
from rl_games.algos_torch import model_builder, torch_ext
from rl_games.algos_torch.a2c_continuous import A2CAgent
from rl_games.common import tr_helpers
from rl_games.common.algo_observer import AlgoObserver
from torch import nn

from lab_rl_games.adapter import RlGamesVecEnv
from lab_rl_games.config import RlGamesPPOConfig
from labcli.errors import LabError, first_line
from labcli.plugins.framework import Framework, StopTraining, TrainContext
from labcli.plugins.policy import (
    ObsNormalizer,
    Policy,
    check_mlp,
    one_torch_thread,
    read_torch_file,
    torch_threads,
)

ALGO, MODEL = "a2c_continuous", "continuous_a2c_logstd"
# rl_games' RunningMeanStd computes (x - mean) / sqrt(var + 1e-5), clamped to ±5.
OBS_EPSILON, OBS_CLIP = 1e-5, 5.0
# What lab needs of rl_games' full state to resume; the model alone to play.
STATE_KEYS = ("model", "optimizer", "epoch", "frame")


def model_params(cfg: RlGamesPPOConfig) -> dict[str, Any]:
    """The `model` and `network` sections of rl_games' params, as its YAML would give them: one
    MLP shared by actor and critic, a state-independent log std."""
    return {
        "model": {"name": MODEL},
        "network": {
            "name": "actor_critic", "separate": False,
            "space": {"continuous": {
                "mu_activation": "None", "sigma_activation": "None",
                "mu_init": {"name": "default"},
                "sigma_init": {"name": "const_initializer", "val": cfg.sigma_init},
                "fixed_sigma": True}},
            "mlp": {"units": list(cfg.units), "activation": cfg.activation, "d2rl": False,
                    "initializer": {"name": "default"}},
        },
    }


def agent_params(cfg: RlGamesPPOConfig, env: RlGamesVecEnv, device: str,
                 train_dir: str) -> dict[str, Any]:
    """rl_games' params for an `A2CAgent` on `env`."""
    return {
        "algo": {"name": ALGO},
        **model_params(cfg),
        "config": {
            "name": "lab", "env_name": "lab", "env_info": env.get_env_info(), "vec_env": env,
            "num_actors": env.num_envs, "device": device, "ppo": True,
            "horizon_length": cfg.horizon_length, "mini_epochs": cfg.mini_epochs,
            "minibatch_size": cfg.minibatch_size_per_env * env.num_envs,
            "learning_rate": cfg.learning_rate,
            "lr_schedule": "adaptive" if cfg.lr_schedule == "adaptive" else None,
            "kl_threshold": cfg.kl_threshold, "gamma": cfg.gamma, "tau": cfg.tau,
            "e_clip": cfg.e_clip, "entropy_coef": cfg.entropy_coef,
            "critic_coef": cfg.critic_coef, "grad_norm": cfg.grad_norm,
            "truncate_grads": cfg.truncate_grads, "clip_value": cfg.clip_value,
            "bounds_loss_coef": cfg.bounds_loss_coef,
            # The env clips actions to its own space (±its clip_actions): rl_games' clamp to
            # [-1, 1] and rescale to the space's bounds would stretch them.
            "clip_actions": False,
            "normalize_input": cfg.normalize_input, "normalize_value": cfg.normalize_value,
            "normalize_advantage": cfg.normalize_advantage,
            # Time-outs are not failures: bootstrap on infos["time_outs"].
            "value_bootstrap": True,
            "reward_shaper": tr_helpers.DefaultRewardsShaper(scale_value=cfg.reward_scale),
            # lab ends the loop and writes every checkpoint: rl_games' own exits and saves stay
            # off, and its episode meters feed no observer (lab's env counts episodes).
            "max_epochs": -1, "save_frequency": 0, "save_best_after": sys.maxsize,
            "print_stats": False, "train_dir": train_dir,
            "features": {"observer": AlgoObserver()},
        },
    }


class _Scalars:
    """Where rl_games writes its own figures (rewards/iter, episode_lengths/step...): the run's
    TensorBoard writer. rl_games passes some steps as floats (seconds of training)."""

    def __init__(self, writer: Any):
        self.writer = writer

    def add_scalar(self, tag: str, value: Any, step: float) -> None:
        self.writer.add_scalar(tag, value, int(step))


class LabAgent(A2CAgent):
    """rl_games' PPO agent, reporting each iteration to lab's TrainContext."""

    def __init__(self, cfg: RlGamesPPOConfig, env: RlGamesVecEnv, ctx: TrainContext,
                 train_dir: str):
        with contextlib.redirect_stdout(io.StringIO()):  # it prints its settings; lab has a bar
            super().__init__(base_name="lab", params=agent_params(cfg, env, ctx.device,
                                                                  train_dir))
        self.writer.close()  # its own, in the throwaway train_dir
        self.writer = _Scalars(ctx.writer)
        self.ctx = ctx
        self.finished = False

    def train_epoch(self) -> Any:
        # A rollout, then the update on the run's update threads (the rollout on one).
        with torch_threads(self.ctx.device, self.ctx.update_threads):
            return super().train_epoch()

    def play_steps(self) -> dict[str, Any]:
        with one_torch_thread(self.ctx.device):
            return super().play_steps()

    def update_epoch(self) -> int:
        # The loop's first call of an iteration: lab said the last one was the last.
        if self.finished:
            raise StopTraining
        return super().update_epoch()

    def write_stats(self, total_time: float, epoch_num: int, step_time: float,
                    play_time: float, update_time: float, a_losses: list, c_losses: list,
                    entropies: list, kls: list, last_lr: float, lr_mul: float, *_: Any) -> None:
        # The tags rl_games' own write_stats uses, so that its users find them.
        scalars = {
            "losses/a_loss": torch_ext.mean_list(a_losses).item(),
            "losses/c_loss": torch_ext.mean_list(c_losses).item(),
            "losses/entropy": torch_ext.mean_list(entropies).item(),
            "info/kl": torch_ext.mean_list(kls).item(),
            "info/last_lr": last_lr * lr_mul,
            "performance/step_time": step_time,
            "performance/rl_update_time": update_time,
        }
        self.finished = self.ctx.end_iteration(epoch_num, self.frame, self.write_checkpoint,
                                               scalars)

    def write_checkpoint(self, path: Path) -> None:
        state = self.get_full_state_weights()
        # After a stop mid-rollout rl_games has counted the dropped iteration already: the
        # checkpoint is the last complete one's, with lab's counts.
        state["epoch"], state["frame"] = self.ctx.iteration, self.ctx.steps
        # Not rl_games' save: it appends ".pth" (path.with_suffix("") would do), but retries a
        # failed write for half a minute, where a full disk must fail at once.
        torch.save(state, path)

    def resume(self, path: Path) -> None:
        saved = read_checkpoint(path, self.ppo_device)
        try:
            self.set_full_state_weights(saved)  # model (with its statistics), optimizer, counts
        except (RuntimeError, KeyError, ValueError, TypeError) as exc:
            raise LabError(f"checkpoint {path.name} does not fit the agent config: "
                           f"{first_line(exc)}", "resume without changing the network") from exc
        # The adaptive schedule's learning rate lives on in the optimizer.
        self.last_lr = self.optimizer.param_groups[0]["lr"]
        if "learning_rate" in self.ctx.changed:
            self.last_lr = self.ctx.cfg.learning_rate
            self.update_lr(self.last_lr)

    def act(self, obs: torch.Tensor) -> torch.Tensor:
        """The mean action through rl_games' own normalizer, leaving its statistics and the
        modules' training modes as they were."""
        modes = [(module, module.training) for module in self.model.modules()]
        self.model.eval()
        try:
            with torch.no_grad():
                mu, *_ = self.model.a2c_network({"obs": self.model.norm_obs(obs)})
        finally:
            for module, mode in modes:  # parents first: each child gets its own mode last
                module.train(mode)
        return mu


class RlGamesFramework(Framework):
    # The default pipeline, the adapter alone: normalization lives in rl_games' model.

    def train(self, env: RlGamesVecEnv, ctx: TrainContext) -> None:
        cfg: RlGamesPPOConfig = ctx.cfg  # type: ignore[assignment]
        with tempfile.TemporaryDirectory(prefix="lab-rl_games-") as train_dir, \
                one_torch_thread(ctx.device):
            agent = LabAgent(cfg, env, ctx, train_dir)
            if ctx.resume is not None:
                agent.resume(ctx.resume.path)
            ctx.watch(agent.model)
            ctx.set_actor(agent.act)
            ctx.restore_rng()
            with ctx.training(agent.write_checkpoint):
                agent.train()  # ends by StopTraining only: rl_games' max_epochs is off

    def load_policy(self, checkpoint: Path, env: Any, cfg: RlGamesPPOConfig) -> Policy:
        saved = read_checkpoint(checkpoint, "cpu")
        observations = env.single_observation_space.shape[0]
        actions = env.single_action_space.shape[0]
        check_mlp(checkpoint, observations, list(cfg.units), actions)
        model = build_model(cfg, observations, actions)
        try:
            model.load_state_dict(saved["model"])
        except (RuntimeError, KeyError, TypeError) as exc:
            raise LabError(f"checkpoint {checkpoint.name} does not fit the run's agent config "
                           f"and the env '{env.task_spec.name}': {first_line(exc)}",
                           "play a checkpoint with the run it was trained in") from exc
        net = model.a2c_network
        normalizer = None
        if cfg.normalize_input:
            stats = model.running_mean_std
            normalizer = ObsNormalizer(stats.running_mean.float(), stats.running_var.float(),
                                       OBS_EPSILON, OBS_CLIP)
        return Policy(nn.Sequential(net.actor_mlp, net.mu, net.mu_act), normalizer).eval()


def build_model(cfg: RlGamesPPOConfig, observations: int, actions: int) -> nn.Module:
    """rl_games' actor-critic model for these sizes, as its agent builds it."""
    with contextlib.redirect_stdout(io.StringIO()):  # its normalizer prints its size
        return model_builder.ModelBuilder().load(model_params(cfg)).build({
            "actions_num": actions, "input_shape": (observations,), "num_seqs": 1,
            "value_size": 1, "normalize_value": cfg.normalize_value,
            "normalize_input": cfg.normalize_input})


def read_checkpoint(path: Path, device: str) -> dict[str, Any]:
    """rl_games' full state, read as data; a LabError for a file that is not one."""
    saved = read_torch_file(path, device)  # data only: never runs pickled code
    missing = [key for key in STATE_KEYS if key not in saved] if isinstance(saved, dict) \
        else list(STATE_KEYS)
    if missing or not isinstance(saved["model"], dict):
        raise LabError(f"checkpoint {path} is not an rl_games checkpoint: it lacks "
                       f"{', '.join(missing) or 'a model state'}",
                       "pick another checkpoint with --checkpoint")
    return saved
