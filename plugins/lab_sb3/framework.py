"""PPO, SAC and TD3 from Stable-Baselines3 behind lab's Framework API.

Checkpoints are SB3's own zip (`model.save`), which SB3 users can `PPO.load` (`SAC.load`,
`TD3.load`). lab never loads them that way: `load` unpickles the zip's `data` entry, and a pickle
can run any code. The model is rebuilt from the run's agent config instead, and only the zip's
tensors are read, with `torch.load(weights_only=True)`. VecNormalize's statistics are saved as
JSON beside the zip, SAC's and TD3's replay buffer as NumPy arrays beside the newest one.
"""

from __future__ import annotations

import contextlib
import copy
import io
import json
import pickle
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import configure
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.save_util import recursive_getattr
from stable_baselines3.common.vec_env import VecNormalize
from torch import nn

from lab_sb3 import offpolicy, plugin
from lab_sb3.config import Sb3Config, Sb3OffPolicyConfig, Sb3PPOConfig, Sb3SACConfig, Sb3TD3Config
from lab_sb3.ppo import DeviceRolloutBuffer, LabPPO
from labcli import files
from labcli.envs.wrappers import Step
from labcli.errors import LabError, first_line
from labcli.plugins.framework import Framework, FrameworkSpec, StopTraining, TrainContext
from labcli.plugins.policy import CHECKPOINT_LIMIT, ObsNormalizer, Policy, one_torch_thread

ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}
# What lab reads from SB3's zip: tensors (torch.load, weights_only) and plain JSON numbers.
POLICY, VARIABLES, DATA = "policy.pth", "pytorch_variables.pth", "data"
COUNTERS = ("num_timesteps", "_n_updates")
MAX_MEMBER_BYTES = 1 << 30  # a member larger than this is not a policy-sized network


class _LabCallback(BaseCallback):
    """Reports each finished iteration (a rollout and its update) to lab. (A stop mid-rollout
    reaches SB3 as StopTraining from the env's step.)"""

    def __init__(self, ctx: TrainContext, save: Any, last_good: Any,
                 normalizer: VecNormalize | None = None):
        super().__init__()
        self.ctx, self.save, self.last_good, self.normalizer = ctx, save, last_good, normalizer
        self.iteration = ctx.start_iteration
        self.started = False
        self.boundary_stats: tuple[Any, Any] | None = None

    def _on_training_start(self) -> None:
        # SB3 has just reset the env (on resume, to the saved episodes). Its VecNormalize counted
        # that reset's observations once more: put back the saved statistics and normalize the
        # first observations with them, as the run that never stopped did.
        if self.normalizer is not None and self.ctx.resume is not None:
            saved = read_normalizer(normalizer_path(self.ctx.resume.path))
            self.normalizer.obs_rms, self.normalizer.ret_rms = saved["obs_rms"], saved["ret_rms"]
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
        if self.ctx.end_iteration(self.iteration, self.model.num_timesteps, self.save,
                                  last_good=self.last_good):
            raise StopTraining  # out of model.learn, into ctx.training

    def _on_step(self) -> bool:
        return True


