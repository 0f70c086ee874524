"""The critic's own observations (`env.critic_observations: noise_free`): the policy's terms
without their noise, bias and delay, given beside the policy's at every reset and step, and read
by RSL-RL's critic through its own observation group."""

import io

import pytest
import torch
from conftest import needs_menagerie, needs_warp
from lab_rsl_rl import framework as rsl_rl_framework
from lab_skrl.ppo import LabSkrlPPO
from rich.console import Console

from labcli.gym import make_env
from labcli.runs import training

pytestmark = needs_menagerie("unitree_go1")
NOISE_FREE = "env.critic_observations=noise_free"
# History and latency on one term: the critic sees its three frames, none of them late.
FRAMES = "env.observations.joint_vel.history_length=3"
# No pushes: over a few steps the envs below draw nothing but the policy's noise.
NO_PUSH = "env.events.push_robot=null"


def go1(*overrides: str):
    env = make_env("go1-flat", num_envs=4, seed=0, backend="cpu", device="cpu",
                   overrides=[NO_PUSH, FRAMES, *overrides])
    return env


def test_the_critic_reads_the_policys_terms_without_their_noise_bias_and_delay():
    noisy = go1(NOISE_FREE, "env.observations.joint_vel.delay=[1,2]",
                "env.observations.base_ang_vel.bias=0.3")
    clean = go1("env.observation_noise=false")  # the same terms, frames, clip and scale
    try:
        assert noisy.critic_observation_size == len(noisy.observation_names)
        assert clean.critic_observation_size == 0
        obs, info = noisy.reset(seed=3)
        expected, clean_info = clean.reset(seed=3)
        assert clean_info == {}
        assert torch.equal(info["critic_obs"], expected)
        action = torch.full((4, noisy.single_action_space.shape[0]), 0.3)
        for _ in range(5):
            obs, *_, info = noisy.step(action)
            expected, *_, clean_info = clean.step(action)
            assert "critic_obs" not in clean_info
            torch.testing.assert_close(info["critic_obs"], expected, rtol=0, atol=1e-6)
            assert not torch.allclose(obs, expected, atol=1e-3)  # the policy's are noisy
    finally:
        noisy.close()
        clean.close()


def test_without_noise_free_the_env_gives_no_critic_observations():
    env = go1()
    try:
        assert env.critic_observation_size == 0
        assert env.reset()[1] == {}
        assert "critic_obs" not in env.step(torch.zeros(4, env.single_action_space.shape[0]))[4]
    finally:
        env.close()


@pytest.mark.parametrize("framework, symmetric", [("rsl_rl", False), ("rsl_rl", True)])
def test_rsl_rl_s_critic_reads_the_critic_group_and_its_actor_the_policy_s(
        framework, symmetric, tmp_path, monkeypatch):
    seen = {}
    learn = rsl_rl_framework.LabRunner.learn

    def spied(runner, *args, **kwargs):
        seen["actor"], seen["critic"] = runner.alg.actor.obs_groups, runner.alg.critic.obs_groups
        seen["obs"] = runner.env.get_observations()
        return learn(runner, *args, **kwargs)

    monkeypatch.setattr(rsl_rl_framework.LabRunner, "learn", spied)
    # With symmetry on, each mini-batch's mirror images are of both groups.
    said = io.StringIO()
    outcome = training.train(
        "go1-flat", framework, num_envs=8, max_iterations=2, logs_dir=tmp_path,
        overrides=[NOISE_FREE, "agent.num_steps_per_env=8", "agent.actor_hidden_dims=[16]",
                   "agent.critic_hidden_dims=[16]",
                   f"agent.symmetry_augmentation={str(symmetric).lower()}"],
        console=Console(file=said, width=300))
    assert outcome.summary["iterations"] == 2
    assert (seen["actor"], seen["critic"]) == (["policy"], ["critic"])
    assert seen["obs"]["critic"].shape == seen["obs"]["policy"].shape
    assert "critic input" not in said.getvalue()


