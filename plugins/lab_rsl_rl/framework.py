"""PPO from RSL-RL (rsl-rl-lib 5.x) behind lab's Framework API."""

from __future__ import annotations

import contextlib
import io
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from rsl_rl.models import MLPModel
from rsl_rl.runners import OnPolicyRunner
from tensordict import TensorDict
from torch import nn

from lab_rsl_rl.adapter import CRITIC_GROUP, OBS_GROUP, RslRlVecEnv
from lab_rsl_rl.config import RslRlPpoConfig
from labcli.envs.mdp.symmetry import Mirror, mirror_of_env
from labcli.errors import LabError, first_line
from labcli.plugins.framework import Framework, StopTraining, TrainContext
from labcli.plugins.policy import (
    ObsNormalizer,
    Policy,
    check_mlp,
    one_torch_thread,
    read_torch_file,
)

# Checkpoints are RSL-RL's own dict (runner.save); lab adds what load_policy needs to rebuild the
# actor without the run's config under this key of its "infos".
INFO_KEY = "lab"
INFO_KEYS = {"observation_size", "action_size", "actor"}
MODEL, DISTRIBUTION = "MLPModel", "lab_rsl_rl.distribution:GaussianDistribution"  # it writes
# Older runs name RSL-RL's own class, whose actor is the same (only its sampling differs).
DISTRIBUTIONS = {DISTRIBUTION, "GaussianDistribution"}


def runner_config(cfg: RslRlPpoConfig, world_size: int = 1,
                  critic_group: str = OBS_GROUP) -> dict[str, Any]:
    """The OnPolicyRunner config dict (5.x schema: `actor`, `critic`, `algorithm`, `obs_groups`)
    for a run of `world_size` data-parallel ranks whose critic reads `critic_group`."""
    norm = cfg.empirical_normalization
    return {
        "num_steps_per_env": cfg.num_steps_per_env,
        # The runner saves by itself only through its own log writer, which lab does not create
        # (see _LabLogger), so this never bypasses lab's atomic save.
        "save_interval": cfg.save_interval,
        "obs_groups": {"actor": [OBS_GROUP], "critic": [critic_group]},
        # lab's env already replaces non-finite observations; the check costs a sync per step.
        "check_for_nan": False,
        "actor": {
            "class_name": MODEL, "hidden_dims": list(cfg.actor_hidden_dims),
            "activation": cfg.activation, "obs_normalization": norm,
            "distribution_cfg": {"class_name": DISTRIBUTION,
                                 "init_std": cfg.init_noise_std},
        },
        "critic": {
            "class_name": MODEL, "hidden_dims": list(cfg.critic_hidden_dims),
            "activation": cfg.activation, "obs_normalization": norm,
        },
        "algorithm": {
            "class_name": "lab_rsl_rl.ppo:LabPPO", "cuda_graph": cfg.cuda_graph,
            "learning_rate": cfg.learning_rate, "schedule": cfg.schedule,
            "desired_kl": cfg.kl_target(world_size), "num_learning_epochs": cfg.num_learning_epochs,
            "num_mini_batches": cfg.num_mini_batches, "gamma": cfg.gamma, "lam": cfg.lam,
            "clip_param": cfg.clip_param, "entropy_coef": cfg.entropy_coef,
            "value_loss_coef": cfg.value_loss_coef,
            "use_clipped_value_loss": cfg.use_clipped_value_loss,
            "max_grad_norm": cfg.max_grad_norm,
        },
    }


def symmetry_config(cfg: RslRlPpoConfig, env: RslRlVecEnv) -> dict[str, Any] | None:
    """RSL-RL's `symmetry_cfg` for the run: its augmentation function appends the mirror image
    of each observation group and action batch (the task's `symmetry.Mirror`); None when the
    config asks for no symmetry."""
    if not cfg.symmetric:
        return None
    return {"data_augmentation_func": mirror_augmentation(mirror_of_env(env.env)),
            "use_data_augmentation": cfg.symmetry_augmentation,
            "use_mirror_loss": cfg.mirror_loss_coef > 0, "mirror_loss_coeff": cfg.mirror_loss_coef}


Augmented = tuple[TensorDict | None, torch.Tensor | None]


def mirror_augmentation(mirror: Mirror) -> Callable[..., Augmented]:
    """RSL-RL's data augmentation function for `mirror`: each observation group and action
    batch with its mirror image appended."""

    def augment(env: Any, obs: TensorDict | None, actions: torch.Tensor | None) -> Augmented:
        if obs is not None:
            mirrored = TensorDict({k: (mirror.critic_observations if k == CRITIC_GROUP
                                       else mirror.observations)(v) for k, v in obs.items()},
                                  batch_size=obs.batch_size, device=obs.device)
            obs = torch.cat([obs, mirrored], dim=0)
        if actions is not None:
            actions = torch.cat([actions, mirror.actions(actions)], dim=0)
        return obs, actions

    return augment


