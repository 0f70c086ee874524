"""SB3's SAC and TD3 as lab runs them: transitions that enter the replay buffer at the end of each
iteration's rollout, and the replay buffer saved beside the newest checkpoint as plain arrays,
so that a resumed run continues as if it had never stopped. The updates are SB3's."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3 import SAC, TD3
from stable_baselines3.common.buffers import ReplayBuffer

from lab_sb3.algorithm import LabAlgorithm
from labcli import files
from labcli.errors import LabError, first_line
from labcli.plugins.policy import CHECKPOINT_LIMIT

# SB3's ReplayBuffer arrays, [buffer_size // n_envs, n_envs, ...] each
FIELDS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")


class StagedReplayBuffer(ReplayBuffer):
    """SB3's replay buffer, whose transitions wait for the end of the rollout (`commit`). SB3
    adds each at its env step, but updates only after the rollout: the buffer it samples is the
    same. A stop mid-rollout, which drops that rollout, then leaves the buffer as the last
    complete iteration left it: what lab checkpoints and resumes from."""

    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.staged: list[tuple[Any, ...]] = []

    def add(self, obs: np.ndarray, next_obs: np.ndarray, action: np.ndarray, reward: np.ndarray,
            done: np.ndarray, infos: list[dict[str, Any]]) -> None:
        # The adapter's arrays may share the env's tensors, which its next step overwrites.
        self.staged.append((np.array(obs), np.array(next_obs), np.array(action),
                            np.array(reward), np.array(done), infos))

    def commit(self) -> None:
        for transition in self.staged:
            super().add(*transition)
        self.staged.clear()


class OffPolicy(LabAlgorithm):
    """Mixed into SB3's SAC and TD3 (after lab_sb3.algorithm's changes)."""

    def collect_rollouts(self, env: Any, callback: Any, train_freq: Any,
                         replay_buffer: StagedReplayBuffer, *args: Any, **kwargs: Any) -> Any:
        rollout = super().collect_rollouts(  # type: ignore[misc]
            env, callback, train_freq, replay_buffer, *args, **kwargs)
        replay_buffer.commit()
        return rollout

    def _sample_action(self, learning_starts: int, *args: Any, **kwargs: Any) -> Any:
        if self.num_timesteps < learning_starts:  # type: ignore[attr-defined]
            # SB3 draws warm-up actions with the action space's own generator, which no
            # checkpoint holds; seeded from NumPy's, which lab restores, a resume during the
            # warm-up draws what the unbroken run drew.
            self.action_space.seed(int(np.random.randint(2**31)))  # type: ignore[attr-defined]
        return super()._sample_action(learning_starts, *args, **kwargs)  # type: ignore[misc]

    def train(self, *args: Any, **kwargs: Any) -> None:
        super().train(*args, **kwargs)
        # The iteration's update figures, written once: learn's own writing, at every few
        # episodes' end, is off (log_interval=None).
        self.logger.dump(self.num_timesteps)  # type: ignore[attr-defined]


class LabSAC(OffPolicy, SAC):
    pass


class LabTD3(OffPolicy, TD3):
    pass


# The replay buffer beside the newest checkpoint -------------------------------------------------

def save_memory(buffer: ReplayBuffer, path: Path) -> None:
    """The buffer's filled rows and where it writes next, as NumPy arrays (no pickle)."""
    rows = buffer.buffer_size if buffer.full else buffer.pos
    with open(path, "xb") as file:
        np.savez(file, pos=np.array(buffer.pos), full=np.array(buffer.full),
                 **{name: getattr(buffer, name)[:rows] for name in FIELDS})


def load_memory(buffer: ReplayBuffer, path: Path) -> None:
    """Refill `buffer` from `path`; without it (the last good state of a run that diverged,
    kept without its buffer) it starts empty. A resume with another env count keeps the newest
    transitions that fill whole rows of the new layout; a LabError when they do not fit at all
    (another observation or action size)."""
    if not path.exists() and not path.is_symlink():
        return
    try:
        data = files.read_bytes(path, CHECKPOINT_LIMIT)
        with np.load(io.BytesIO(data), allow_pickle=False) as saved:
            arrays = {name: saved[name] for name in FIELDS}
            pos, full = int(saved["pos"]), bool(saved["full"])
        for name in FIELDS:
            shape, expected = arrays[name].shape[2:], getattr(buffer, name).shape[2:]
            if shape != expected:
                raise ValueError(f"its '{name}' are of size {shape}, this run's {expected}")
    except files.Unreadable as exc:
        raise LabError(f"replay buffer {path} {exc}", "pick another checkpoint") from None
    except (KeyError, ValueError, TypeError, OSError, zipfile.BadZipFile) as exc:
        raise LabError(f"replay buffer {path} does not fit this run: {first_line(exc)}",
                       "resume it on the task it was trained on") from None
    envs, capacity = buffer.n_envs, buffer.buffer_size
    if arrays["rewards"].shape[1:] == (envs,) and len(arrays["rewards"]) <= capacity:
        # The same layout: row for row, so that sampling draws what it would have drawn.
        for name in FIELDS:
            getattr(buffer, name)[:len(arrays[name])] = arrays[name]
        buffer.pos, buffer.full = pos, full
        return
    # Oldest first, one transition after another, then the newest into whole rows.
    rows = min(capacity, arrays["rewards"].size // envs)
    for name in FIELDS:
        saved = arrays[name]
        ordered = np.concatenate([saved[pos:], saved[:pos]]) if full else saved
        flat = ordered.reshape(-1, *saved.shape[2:])
        getattr(buffer, name)[:rows] = flat[len(flat) - rows * envs:].reshape(
            rows, envs, *saved.shape[2:])
    buffer.full = rows == capacity
    buffer.pos = 0 if buffer.full else rows