def test_skrl_s_value_model_reads_them_as_states_and_bootstraps_time_outs_from_the_last(
        tmp_path, monkeypatch):
    """skrl's PPO takes the critic observations as its states: the value model's input, kept
    in its memory, normalized by its state preprocessor; a time-out's bootstrap reads the
    ended episode's last ones (`info["final_critic_obs"]`), not the next episode's first."""
    recorded = []
    record = LabSkrlPPO.record_transition

    def spied(agent, **kwargs):
        recorded.append({k: kwargs[k] for k in ("states", "next_states", "truncated")}
                        | {"final": kwargs["infos"]["final_critic_obs"],
                           "next": kwargs["infos"]["critic_obs"]})
        return record(agent, **kwargs)

    monkeypatch.setattr(LabSkrlPPO, "record_transition", spied)
    said = io.StringIO()
    # 0.2 s episodes: time-outs every 10 steps.
    outcome = training.train(
        "go1-flat", "skrl", num_envs=8, max_iterations=2, logs_dir=tmp_path,
        overrides=[NOISE_FREE, "env.episode_length_s=0.2", "agent.rollouts=16",
                   "agent.hidden_sizes=[16]", "agent.normalize_obs=true"],
        console=Console(file=said, width=300))
    assert outcome.summary["iterations"] == 2 and "critic input" not in said.getvalue()
    saved = torch.load(outcome.run.dir / "model_2.pt", weights_only=True)
    assert saved["state_preprocessor"]["running_mean"].shape == (48,)
    assert saved["value"]["net.0.weight"].shape[1] == 48
    timed_out = [r for r in recorded if r["truncated"].any()]
    assert timed_out
    for r in recorded:
        ended = r["truncated"].view(-1)
        assert torch.equal(r["next_states"][ended], r["final"][ended])
        assert torch.equal(r["next_states"][~ended], r["next"][~ended])
    assert not torch.equal(timed_out[0]["final"], timed_out[0]["next"])
    # A resume restores the state preprocessor with the rest.
    resumed = training.train(
        "go1-flat", "skrl", max_iterations=3, logs_dir=tmp_path, checkpoint="latest",
        console=Console(file=io.StringIO(), width=300))
    assert resumed.summary["iterations"] == 3


def test_a_framework_without_a_critic_input_says_its_critic_reads_the_policy_s(tmp_path):
    said = io.StringIO()
    training.train("go1-flat", "sb3", num_envs=8, max_iterations=1, logs_dir=tmp_path,
                   overrides=[NOISE_FREE, "agent.n_steps=8", "agent.batch_size=16",
                              "agent.net_arch=[16]"],
                   console=Console(file=said, width=300))
    assert ("note: sb3 has no critic input of its own: its critic reads the policy's "
            "observations, noise included (env.critic_observations is for rsl_rl and skrl)"
            ) in said.getvalue()


@pytest.mark.gpu
@needs_warp()
def test_the_replayed_gpu_step_gives_the_critic_observations_of_its_own_state():
    """On the warp backend the step replays as a CUDA graph: each step's critic observations are
    a copy of what the replayed step computed (the next replay does not overwrite them), within
    each term's noise of the policy's."""
    env = make_env("go1-flat", num_envs=16, seed=0, backend="warp", device="cuda",
                   overrides=[NO_PUSH, NOISE_FREE])
    try:
        terms = dict(env.cfg.observations.terms())
        columns = [terms[name.split(".")[0]] for name in env.observation_names]
        # Each column's noise, after the term's scale (Isaac Lab's order: noise, clip, scale).
        noise = torch.tensor([t.noise * abs(t.scale) for t in columns], device="cuda")
        env.reset(seed=3)
        action = torch.full((16, env.single_action_space.shape[0]), 0.3, device="cuda")
        kept = []
        for _ in range(6):  # the first steps capture the graph, the rest replay it
            obs, *_, info = env.step(action)
            critic = info["critic_obs"]
            torch.testing.assert_close(critic, env.task.critic_observations().float())
            assert ((obs - critic).abs() <= noise + 1e-5).all()
            kept.append((critic, critic.clone()))
        assert all(torch.equal(a, b) for a, b in kept)
        assert not torch.equal(kept[-1][0], kept[-2][0])
    finally:
        env.close()