class _LabLogger:
    """Stands in for RSL-RL's Logger inside the runner. lab's env already counts episodes on the
    device and TrainContext writes TensorBoard, progress and checkpoints, so this forwards the
    losses and ends each iteration through lab. Its `writer` stays None: the runner then neither
    prints, nor dumps git diffs, nor saves checkpoints behind lab's back."""

    writer = None

    def __init__(self, ctx: TrainContext, save: Any, steps_per_iteration: int):
        self.ctx, self.save, self.steps_per_iteration = ctx, save, steps_per_iteration

    def init_logging_writer(self) -> None:
        pass

    def process_env_step(self, *args: Any, **kwargs: Any) -> None:
        pass  # episodes are counted by lab's env

    def log(self, *, it: int, collect_time: float, learn_time: float,
            loss_dict: dict[str, float], learning_rate: float, action_std: torch.Tensor,
            **_: Any) -> None:
        iteration = it + 1  # the runner counts from 0; lab counts iterations done
        # The tags RSL-RL's own logger writes, so its users find them where they expect.
        scalars = {f"Loss/{name}": value for name, value in loss_dict.items()}
        scalars["Loss/learning_rate"] = learning_rate
        scalars["Policy/mean_std"] = action_std.mean().item()
        scalars["Perf/collection_time"] = collect_time
        scalars["Perf/learning_time"] = learn_time
        if self.ctx.end_iteration(iteration, iteration * self.steps_per_iteration, self.save,
                                  scalars):
            raise StopTraining  # out of the runner's loop, into ctx.training

    def save_model(self, path: str, it: int) -> None:
        pass  # no external logging service to upload to


class LabRunner(OnPolicyRunner):
    """OnPolicyRunner reporting to lab's TrainContext; checkpoints keep RSL-RL's format."""

    def __init__(self, env: RslRlVecEnv, cfg: RslRlPpoConfig, ctx: TrainContext):
        self._ranks = ctx.rank, ctx.world_size  # for _configure_multi_gpu, called by __init__
        groups = env.get_observations().keys()
        config = runner_config(cfg, ctx.world_size,
                               CRITIC_GROUP if CRITIC_GROUP in groups else OBS_GROUP)
        config["algorithm"]["symmetry_cfg"] = symmetry_config(cfg, env)
        with contextlib.redirect_stdout(io.StringIO()):  # it prints both models; lab has a bar
            super().__init__(env, config, log_dir=str(ctx.run_dir), device=ctx.device)
        self.ctx = ctx
        self.alg.update_threads = ctx.update_threads
        self.info = {"observation_size": env.get_observations()[OBS_GROUP].shape[1],
                     "action_size": env.num_actions, "actor": self.cfg["actor"]}
        self.logger = _LabLogger(ctx, self.write_checkpoint, cfg.num_steps_per_env * env.num_envs)
        ctx.watch(self.alg.actor, self.alg.critic)
        ctx.set_actor(self.act)

    def _configure_multi_gpu(self) -> None:
        """RSL-RL's own set-up reads torchrun's variables, starts NCCL and insists on
        `cuda:<local rank>`; lab has set up the process group already (gloo on the CPU, NCCL on
        GPUs, each rank on its own device), so this only tells RSL-RL the ranks. Its PPO then
        averages the gradients, its normalizers sum their statistics over the ranks, and `learn`
        starts by broadcasting rank 0's parameters."""
        rank, world_size = self._ranks
        self.gpu_global_rank, self.gpu_world_size = rank, world_size
        self.gpu_local_rank = torch.device(self.device).index or 0
        self.is_distributed = world_size > 1
        self.cfg["multi_gpu"] = ({"global_rank": rank, "local_rank": self.gpu_local_rank,
                                  "world_size": world_size} if self.is_distributed else None)

    def learn(self, num_learning_iterations: int, init_at_random_ep_len: bool = False) -> None:
        # RSL-RL's learn broadcasts rank 0's parameters after printing a line on every rank's
        # stdout, between lab's progress lines: lab broadcasts them itself, without it.
        distributed, self.is_distributed = self.is_distributed, False
        if distributed:
            self.alg.broadcast_parameters()
        try:
            super().learn(num_learning_iterations, init_at_random_ep_len)
        finally:
            self.is_distributed = distributed

    def act(self, obs: torch.Tensor) -> torch.Tensor:
        """The actor's deterministic output, through its own normalizer."""
        with torch.no_grad():
            return self.alg.actor(TensorDict({OBS_GROUP: obs}, batch_size=[obs.shape[0]]))

    def write_checkpoint(self, path: Path) -> None:
        # "iter" is the number of iterations done, so that learn() after load() goes on with
        # the next one.
        self.current_learning_iteration = self.ctx.iteration
        self.save(str(path), infos={INFO_KEY: self.info})

    def resume(self, path: Path) -> None:
        saved = _read_checkpoint(path, self.device)
        try:
            self.alg.load(saved, None, strict=True)  # actor, critic (normalizers too), optimizer
        except (RuntimeError, KeyError, ValueError) as exc:
            raise LabError(f"checkpoint {path.name} does not fit the agent config: "
                           f"{first_line(exc)}", "resume without changing the network") from exc
        self.current_learning_iteration = self.ctx.start_iteration
        if "learning_rate" in self.ctx.changed:  # the optimizer came back with the old one
            self.alg.set_learning_rate(self.ctx.cfg.learning_rate)


