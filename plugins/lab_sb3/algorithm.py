"""What lab changes in every SB3 learner it runs (PPO, SAC, TD3), mixed in before SB3's class."""

from __future__ import annotations

from typing import Any

import numpy as np

from labcli.plugins.policy import torch_threads


class LabAlgorithm:
    """Reads only the ended envs' infos for SB3's episode buffers (SB3 reads every env's every
    step; lab's adapter puts figures in the ended envs' infos only), updates on
    `update_threads` torch threads on the CPU, and saves a zip that plain SB3 loads."""

    update_threads = 1  # the run's TrainContext.update_threads, set by lab's framework

    def train(self, *args: Any, **kwargs: Any) -> None:
        with torch_threads(str(self.device), self.update_threads):  # type: ignore[attr-defined]
            super().train(*args, **kwargs)  # type: ignore[misc]

    def _update_info_buffer(self, infos: list[dict[str, Any]],
                            dones: np.ndarray | None = None) -> None:
        if dones is None:
            super()._update_info_buffer(infos, dones)  # type: ignore[misc]
            return
        ended = np.flatnonzero(dones)
        super()._update_info_buffer(  # type: ignore[misc]
            [infos[i] for i in ended], np.ones(len(ended), dtype=bool))

    def _excluded_save_params(self) -> list[str]:
        # A buffer's class is a choice of this process, not the model's: a zip without it
        # loads with plain SB3, and without lab installed. The last observations are the env's,
        # which a resumed run restores itself (SB3 resets its env when they are missing): SB3
        # pickles and prints them into the zip's JSON, 40 of a save's 50 ms at 4,096 envs.
        return [*super()._excluded_save_params(),  # type: ignore[misc]
                "rollout_buffer_class", "rollout_buffer_kwargs", "replay_buffer_class",
                "replay_buffer_kwargs", "update_threads", "_last_obs", "_last_episode_starts",
                "_last_original_obs"]