class Sb3Framework(Framework):
    """SB3's PPO; the off-policy frameworks below change what differs for SAC and TD3 (the
    model, the replay buffer beside the newest checkpoint, the actor played)."""

    algorithm: type[BaseAlgorithm] = PPO  # whose MlpPolicy load_policy rebuilds
    # The spec whose adapter and VecNormalize it trains through (a variant registered under
    # another name keeps them).
    registered: FrameworkSpec = plugin.SPEC

    def pipeline(self, cfg: Sb3Config) -> list[Step]:
        adapter, vec_normalize = self.registered.wrappers
        steps = [Step(adapter)]
        if cfg.normalize_obs or cfg.normalize_reward:
            steps.append(Step(vec_normalize, {
                "norm_obs": cfg.normalize_obs, "norm_reward": cfg.normalize_reward,
                "clip_obs": cfg.clip_obs, "gamma": cfg.gamma}))
        return steps

    def make_model(self, env: Any, ctx: TrainContext) -> BaseAlgorithm:
        cfg: Sb3PPOConfig = ctx.cfg  # type: ignore[assignment]
        on_gpu = torch.device(ctx.device).type == "cuda"
        return LabPPO(
            "MlpPolicy", env, n_steps=cfg.n_steps, batch_size=cfg.batch_size,
            n_epochs=cfg.n_epochs, learning_rate=cfg.learning_rate, gamma=cfg.gamma,
            gae_lambda=cfg.gae_lambda, clip_range=cfg.clip_range, ent_coef=cfg.ent_coef,
            vf_coef=cfg.vf_coef, max_grad_norm=cfg.max_grad_norm, target_kl=cfg.target_kl,
            policy_kwargs=self.policy_kwargs(cfg), seed=ctx.seed, device=ctx.device, verbose=0,
            # On the CPU SB3's own buffer stays: lab's CPU figures were measured with it.
            rollout_buffer_class=DeviceRolloutBuffer if on_gpu else None)

    def policy_kwargs(self, cfg: Any) -> dict[str, Any]:
        return {"net_arch": list(cfg.net_arch), "activation_fn": ACTIVATIONS[cfg.activation],
                "log_std_init": cfg.log_std_init,
                # SB3's Adam (its eps), stepping all parameters in one fused kernel
                "optimizer_kwargs": {"eps": 1e-5, "fused": True}}

    def layers(self, cfg: Any) -> tuple[str, str]:
        """The policy's weights whose sizes tell the observation size (the actor's first
        layer's inputs) and the action size (its first dimension)."""
        first = "mlp_extractor.policy_net.0.weight" if cfg.net_arch else "action_net.weight"
        return first, "log_std"

    def actor(self, policy: Any, env: Any) -> nn.Module:
        """The deterministic actor of a policy, its weights loaded."""
        return nn.Sequential(policy.mlp_extractor.policy_net, policy.action_net)

    def iteration_steps(self, cfg: Any) -> int:
        return cfg.n_steps

    def learn_kwargs(self) -> dict[str, Any]:
        return {}

    def save_beside(self, model: Any, checkpoint: Path) -> None:
        """Files a checkpoint holds besides SB3's zip and VecNormalize's statistics: none for
        PPO."""

    def load_beside(self, model: Any, checkpoint: Path) -> None:
        """Read back what `save_beside` wrote."""

    def train(self, env: Any, ctx: TrainContext) -> None:
        cfg: Sb3Config = ctx.cfg  # type: ignore[assignment]
        model = self.make_model(env, ctx)
        model.update_threads = ctx.update_threads  # type: ignore[attr-defined]
        if ctx.resume is not None:
            restore(model, ctx.resume.path, ctx.device, ctx.env, self.layers(cfg))
            self.load_beside(model, ctx.resume.path)
        model.set_logger(configure(str(ctx.run_dir), ["tensorboard"]))

        def save_model(path: Path) -> None:
            # After a stop mid-rollout SB3 has counted the dropped rollout's steps; the
            # checkpoint is that of the last complete iteration, whose steps lab counted.
            model.num_timesteps = ctx.steps
            # Opened here: given a path, SB3 creates its missing directories, and so re-created
            # a run dir deleted under lab.
            with open(path, "xb") as file:
                model.save(file)
            if isinstance(env, VecNormalize):
                stats = callback.boundary_stats or (env.obs_rms, env.ret_rms)
                normalizer_path(path).write_text(json.dumps(normalizer_json(env, *stats)))

        def save(path: Path) -> None:
            save_model(path)
            self.save_beside(model, path)

        # The last good state kept each iteration: the model without what is saved beside it
        # (a replay buffer, rewritten whole at every save).
        callback = _LabCallback(ctx, save, save_model,
                                env if isinstance(env, VecNormalize) else None)
        ctx.watch(model.policy)
        ctx.set_actor(lambda obs: _act(model, callback, obs))
        remaining = cfg.max_iterations - ctx.start_iteration
        try:
            with one_torch_thread(ctx.device), ctx.training(save):
                model.learn(total_timesteps=remaining * self.iteration_steps(cfg) * env.num_envs,
                            callback=callback, reset_num_timesteps=ctx.resume is None,
                            progress_bar=False, **self.learn_kwargs())
                callback.end_iteration()  # the last update has no next rollout start
        except BaseException:
            # The error in flight says what went wrong (a run dir deleted under lab: one line);
            # the TensorBoard writer re-raises its own copy of it on close, which would replace it.
            with contextlib.suppress(OSError):
                model.logger.close()
            raise
        model.logger.close()  # its TensorBoard writer holds a file of the run dir open

    def load_policy(self, checkpoint: Path, env: Any, cfg: Sb3Config) -> Policy:
        make = self.algorithm.policy_aliases["MlpPolicy"]
        policy = make(env.single_observation_space, env.single_action_space,
                      lambda _: cfg.learning_rate, **self.policy_kwargs(cfg))
        saved = read_checkpoint(checkpoint, "cpu", (POLICY,))
        load_weights(policy, saved[POLICY], checkpoint, env, self.layers(cfg))
        normalizer = None
        if cfg.normalize_obs:
            stats = read_normalizer(normalizer_path(checkpoint))
            normalizer = ObsNormalizer(torch.as_tensor(stats["obs_rms"].mean),
                                       torch.as_tensor(stats["obs_rms"].var), stats["epsilon"],
                                       stats["clip_obs"])
        return Policy(self.actor(policy, env), normalizer).eval()