class RslRlFramework(Framework):
    # The default pipeline, the adapter alone: normalization lives in RSL-RL's models.

    def train(self, env: RslRlVecEnv, ctx: TrainContext) -> None:
        cfg: RslRlPpoConfig = ctx.cfg  # type: ignore[assignment]
        with one_torch_thread(ctx.device):
            runner = LabRunner(env, cfg, ctx)
            if ctx.resume is not None:
                runner.resume(ctx.resume.path)
            ctx.restore_rng()
            with ctx.training(runner.write_checkpoint):
                runner.learn(cfg.max_iterations - ctx.start_iteration)

    def load_policy(self, checkpoint: Path, env: Any, cfg: Any = None) -> Policy:
        # The checkpoint describes its own networks (see save): `cfg` is not needed.
        saved = _read_checkpoint(checkpoint, "cpu")
        info = saved.get("infos")
        info = info.get(INFO_KEY) if isinstance(info, dict) else None
        if not isinstance(info, dict) or INFO_KEYS - info.keys():
            raise LabError(f"checkpoint {checkpoint.name} was not written by lab's rsl_rl plugin"
                           f" (its infos lack the '{INFO_KEY}' entry)",
                           "pick another checkpoint with --checkpoint")
        obs_size, action_size = info["observation_size"], info["action_size"]
        for what, size, current in (
            ("observation", obs_size, env.single_observation_space.shape[0]),
            ("action", action_size, env.single_action_space.shape[0]),
        ):
            if size != current:
                raise LabError(f"checkpoint {checkpoint.name} has {what} size {size}, but the env"
                               f" '{env.task_spec.name}' has {current}",
                               "use a checkpoint trained on this task")
        kwargs = _actor_kwargs(checkpoint, info["actor"])
        check_mlp(checkpoint, obs_size, kwargs.get("hidden_dims"), action_size)
        dummy = TensorDict({OBS_GROUP: torch.zeros(1, obs_size)}, batch_size=[1])
        model = MLPModel(dummy, {"actor": [OBS_GROUP]}, "actor", action_size, **kwargs)
        try:
            model.load_state_dict(saved["actor_state_dict"])
        except (KeyError, RuntimeError) as exc:
            raise LabError(f"checkpoint {checkpoint.name} holds no actor matching its own config:"
                           f" {first_line(exc)}", "the checkpoint is damaged; pick another"
                           ) from exc
        return Policy(_deterministic_actor(model), _normalizer(model)).eval()


def _actor_kwargs(checkpoint: Path, actor: dict[str, Any]) -> dict[str, Any]:
    """MLPModel's arguments from the saved actor config. RSL-RL resolves class names to any
    importable callable, so only the classes this plugin writes are accepted: loading a
    checkpoint must not run code named in it."""
    if not isinstance(actor, dict):
        raise LabError(f"checkpoint {checkpoint.name} describes its actor as {actor!r}",
                       "the checkpoint is damaged; pick another")
    kwargs = dict(actor)
    distribution = kwargs.get("distribution_cfg") or {}
    if (kwargs.pop("class_name", None) != MODEL
            or distribution.get("class_name", DISTRIBUTION) not in DISTRIBUTIONS):
        raise LabError(f"checkpoint {checkpoint.name} has an actor other than a {MODEL} with a "
                       "GaussianDistribution", "pick a checkpoint written by lab's rsl_rl plugin")
    return kwargs


def _deterministic_actor(model: nn.Module) -> nn.Module:
    """MLP then the distribution's mean: what RSL-RL's own JIT/ONNX export runs."""
    if model.distribution is None:
        return model.mlp
    return nn.Sequential(model.mlp, model.distribution.as_deterministic_output_module())


def _normalizer(model: nn.Module) -> ObsNormalizer | None:
    """RSL-RL's EmpiricalNormalization computes (x - mean) / (std + eps); ObsNormalizer computes
    (x - mean) / sqrt(var + eps), so pass var = (std + eps)² and eps = 0 for the same result."""
    if not model.obs_normalization:
        return None
    norm = model.obs_normalizer
    return ObsNormalizer(norm.mean, (norm.std + norm.eps) ** 2, 0.0, None)


def _read_checkpoint(path: Path, device: str) -> dict[str, Any]:
    saved = read_torch_file(path, device)  # data only: never runs pickled code
    if not isinstance(saved, dict):
        raise LabError(f"checkpoint {path} is not a loadable RSL-RL model: it holds a "
                       f"{type(saved).__name__}", "pick another checkpoint with --checkpoint")
    return saved
