"""PPO from Stable-Baselines3 behind lab's Framework API."""

from __future__ import annotations

import copy
import os
import pickle
import zipfile
from pathlib import Path
from typing import Any

import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import configure
from stable_baselines3.common.vec_env import VecNormalize
from torch import nn

from lab_sb3.config import Sb3PPOConfig
from lab_sb3.plugin import ADAPTER, VEC_NORMALIZE
from labcli.envs.wrappers import Step
from labcli.errors import LabError
from labcli.plugins.framework import Framework, TrainContext
from labcli.plugins.policy import ObsNormalizer, Policy, one_torch_thread

ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}


class _LabCallback(BaseCallback):
    """Reports each finished PPO iteration to lab and stops on Ctrl-C at the next env step."""

    def __init__(self, ctx: TrainContext, save: Any, normalizer: VecNormalize | None = None):
        super().__init__()
        self.ctx, self.save, self.normalizer = ctx, save, normalizer
        self.iteration = ctx.start_iteration
        self.started = False
        self.boundary_stats: tuple[Any, Any] | None = None

    def _on_training_start(self) -> None:
        # SB3 has just reset the env (on resume, to the saved episodes). Its VecNormalize counted
        # that reset's observations once more: put back the saved statistics and normalize the
        # first observations with them, as the run that never stopped did.
        if self.normalizer is not None and self.ctx.resume is not None:
            saved = _load_normalizer(Sb3Framework.normalizer_path(self.ctx.resume.path))
            self.normalizer.obs_rms, self.normalizer.ret_rms = saved.obs_rms, saved.ret_rms
            self.model._last_obs = self.normalizer.normalize_obs(self.normalizer.old_obs)
        self.ctx.restore_rng()

    def _on_rollout_start(self) -> None:
        # SB3 has no hook after the update; the next rollout's start is one.
        if self.started:
            self.end_iteration()
        self.started = True

    def end_iteration(self) -> None:
        if self.normalizer is not None:
            # VecNormalize updates its statistics at every step: a stop mid-rollout must not
            # save the dropped rollout's observations into the last complete iteration's.
            self.boundary_stats = copy.deepcopy((self.normalizer.obs_rms, self.normalizer.ret_rms))
        self.iteration += 1
        self.ctx.end_iteration(self.iteration, self.model.num_timesteps, self.save)

    def _on_step(self) -> bool:
        return not self.ctx.stop_requested


class Sb3Framework(Framework):
    def pipeline(self, cfg: Sb3PPOConfig) -> list[Step]:
        steps = [Step(ADAPTER)]
        if cfg.normalize_obs or cfg.normalize_reward:
            steps.append(Step(VEC_NORMALIZE, {
                "norm_obs": cfg.normalize_obs, "norm_reward": cfg.normalize_reward,
                "clip_obs": cfg.clip_obs, "gamma": cfg.gamma}))
        return steps

    @staticmethod
    def normalizer_path(checkpoint: Path) -> Path:
        iteration = checkpoint.stem.rsplit("_", 1)[-1]
        return checkpoint.with_name(f"vecnormalize_{iteration}.pkl")

    def train(self, env: Any, ctx: TrainContext) -> None:
        cfg: Sb3PPOConfig = ctx.cfg  # type: ignore[assignment]
        if ctx.resume is not None:
            model = PPO.load(ctx.resume.path, env=env, device=ctx.device)
        else:
            model = PPO(
                "MlpPolicy", env, n_steps=cfg.n_steps, batch_size=cfg.batch_size,
                n_epochs=cfg.n_epochs, learning_rate=cfg.learning_rate, gamma=cfg.gamma,
                gae_lambda=cfg.gae_lambda, clip_range=cfg.clip_range, ent_coef=cfg.ent_coef,
                vf_coef=cfg.vf_coef, max_grad_norm=cfg.max_grad_norm, target_kl=cfg.target_kl,
                policy_kwargs={"net_arch": list(cfg.net_arch),
                               "activation_fn": ACTIVATIONS[cfg.activation],
                               "log_std_init": cfg.log_std_init},
                seed=ctx.seed, device=ctx.device, verbose=0)
        model.set_logger(configure(str(ctx.run_dir), ["tensorboard"]))

        def save(path: Path) -> None:
            # After a stop mid-rollout SB3 has counted the dropped rollout's steps; the
            # checkpoint is that of the last complete iteration, whose steps lab counted.
            model.num_timesteps = ctx.steps
            if isinstance(env, VecNormalize):
                target = self.normalizer_path(path)
                tmp = target.with_name(f".tmp_{target.name}")
                live = env.obs_rms, env.ret_rms
                if callback.boundary_stats is not None:
                    env.obs_rms, env.ret_rms = callback.boundary_stats
                try:
                    env.save(tmp)
                finally:
                    env.obs_rms, env.ret_rms = live
                os.replace(tmp, target)
            model.save(path)

        callback = _LabCallback(ctx, save, env if isinstance(env, VecNormalize) else None)
        ctx.watch(model.policy)
        remaining = cfg.max_iterations - ctx.start_iteration
        with one_torch_thread(ctx.device):
            model.learn(total_timesteps=remaining * cfg.n_steps * env.num_envs,
                        callback=callback, reset_num_timesteps=ctx.resume is None,
                        progress_bar=False)
        if not ctx.stop_requested:
            callback.end_iteration()  # the last update has no next rollout start
        ctx.save(save)

    def load_policy(self, checkpoint: Path, env: Any) -> Policy:
        try:
            model = PPO.load(checkpoint, device="cpu")
        except (zipfile.BadZipFile, ValueError, KeyError, EOFError, RuntimeError) as exc:
            raise LabError(f"checkpoint {checkpoint} is not a loadable SB3 model: {exc}",
                           "pick another checkpoint with --checkpoint") from exc
        _check_spaces(checkpoint, model, env)
        policy = model.policy
        actor = nn.Sequential(policy.mlp_extractor.policy_net, policy.action_net)
        normalizer = None
        pkl = self.normalizer_path(checkpoint)
        if pkl.is_file():
            vn = _load_normalizer(pkl)
            if vn.norm_obs:
                normalizer = ObsNormalizer(torch.as_tensor(vn.obs_rms.mean),
                                           torch.as_tensor(vn.obs_rms.var), vn.epsilon, vn.clip_obs)
        return Policy(actor, normalizer).eval()


def _load_normalizer(path: Path) -> VecNormalize:
    try:
        with path.open("rb") as f:
            return pickle.load(f)
    except (OSError, pickle.UnpicklingError, EOFError) as exc:
        raise LabError(f"normalizer {path} cannot be read: {exc}",
                       "the checkpoint is incomplete; pick another") from exc


def _check_spaces(checkpoint: Path, model: PPO, env: Any) -> None:
    for what, saved, current in (
        ("observation", model.observation_space.shape, env.single_observation_space.shape),
        ("action", model.action_space.shape, env.single_action_space.shape),
    ):
        if saved != current:
            raise LabError(f"checkpoint {checkpoint.name} has {what} size {saved[0]}, but the env"
                           f" '{env.task_spec.name}' has {current[0]}",
                           "use a checkpoint trained on this task")