class _OffPolicyFramework(Sb3Framework):
    """SB3's SAC or TD3 (lab_sb3.offpolicy): the newest checkpoint also saves the replay buffer,
    and the policy played and exported is the actor's deterministic action, tanh-bounded."""

    def make_model(self, env: Any, ctx: TrainContext) -> BaseAlgorithm:
        cfg: Sb3OffPolicyConfig = ctx.cfg  # type: ignore[assignment]
        return self.algorithm(
            "MlpPolicy", env, learning_rate=cfg.learning_rate, buffer_size=cfg.buffer_size,
            learning_starts=cfg.learning_starts, batch_size=cfg.batch_size, tau=cfg.tau,
            gamma=cfg.gamma, train_freq=cfg.train_freq, gradient_steps=cfg.gradient_steps,
            replay_buffer_class=offpolicy.StagedReplayBuffer,
            policy_kwargs=self.policy_kwargs(cfg), seed=ctx.seed, device=ctx.device, verbose=0,
            **self.settings(cfg, env.action_space.shape[-1]))

    def settings(self, cfg: Any, actions: int) -> dict[str, Any]:
        """The algorithm's own settings, from lab's config."""
        raise NotImplementedError

    def policy_kwargs(self, cfg: Any) -> dict[str, Any]:
        return {"net_arch": list(cfg.net_arch), "activation_fn": ACTIVATIONS[cfg.activation],
                # SB3's Adam, stepping all parameters in one fused kernel
                "optimizer_kwargs": {"fused": True}}

    def iteration_steps(self, cfg: Any) -> int:
        return cfg.train_freq

    def learn_kwargs(self) -> dict[str, Any]:
        return {"log_interval": None}  # lab_sb3.offpolicy writes the figures once an update

    def save_beside(self, model: Any, checkpoint: Path) -> None:
        offpolicy.save_memory(model.replay_buffer, memory_path(checkpoint))

    def load_beside(self, model: Any, checkpoint: Path) -> None:
        offpolicy.load_memory(model.replay_buffer, memory_path(checkpoint))


class Sb3SACFramework(_OffPolicyFramework):
    algorithm = offpolicy.LabSAC
    registered = plugin.SAC_SPEC

    def settings(self, cfg: Sb3SACConfig, actions: int) -> dict[str, Any]:
        return {"ent_coef": cfg.ent_coef, "target_entropy": cfg.target_entropy}

    def layers(self, cfg: Any) -> tuple[str, str]:
        return "actor.latent_pi.0.weight" if cfg.net_arch else "actor.mu.weight", "actor.mu.weight"

    def actor(self, policy: Any, env: Any) -> nn.Module:
        # SB3's deterministic SAC action: tanh of the Gaussian's mean, into the bounds.
        actor = policy.actor
        return nn.Sequential(actor.latent_pi, actor.mu, nn.Tanh(),
                             Unscaled(env.single_action_space))


class Sb3TD3Framework(_OffPolicyFramework):
    algorithm = offpolicy.LabTD3
    registered = plugin.TD3_SPEC

    def settings(self, cfg: Sb3TD3Config, actions: int) -> dict[str, Any]:
        noise = None
        if cfg.action_noise_sigma:
            noise = NormalActionNoise(np.zeros(actions), np.full(actions, cfg.action_noise_sigma))
        return {"policy_delay": cfg.policy_delay, "target_policy_noise": cfg.target_policy_noise,
                "target_noise_clip": cfg.target_noise_clip, "action_noise": noise}

    def layers(self, cfg: Any) -> tuple[str, str]:
        return "actor.mu.0.weight", f"actor.mu.{2 * len(cfg.net_arch)}.weight"

    def actor(self, policy: Any, env: Any) -> nn.Module:
        return nn.Sequential(policy.actor.mu, Unscaled(env.single_action_space))  # mu ends in tanh


