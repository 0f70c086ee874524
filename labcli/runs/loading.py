"""A checkpoint loaded as a Policy for playing, exporting or resuming, checked before any of them
uses it: a framework's loader that fails on a damaged file (an unknown activation, a missing key, a
string where a number belongs) is one line naming the checkpoint, and so is a policy that does
not fit the env's sizes or whose weights are not finite."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from labcli.errors import LabError, first_line
from labcli.plugins.framework import Checkpoint, Framework
from labcli.plugins.policy import Policy

# What a framework's loader raises on data it does not expect; anything else is a bug in it.
DAMAGED = (TypeError, ValueError, KeyError, IndexError, AttributeError, RuntimeError,
           OverflowError, MemoryError)


def load(fw: Framework, path: Path, env: Any, cfg: Any) -> Policy:
    """The framework's Policy of the checkpoint at `path`, clipped as `env` clips actions: the
    bound is the task's, not the library's."""
    policy = fw.load_policy(path, env, cfg)
    policy.clip = env.clip_actions
    return policy


def policy_of(fw: Framework, checkpoint: Checkpoint, env: Any, cfg: Any) -> Policy:
    path = checkpoint.path
    try:
        policy = load(fw, path, env, cfg)
    except DAMAGED as exc:
        raise LabError(f"checkpoint {path} is not a loadable {fw.name} checkpoint: "
                       f"{type(exc).__name__}: {first_line(exc)}", "pick another checkpoint"
                       ) from None
    observations, actions = (env.single_observation_space.shape[0],
                             env.single_action_space.shape[0])
    try:
        with torch.no_grad():
            out = policy(torch.zeros(2, observations))
    except DAMAGED as exc:
        raise LabError(f"checkpoint {path} does not fit {observations} observations: "
                       f"{type(exc).__name__}: {first_line(exc)}",
                       "the checkpoint is damaged, or of another task; pick another") from None
    if tuple(out.shape) != (2, actions):
        raise LabError(f"checkpoint {path} gives {tuple(out.shape)[1:]} actions, not {actions}",
                       "the checkpoint is damaged, or of another task; pick another")
    if not all(bool(torch.isfinite(t).all()) for t in policy.state_dict().values()
               if t.is_floating_point()):
        raise LabError(f"checkpoint {path} holds non-finite weights (NaN or inf): it cannot be "
                       "played, exported or resumed",
                       "pick an earlier checkpoint of the run (--checkpoint <run dir>/model_N...)")
    return policy
