"""PPO on a lab task in one file, in the style of CleanRL's ppo_continuous_action.py.

    python examples/cleanrl_ppo.py --task cartpole --num-envs 128 --total-timesteps 1000000
    python examples/cleanrl_ppo.py --set episode_length_s=3 --backend warp --num-envs 4096

lab's env is a gymnasium VectorEnv of torch tensors: observations, rewards and flags come out as
tensors on the env's device and actions go in as tensors, so the loop needs no NumPy. lab resets
an ended env within the step (gymnasium's SAME_STEP autoreset): the observation a step returns
is already the next episode's first, which is what this loop, like CleanRL's, expects. The
episodes' figures are in `info["lab_episode"]`. Time-outs are treated as terminations, as in
CleanRL.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np
import torch
from torch import nn
from torch.distributions import Normal

import labcli.gym  # noqa: F401  (registers "lab/<task>" with gymnasium)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--task", default="cartpole")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--backend", default=None, help="cpu or warp (default: as lab train)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="the task's config, as lab train --set env.KEY=VALUE")
    p.add_argument("--total-timesteps", type=int, default=1_000_000)
    p.add_argument("--learning-rate", type=float, default=1e-3)
    p.add_argument("--num-envs", type=int, default=128)
    p.add_argument("--num-steps", type=int, default=32, help="steps per env per rollout")
    p.add_argument("--gamma", type=float, default=0.99)
    p.add_argument("--gae-lambda", type=float, default=0.95)
    p.add_argument("--num-minibatches", type=int, default=8)
    p.add_argument("--update-epochs", type=int, default=8)
    p.add_argument("--clip-coef", type=float, default=0.2)
    p.add_argument("--ent-coef", type=float, default=0.0)
    p.add_argument("--vf-coef", type=float, default=0.5)
    p.add_argument("--max-grad-norm", type=float, default=1.0)
    args = p.parse_args(argv)
    args.batch_size = args.num_envs * args.num_steps
    args.minibatch_size = args.batch_size // args.num_minibatches
    args.num_iterations = args.total_timesteps // args.batch_size
    return args


def layer_init(layer: nn.Linear, std: float = np.sqrt(2), bias_const: float = 0.0) -> nn.Linear:
    torch.nn.init.orthogonal_(layer.weight, std)
    torch.nn.init.constant_(layer.bias, bias_const)
    return layer


class Agent(nn.Module):
    def __init__(self, envs: gym.vector.VectorEnv):
        super().__init__()
        obs = np.prod(envs.single_observation_space.shape)
        act = np.prod(envs.single_action_space.shape)
        self.critic = nn.Sequential(
            layer_init(nn.Linear(obs, 64)), nn.Tanh(),
            layer_init(nn.Linear(64, 64)), nn.Tanh(),
            layer_init(nn.Linear(64, 1), std=1.0),
        )
        self.actor_mean = nn.Sequential(
            layer_init(nn.Linear(obs, 64)), nn.Tanh(),
            layer_init(nn.Linear(64, 64)), nn.Tanh(),
            layer_init(nn.Linear(64, act), std=0.01),
        )
        self.actor_logstd = nn.Parameter(torch.zeros(1, act))

    def get_value(self, x: torch.Tensor) -> torch.Tensor:
        return self.critic(x)

    def get_action_and_value(self, x: torch.Tensor, action: torch.Tensor | None = None):
        action_mean = self.actor_mean(x)
        action_std = self.actor_logstd.expand_as(action_mean).exp()
        probs = Normal(action_mean, action_std)
        if action is None:
            action = probs.sample()
        return action, probs.log_prob(action).sum(1), probs.entropy().sum(1), self.critic(x)


def main(argv: list[str] | None = None) -> float:
    """Trains, printing one line per iteration; returns the last success rate seen."""
    args = parse_args(argv)
    torch.manual_seed(args.seed)
    envs = gym.make_vec(f"lab/{args.task}", num_envs=args.num_envs, seed=args.seed,
                        backend=args.backend, overrides=args.set)
    device = envs.device
    torch.set_num_threads(1)  # policy-sized networks: more CPU threads only add overhead
    agent = Agent(envs).to(device)
    optimizer = torch.optim.Adam(agent.parameters(), lr=args.learning_rate, eps=1e-5)

    obs = torch.zeros((args.num_steps, args.num_envs, *envs.single_observation_space.shape),
                      device=device)
    actions = torch.zeros((args.num_steps, args.num_envs, *envs.single_action_space.shape),
                          device=device)
    logprobs, rewards, dones, values = (torch.zeros((args.num_steps, args.num_envs),
                                                    device=device) for _ in range(4))

    global_step, start, success = 0, time.time(), float("nan")
    next_obs, _ = envs.reset(seed=args.seed)
    next_done = torch.zeros(args.num_envs, device=device)
    for iteration in range(1, args.num_iterations + 1):
        frac = 1.0 - (iteration - 1.0) / args.num_iterations  # CleanRL's annealed rate
        optimizer.param_groups[0]["lr"] = frac * args.learning_rate
        returns_seen, successes = [], []
        for step in range(args.num_steps):
            global_step += args.num_envs
            obs[step], dones[step] = next_obs, next_done
            with torch.no_grad():
                action, logprob, _, value = agent.get_action_and_value(next_obs)
                values[step] = value.flatten()
            actions[step], logprobs[step] = action, logprob
            next_obs, reward, terminations, truncations, infos = envs.step(action)
            rewards[step] = reward
            next_done = (terminations | truncations).float()
            ended = infos["_lab_episode"]
            returns_seen.append(infos["lab_episode"]["r"][ended])
            successes.append(infos["lab_episode"]["success"][ended])

        with torch.no_grad():  # GAE, as CleanRL computes it
            next_value = agent.get_value(next_obs).reshape(1, -1)
            advantages = torch.zeros_like(rewards)
            lastgaelam = 0
            for t in reversed(range(args.num_steps)):
                nextnonterminal = 1.0 - (next_done if t == args.num_steps - 1 else dones[t + 1])
                nextvalues = next_value if t == args.num_steps - 1 else values[t + 1]
                delta = rewards[t] + args.gamma * nextvalues * nextnonterminal - values[t]
                advantages[t] = lastgaelam = (delta + args.gamma * args.gae_lambda
                                              * nextnonterminal * lastgaelam)
            returns = advantages + values

        b_obs = obs.reshape((-1, *envs.single_observation_space.shape))
        b_logprobs, b_advantages = logprobs.reshape(-1), advantages.reshape(-1)
        b_actions = actions.reshape((-1, *envs.single_action_space.shape))
        b_returns = returns.reshape(-1)
        for _ in range(args.update_epochs):
            for mb in torch.randperm(args.batch_size, device=device).split(args.minibatch_size):
                _, newlogprob, entropy, newvalue = agent.get_action_and_value(b_obs[mb],
                                                                              b_actions[mb])
                ratio = (newlogprob - b_logprobs[mb]).exp()
                mb_advantages = b_advantages[mb]
                mb_advantages = (mb_advantages - mb_advantages.mean()) / (mb_advantages.std()
                                                                         + 1e-8)
                pg_loss = torch.max(-mb_advantages * ratio, -mb_advantages * torch.clamp(
                    ratio, 1 - args.clip_coef, 1 + args.clip_coef)).mean()
                v_loss = 0.5 * ((newvalue.view(-1) - b_returns[mb]) ** 2).mean()
                loss = pg_loss - args.ent_coef * entropy.mean() + v_loss * args.vf_coef
                optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
                optimizer.step()

        ended_returns, ended_successes = torch.cat(returns_seen), torch.cat(successes)
        figures = "no episode ended"
        if len(ended_returns):
            success = ended_successes.float().mean().item()
            figures = (f"episodic_return={ended_returns.mean().item():.1f} "
                       f"success={success:.2f}")
        print(f"iteration {iteration}/{args.num_iterations} global_step={global_step} "
              f"{figures} SPS={int(global_step / (time.time() - start))}", flush=True)
    envs.close()
    return success


if __name__ == "__main__":
    main()
