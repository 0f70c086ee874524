"""The framework: lab's Framework API over the library. `train` runs the library's own loop;
`load_policy` turns one of its checkpoints into the Policy that `lab play` and `lab export` use."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lab_example_ppo.config import ExamplePPOConfig
from lab_example_ppo.ppo import CLIP, EPS, PPO, ActorCritic
from labcli.plugins.framework import Framework, StopTraining, TrainContext
from labcli.plugins.policy import ObsNormalizer, Policy, one_torch_thread, read_torch_file


class ExamplePPO(Framework):
    def train(self, env: Any, ctx: TrainContext) -> None:
        cfg: ExamplePPOConfig = ctx.cfg
        with one_torch_thread(ctx.device):  # policy-sized networks run fastest on one thread
            ppo = PPO(env, cfg.hidden, cfg.learning_rate, cfg.steps_per_env, cfg.epochs,
                      cfg.minibatches, cfg.gamma, cfg.lam, cfg.clip, cfg.normalize_obs,
                      ctx.device)
            if ctx.resume is not None:
                ppo.load(ctx.resume.path)  # weights, optimizer, normalizer, counters
                if "learning_rate" in ctx.changed:  # the optimizer came back with the old one
                    for group in ppo.optimizer.param_groups:
                        group["lr"] = cfg.learning_rate
            ctx.watch(ppo.model)  # checked for NaN after each update
            ctx.set_actor(lambda obs: ppo.act(obs, deterministic=True))
            ctx.restore_rng()  # building the model drew random numbers: a resume draws on

            def save(path: Path) -> None:
                ppo.save(path.with_suffix(""))  # the library appends ".pt" itself

            def report(iteration: int, figures: dict[str, float]) -> None:
                if ctx.end_iteration(iteration, ppo.steps_done, save, figures):
                    raise StopTraining  # out of the library's loop, into ctx.training

            with ctx.training(save):  # a stop, or the last iteration: checkpointed once
                ppo.learn(cfg.max_iterations, report)

    def load_policy(self, checkpoint: Path, env: Any, cfg: ExamplePPOConfig) -> Policy:
        # Data only: a checkpoint may come from anywhere. What does not fit (a damaged file,
        # another task's sizes) raises, and lab reports it in one line naming the checkpoint.
        state = read_torch_file(checkpoint)
        model = ActorCritic(env.single_observation_space.shape[0],
                            env.single_action_space.shape[0], cfg.hidden)
        model.load_state_dict(state["model"])
        normalizer = None
        if cfg.normalize_obs:
            norm = state["norm"]  # the library's RunningNorm: ObsNormalizer's own formula
            normalizer = ObsNormalizer(norm["mean"], norm["var"], EPS, CLIP)
        return Policy(model.actor, normalizer).eval()