class Unscaled(nn.Module):
    """SB3's `unscale_action`: an action in [-1, 1] into the action space's bounds."""

    def __init__(self, space: Any):
        super().__init__()
        low, high = (torch.as_tensor(bound, dtype=torch.float32) for bound in (space.low,
                                                                             space.high))
        self.register_buffer("low", low)
        self.register_buffer("span", high - low)

    def forward(self, action: torch.Tensor) -> torch.Tensor:
        return self.low + 0.5 * (action + 1.0) * self.span


def _act(model: BaseAlgorithm, callback: _LabCallback, obs: torch.Tensor) -> np.ndarray:
    """The deterministic action SB3 takes, through VecNormalize's own normalization with the
    statistics a checkpoint saves (the last complete iteration's)."""
    raw = obs.cpu().numpy()
    normalizer = callback.normalizer
    if normalizer is not None and normalizer.norm_obs:
        obs_rms = callback.boundary_stats[0] if callback.boundary_stats else normalizer.obs_rms
        raw = normalizer._normalize_obs(raw, obs_rms)
    actions, _ = model.predict(raw, deterministic=True)
    return actions


def companion(checkpoint: Path, prefix: str, suffix: str) -> Path:
    """<prefix><N><suffix> beside model_<N>.zip."""
    iteration = checkpoint.stem.rsplit("_", 1)[-1]
    return checkpoint.with_name(f"{prefix}{iteration}{suffix}")


def memory_path(checkpoint: Path) -> Path:
    return companion(checkpoint, "memory_", ".npz")


def normalizer_path(checkpoint: Path) -> Path:
    return companion(checkpoint, "vecnormalize_", ".json")


def _not_loadable(checkpoint: Path, why: str) -> LabError:
    return LabError(f"checkpoint {checkpoint} is not a loadable SB3 model: {why}",
                    "pick another checkpoint with --checkpoint")


def read_checkpoint(path: Path, device: str, members: Sequence[str]) -> dict[str, Any]:
    """The zip's tensor `members` (by name: "policy.pth") and counters, read without unpickling
    anything."""
    try:
        with zipfile.ZipFile(io.BytesIO(files.read_bytes(path, CHECKPOINT_LIMIT))) as archive:
            found = {info.filename: info for info in archive.infolist()}
            for name in (*members, DATA):
                if name not in found:
                    raise _not_loadable(path, f"it has no '{name}'")
                if found[name].file_size > MAX_MEMBER_BYTES:
                    raise _not_loadable(path, f"its '{name}' is {found[name].file_size:,} bytes")
            saved = {name: torch.load(io.BytesIO(archive.read(name)), map_location=device,
                                      weights_only=True) for name in members}
            data = json.loads(archive.read(DATA))
    except files.Unreadable as exc:
        raise _not_loadable(path, str(exc)) from None
    except (zipfile.BadZipFile, OSError, EOFError, RuntimeError, ValueError,
            pickle.UnpicklingError) as exc:
        raise _not_loadable(path, f"{type(exc).__name__}: {first_line(exc)}") from exc
    counters = {name: data.get(name) if isinstance(data, dict) else None for name in COUNTERS}
    if not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0
               for v in counters.values()):
        raise _not_loadable(path, f"its data has no counts {', '.join(COUNTERS)}")
    return {**saved, DATA: counters}


def restore(model: BaseAlgorithm, checkpoint: Path, device: str, env: Any,
            layers: tuple[str, str]) -> None:
    """Everything of `model` its zip holds: the policy, the optimizers, the tensors SB3 saves
    apart (SAC's entropy coefficient) and the counters, by the names SB3 saves them under."""
    state_dicts, variables = model._get_torch_save_params()
    members = [f"{name}.pth" for name in state_dicts] + ([VARIABLES] if variables else [])
    saved = read_checkpoint(checkpoint, device, members)
    load_weights(model.policy, saved[POLICY], checkpoint, env, layers)
    for name in state_dicts:
        if name != "policy":
            _load(recursive_getattr(model, name), saved[f"{name}.pth"], checkpoint)
    for name in variables:
        try:
            with torch.no_grad():
                recursive_getattr(model, name).copy_(saved[VARIABLES][name])
        except (KeyError, TypeError, RuntimeError) as exc:
            raise _not_loadable(checkpoint, f"its '{name}' does not fit: {first_line(exc)}"
                                ) from exc
    for name in COUNTERS:
        setattr(model, name, saved[DATA][name])


