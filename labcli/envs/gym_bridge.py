"""`--task gym:<id>`: any registered gymnasium env, vectorized by gymnasium and seen by lab's
frameworks and commands through the same interface as LabVecEnv (torch tensors at the edge)."""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
import torch
from gymnasium.envs.registration import load_env_creator
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from labcli.envs import metrics
from labcli.envs.config import GymConfig
from labcli.envs.env import Reduce
from labcli.envs.gym_spec import BACKEND, GymTaskSpec
from labcli.envs.render.scene import render_error, unavailable
from labcli.errors import LabError, first_line

TERMINATED = "terminated"
RENDER_MODE = "rgb_array"


class GymVecEnv(gym.vector.VectorEnv):
    """gymnasium's own vector env (same-step autoreset) behind LabVecEnv's interface: torch
    tensors on `device`, actions in [-1, 1] scaled to the action space's bounds, episode
    statistics under lab's TensorBoard tags, `info["final_obs"]` of ended episodes."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP}
    render_mode = RENDER_MODE

    def __init__(self, spec: GymTaskSpec, cfg: GymConfig, *, device: str = "cpu", seed: int = 0):
        self.task_spec, self.cfg = spec, cfg
        self.backend = BACKEND
        self.device = torch.device(device)
        self.num_envs = cfg.num_envs
        self._vec = self._make_vector_env(spec, cfg)
        try:
            self._check_spaces()
        except BaseException:
            self._vec.close()
            raise
        space = self._vec.single_action_space
        self._low = torch.as_tensor(space.low, dtype=torch.float32, device=self.device)
        self._span = torch.as_tensor(space.high - space.low, dtype=torch.float32,
                                     device=self.device)
        n_obs = math.prod(self._vec.single_observation_space.shape)
        n_act = space.shape[0]
        self.observation_names = [f"obs_{i}" for i in range(n_obs)]
        self.action_names = [f"action_{i}" for i in range(n_act)]
        self.critic_observation_size = 0  # a gymnasium env has no critic observations
        self.single_observation_space = gym.spaces.Box(-np.inf, np.inf, (n_obs,), np.float32)
        self.clip_actions = 1.0  # the policy's [-1, 1] spans the gymnasium env's bounds
        self.single_action_space = gym.spaces.Box(-1.0, 1.0, (n_act,), np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.reward_names: list[str] = []
        self.termination_names = [TERMINATED]
        self.max_episode_length = (cfg.max_episode_steps or gym.spec(spec.gym_id).max_episode_steps
                                   or 2**31 - 1)
        self.step_dt = self._step_dt()
        self._seed: int | None = seed
        n = self.num_envs
        self.episode_length = torch.zeros(n, dtype=torch.long, device=self.device)
        self.episode_return = torch.zeros(n, dtype=torch.float64, device=self.device)
        self._stats = self._zero_stats()

    # construction ----------------------------------------------------------------------------
    @staticmethod
    def _make_vector_env(spec: GymTaskSpec, cfg: GymConfig) -> gym.vector.VectorEnv:
        entry = gym.spec(spec.gym_id).entry_point
        creator = load_env_creator(entry) if isinstance(entry, str) else entry
        renders = RENDER_MODE in getattr(creator, "metadata", {}).get("render_modes", ())
        sync = cfg.vectorization == "sync"

        def make(index: int):
            # Only env 0 renders (for videos); the renderer makes its GL context on first use.
            mode = RENDER_MODE if renders and sync and index == 0 else None
            return lambda: gym.make(spec.gym_id, max_episode_steps=cfg.max_episode_steps,
                                    render_mode=mode, **cfg.kwargs)

        fns = [make(i) for i in range(cfg.num_envs)]
        vector = gym.vector.SyncVectorEnv if sync else gym.vector.AsyncVectorEnv
        try:
            return vector(fns, autoreset_mode=AutoresetMode.SAME_STEP)
        # A keyword the env does not take, a model file it cannot read (not MJCF, missing).
        except (TypeError, ValueError, OSError, gym.error.Error) as exc:
            raise LabError(f"gymnasium could not make '{spec.gym_id}': {first_line(exc)}",
                           "check --set env.kwargs.* against the env's constructor") from None

    def _check_spaces(self) -> None:
        gym_id = self.task_spec.gym_id
        act, obs = self._vec.single_action_space, self._vec.single_observation_space
        if not isinstance(act, gym.spaces.Box) or len(act.shape) != 1 or \
                not (np.isfinite(act.low).all() and np.isfinite(act.high).all()):
            raise LabError(f"'{gym_id}' has action space {act}; lab's policies act in a bounded "
                           "1-D Box", "pick an env with continuous, bounded actions")
        if not isinstance(obs, gym.spaces.Box):
            raise LabError(f"'{gym_id}' has observation space {obs}; lab's policies read a Box",
                           "pick an env with Box observations")

    def _step_dt(self) -> float:
        """Seconds per env step: MuJoCo envs' `dt`, else the render rate, for video fps."""
        try:
            return float(self._vec.get_attr("dt")[0])
        except AttributeError:
            return 1.0 / self._vec.metadata.get("render_fps", 30)

    @staticmethod
    def _zero_stats() -> dict[str, float]:
        return {"episodes": 0.0, "return": 0.0, "length": 0.0, "success": 0.0, TERMINATED: 0.0,
                "nonfinite": 0.0}

    # gymnasium API ---------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        # The first reset uses the construction seed, as LabVecEnv's generator does.
        seed, self._seed = (self._seed if seed is None else seed), None
        mask = (options or {}).get("reset_mask")
        if mask is not None:
            mask = torch.as_tensor(mask, dtype=torch.bool).cpu().numpy()
            options = {**options, "reset_mask": mask}
        else:
            self._stats = self._zero_stats()
        obs, _ = self._vec.reset(seed=seed, options=options)
        self._last_obs = self._obs(obs)
        ended = torch.ones(self.num_envs, dtype=torch.bool, device=self.device) if mask is None \
            else torch.as_tensor(mask, device=self.device)
        self.episode_length.masked_fill_(ended, 0)
        self.episode_return.masked_fill_(ended, 0.0)
        return self._last_obs, {}

    def observations(self) -> torch.Tensor:
        """The current observations: what the last step or reset returned."""
        return self._last_obs

    def step(self, actions: torch.Tensor):
        actions = torch.as_tensor(actions, dtype=torch.float32, device=self.device)
        # Counted, as LabVecEnv does: a policy acting with NaN stops training (see training.py).
        self._stats["nonfinite"] += float((~torch.isfinite(actions)).any(dim=1).sum())
        scaled = self._low + (actions.nan_to_num(0.0).clamp(-1.0, 1.0) + 1.0) * 0.5 * self._span
        obs, reward, terminated, truncated, info = self._vec.step(scaled.cpu().numpy())
        done = terminated | truncated
        final = obs.reshape(self.num_envs, -1).copy()
        if done.any():
            ended = np.flatnonzero(info["_final_obs"])
            final[ended] = np.stack([np.ravel(info["final_obs"][i]) for i in ended])
        reward_t = self._tensor(reward)
        self.episode_length += 1
        self.episode_return += reward_t.double()
        done_t = self._tensor(done, torch.bool)
        terminated_t = self._tensor(terminated, torch.bool)
        # As in LabVecEnv: a time-out is an episode that ended without terminating.
        truncated_t = done_t & ~terminated_t
        threshold = self.task_spec.reward_threshold
        success = done_t & (self.episode_return >= threshold) if threshold is not None \
            else torch.zeros_like(done_t)
        episode = {"r": self.episode_return.float(), "l": self.episode_length.clone(),
                   "success": success}
        self._accumulate(done, episode, terminated)
        self.episode_length.masked_fill_(done_t, 0)
        self.episode_return.masked_fill_(done_t, 0.0)
        info = {"final_obs": self._obs(final), "_final_obs": done_t, "lab_episode": episode,
                "_lab_episode": done_t, "terminations": terminated_t[:, None]}
        self._last_obs = self._obs(obs)
        return self._last_obs, reward_t, terminated_t, truncated_t, info

    def close(self, **kwargs: Any) -> None:
        self._vec.close()

    # statistics ------------------------------------------------------------------------------
    def _accumulate(self, done: np.ndarray, episode: dict[str, torch.Tensor],
                    terminated: np.ndarray) -> None:
        if not done.any():
            return
        mask = torch.as_tensor(done, device=self.device)
        stats = self._stats
        stats["episodes"] += float(done.sum())
        stats["return"] += float(episode["r"][mask].sum())
        stats["length"] += float(episode["l"][mask].sum())
        stats["success"] += float(episode["success"][mask].sum())
        stats[TERMINATED] += float((terminated & done).sum())

    def pop_stats(self, reduce: Reduce | None = None) -> dict[str, float]:
        """Means over the episodes that ended since the last call, as LabVecEnv's; the success
        rate only where the id has a reward threshold."""
        stats, self._stats = self._stats, self._zero_stats()
        if reduce is not None:
            totals = reduce(torch.tensor(list(stats.values()), dtype=torch.float64))
            stats = dict(zip(stats, totals.tolist(), strict=True))
        count = stats["episodes"]
        out = {metrics.NONFINITE_ACTIONS: stats["nonfinite"]} if stats["nonfinite"] else {}
        if count == 0:
            return out
        out |= {metrics.EPISODES: count, metrics.MEAN_RETURN: stats["return"] / count,
               metrics.MEAN_LENGTH: stats["length"] / count,
               metrics.TERMINATION + TERMINATED: stats[TERMINATED] / count}
        if self.task_spec.reward_threshold is not None:
            out[metrics.SUCCESS_RATE] = stats["success"] / count
        return out

    # looking at env 0 ------------------------------------------------------------------------
    def render(self) -> np.ndarray:
        """Env 0 as an RGB image, rendered by the env itself (sync vectorization only)."""
        if not isinstance(self._vec, gym.vector.SyncVectorEnv) or \
                self._vec.envs[0].render_mode != RENDER_MODE:
            raise LabError(f"'{self.task_spec.gym_id}' cannot render images here",
                           "videos need --set env.vectorization=sync and an env with "
                           "render mode rgb_array")
        unavailable()
        try:
            # The env itself, not its wrappers: their order check would refuse a first image
            # before the first reset, which training takes to check rendering before it starts.
            return self._vec.envs[0].unwrapped.render()
        except Exception as exc:  # MuJoCo's GL errors are FatalError, others vary
            raise render_error(exc) from exc

    def markers(self) -> list:
        """A Gymnasium env draws what it shows itself."""
        return []

    def mj_scene(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        """Env 0's MuJoCo model and live data, for MuJoCo's viewer."""
        inner = self._vec.envs[0].unwrapped if isinstance(self._vec, gym.vector.SyncVectorEnv) \
            else None
        model, data = getattr(inner, "model", None), getattr(inner, "data", None)
        if not isinstance(model, mujoco.MjModel) or not isinstance(data, mujoco.MjData):
            raise LabError(f"'{self.task_spec.gym_id}' is not a MuJoCo env lab can show in "
                           "MuJoCo's viewer", "use --video instead")
        return model, data

    def get_state(self) -> None:
        """Gymnasium envs have no general way to save a state: a resumed run starts new
        episodes (the random generators are still restored)."""
        return None

    def describe(self) -> dict[str, Any]:
        """As LabVecEnv.describe: a policy action a in [-1, 1] is the gymnasium env's action
        low + (a + 1) / 2 * (high - low); observations are the env's, flattened."""
        space = self._vec.single_action_space
        actions = [{"action": name, "actuator": f"{self.task_spec.gym_id} action[{i}]",
                    "command": f"{lo:g} + (action + 1) / 2 * {hi - lo:g}", "unit": ""}
                   for i, (name, lo, hi) in enumerate(zip(self.action_names,
                                                          space.low.tolist(),
                                                          space.high.tolist(), strict=True))]
        return {"observations": [{"name": name, "unit": ""} for name in self.observation_names],
                "actions": actions, "action_range": [-1.0, 1.0], "control_dt": self.step_dt}

    def _tensor(self, array: np.ndarray, dtype: torch.dtype = torch.float32) -> torch.Tensor:
        return torch.as_tensor(array, dtype=dtype, device=self.device)

    def _obs(self, array: np.ndarray) -> torch.Tensor:
        """Observations of any Box shape, flattened to `[num_envs, n]` float32."""
        return self._tensor(np.asarray(array).reshape(self.num_envs, -1))