def load_weights(policy: BasePolicy, weights: Any, checkpoint: Path, env: Any,
                 layers: tuple[str, str]) -> None:
    """The policy's weights, after their sizes are checked against the env's (`layers`: the
    weights that tell the observation and the action size)."""
    if not isinstance(weights, dict) or not all(isinstance(t, torch.Tensor)
                                                for t in weights.values()):
        raise _not_loadable(checkpoint, f"its {POLICY} is not a state dict")
    first, last = (weights.get(name) for name in layers)
    for what, size, current in (
        ("observation", None if first is None else first.shape[-1],
         env.single_observation_space.shape[0]),
        ("action", None if last is None else last.shape[0], env.single_action_space.shape[0]),
    ):
        if size is not None and size != current:
            raise LabError(f"checkpoint {checkpoint.name} has {what} size {size}, but the env"
                           f" '{env.task_spec.name}' has {current}",
                           "use a checkpoint trained on this task")
    _load(policy, weights, checkpoint)


def _load(module: Any, state: Any, checkpoint: Path) -> None:
    try:
        module.load_state_dict(state)
    except (RuntimeError, KeyError, ValueError, TypeError) as exc:
        raise LabError(f"checkpoint {checkpoint.name} does not fit the run's agent config: "
                       f"{first_line(exc)}", "resume or play with the settings it was trained "
                       "with (params/agent.yaml)") from exc


def normalizer_json(env: VecNormalize, obs_rms: RunningMeanStd,
                    ret_rms: RunningMeanStd) -> dict[str, Any]:
    """VecNormalize's settings and statistics as plain numbers (floats round-trip exactly)."""
    def stats(rms: RunningMeanStd) -> dict[str, Any]:
        return {"mean": np.asarray(rms.mean, dtype=np.float64).tolist(),
                "var": np.asarray(rms.var, dtype=np.float64).tolist(), "count": float(rms.count)}

    return {"norm_obs": env.norm_obs, "norm_reward": env.norm_reward, "clip_obs": env.clip_obs,
            "clip_reward": env.clip_reward, "gamma": env.gamma, "epsilon": env.epsilon,
            "obs_rms": stats(obs_rms), "ret_rms": stats(ret_rms)}


def read_normalizer(path: Path) -> dict[str, Any]:
    """The statistics of `normalizer_json`, as RunningMeanStd; a LabError when missing, damaged,
    or an old pickle (which lab never loads: a pickle can run code)."""
    if not path.is_file():
        old = path.with_suffix(".pkl")
        if old.is_file():
            raise LabError(f"normalizer {old.name} is a pickle, which lab does not load (loading "
                           "a pickle can run any code in it)",
                           f"retrain, or resave its statistics as {path.name}")
        raise LabError(f"checkpoint {path.name.replace('vecnormalize', 'model')} was trained with "
                       f"normalize_obs, but its normalizer {path.name} is missing",
                       "pick another checkpoint, or restore the file")
    try:
        data = files.load_json(files.read_bytes(path))
        out = {key: float(data[key]) for key in ("clip_obs", "epsilon")}
        for key in ("obs_rms", "ret_rms"):
            rms = RunningMeanStd(shape=np.shape(data[key]["mean"]))
            rms.mean = np.asarray(data[key]["mean"], dtype=np.float64)
            rms.var = np.asarray(data[key]["var"], dtype=np.float64)
            rms.count = float(data[key]["count"])
            if rms.mean.shape != rms.var.shape or not (np.isfinite(rms.mean).all()
                                                       and (rms.var >= 0).all()):
                raise ValueError(f"{key} has mismatched or non-finite statistics")
            out[key] = rms
    except files.Unreadable as exc:
        raise LabError(f"normalizer {path} {exc}", "the checkpoint is damaged; pick another"
                       ) from None
    except (ValueError, TypeError, KeyError, AttributeError) as exc:
        raise LabError(f"normalizer {path} cannot be read: {type(exc).__name__}: "
                       f"{first_line(exc)}", "the checkpoint is damaged; pick another") from exc
    return out
