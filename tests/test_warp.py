"""The warp backend: parity with the cpu backend, LabVecEnv on it, and lab without it.

The GPU tests need CUDA and MuJoCo Warp (`pip install -e ".[warp]"`) and skip elsewhere, CI
included; their first run compiles MuJoCo Warp's kernels (~1 min, cached afterwards).
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys

import mujoco
import pytest
import torch
from conftest import needs_menagerie
from lab_cartpole.cartpole import Cartpole
from lab_cartpole.config import CartpoleConfig
from lab_cartpole.plugin import MODEL

from labcli.envs import metrics
from labcli.envs.env import LabVecEnv
from labcli.envs.sim import default_backend, make_sim
from labcli.envs.spec import TaskSpec
from labcli.errors import LabError
from labcli.gym import make_env

HAVE_WARP = all(importlib.util.find_spec(m) for m in ("warp", "mujoco_warp"))
on_gpu = pytest.mark.skipif(not (HAVE_WARP and torch.cuda.is_available()),
                            reason='needs a CUDA GPU and MuJoCo Warp (pip install -e ".[warp]")')

SPEC = TaskSpec(name="cartpole", task=Cartpole, config=CartpoleConfig, model=MODEL)
PARITY_ENVS = 64
PARITY_STEPS = 100
# float32 on the GPU against float64 on the CPU over 100 env steps (200 physics steps) of a
# randomly pushed cartpole whose cart reaches its rail limits. The gap grows with the pole's
# swings: 2e-7 after 10 env steps, 2e-6 after 50, 6.8e-5 after 100 on an H100 (mujoco-warp 4.0,
# warp 1.19; 24 of the 64 envs hit a limit), as MuJoCo Warp's own ~5e-5 on gymnasium's pendulum.
# 1e-3 (a millimetre, a milliradian) leaves 15x room for other GPUs and versions, while a missed
# limit, a wrong sign or a substep lost between the CUDA graph and torch is off by far more.
PARITY_TOL = 1e-3


def cartpole_model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(MODEL))


# Without a GPU (CI too): lab imports and explains ----------------------------------------------
def test_lab_imports_without_warp():
    code = ("import sys, labcli.envs.sim, labcli.envs.env, labcli.runs.session; "
            "sys.exit(int('warp' in sys.modules or 'mujoco_warp' in sys.modules))")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


def test_warp_backend_refuses_a_cpu_device():
    with pytest.raises(LabError, match="CUDA device") as err:
        make_sim("warp", cartpole_model(), 4, "cpu")
    assert "--device cuda" in err.value.hint


@pytest.mark.skipif(torch.cuda.is_available(), reason="CUDA is available here")
def test_warp_backend_without_cuda_says_how_to_get_it():
    with pytest.raises(LabError, match="needs CUDA") as err:
        make_sim("warp", cartpole_model(), 4, "cuda")
    assert 'pip install -e ".[warp]"' in err.value.hint


def test_default_backend_follows_the_device():
    assert default_backend("cpu") == "cpu"
    expected = "warp" if torch.cuda.is_available() and HAVE_WARP else "cpu"
    assert default_backend("cuda") == expected


# On a GPU -------------------------------------------------------------------------------------
@pytest.mark.gpu
@on_gpu
def test_trajectories_match_the_cpu_backend():
    """Same initial states, same controls (both rounded to float32 first, so only the engines
    differ), 100 env steps of `decimation` physics steps each: qpos agrees all along."""
    cfg = CartpoleConfig()
    model = cartpole_model()
    n = PARITY_ENVS
    cpu = make_sim("cpu", model, n, "cpu")
    gpu = make_sim("warp", model, n, "cuda")
    assert gpu.qpos.dtype == torch.float32 and gpu.qpos.device.type == "cuda"

    g = torch.Generator().manual_seed(0)

    def uniform(*shape: int, low: float, high: float) -> torch.Tensor:
        u = torch.rand(*shape, generator=g, dtype=torch.float64)
        return (low + u * (high - low)).float().double()

    qpos = torch.cat([uniform(n, 1, low=-1.0, high=1.0), uniform(n, 1, low=-0.8, high=0.8)], 1)
    qvel = uniform(n, 2, low=-0.5, high=0.5)
    ctrl = uniform(PARITY_STEPS, n, model.nu, low=-cfg.action_scale, high=cfg.action_scale)
    for sim in (cpu, gpu):
        sim.qpos.copy_(qpos)
        sim.qvel.copy_(qvel)

    errors = []
    at_limit = torch.zeros(n, dtype=torch.bool)
    for step in range(PARITY_STEPS):
        cpu.ctrl.copy_(ctrl[step])
        gpu.ctrl.copy_(ctrl[step])
        cpu.step(cfg.decimation)
        gpu.step(cfg.decimation)
        errors.append((gpu.qpos.cpu().double() - cpu.qpos).abs().max().item())
        at_limit |= cpu.qpos[:, 0].abs() > model.jnt_range[0, 1] - 0.05
    cpu.close()
    print(f"\nparity: max |qpos warp - cpu| over {PARITY_STEPS} env steps of {n} envs = "
          f"{max(errors):.2e} (after 10: {errors[9]:.2e}, 50: {errors[49]:.2e}, "
          f"100: {errors[-1]:.2e}); {int(at_limit.sum())} envs reached a rail limit")
    assert max(errors) < PARITY_TOL


@pytest.mark.gpu
@on_gpu
def test_masked_reset_touches_only_masked_envs():
    sim = make_sim("warp", cartpole_model(), 8, "cuda")
    sim.qpos.uniform_(-1.0, 1.0)
    sim.qvel.uniform_(-1.0, 1.0)
    before = sim.qpos.clone(), sim.qvel.clone()
    mask = torch.arange(8, device="cuda") % 2 == 0
    sim.reset_to_defaults(mask)
    qpos0 = torch.as_tensor(sim.model.qpos0, dtype=torch.float32, device="cuda")
    assert torch.equal(sim.qpos[mask], qpos0.expand(4, -1))
    assert torch.equal(sim.qvel[mask], torch.zeros(4, 2, device="cuda"))
    assert torch.equal(sim.qpos[~mask], before[0][~mask])
    assert torch.equal(sim.qvel[~mask], before[1][~mask])
    sim.reset_to_defaults(torch.zeros(8, dtype=torch.bool, device="cuda"))
    assert torch.equal(sim.qpos[~mask], before[0][~mask])


@pytest.fixture(scope="module")
def warp_env():
    env = LabVecEnv(SPEC, CartpoleConfig(num_envs=256), backend="warp", device="cuda")
    yield env
    env.close()


@pytest.mark.gpu
@on_gpu
def test_env_shapes_devices_and_autoreset(warp_env):
    env = warp_env
    n = env.num_envs
    obs, _ = env.reset(seed=0)
    assert obs.shape == (n, 4) and obs.dtype == torch.float32 and obs.device.type == "cuda"
    g = torch.Generator(device="cuda").manual_seed(1)
    ended = torch.zeros(n, dtype=torch.bool, device="cuda")
    for _ in range(env.max_episode_length):
        actions = torch.rand(n, 1, device="cuda", generator=g) * 2 - 1
        obs, reward, terminated, truncated, info = env.step(actions)
        for t, shape, dtype in ((obs, (n, 4), torch.float32), (reward, (n,), torch.float32),
                                (terminated, (n,), torch.bool), (truncated, (n,), torch.bool)):
            assert t.shape == shape and t.dtype == dtype and t.device.type == "cuda"
        assert torch.isfinite(obs).all() and torch.isfinite(reward).all()
        done = terminated | truncated
        ended |= done
        # Ended envs start over in the same step: a fresh episode, its first observation.
        assert (env.episode_length[done] == 0).all()
        assert torch.equal(info["_final_obs"], done)
        fresh = obs[done]
        assert (fresh[:, 0].abs() <= 1.0 + 1e-6).all()
        assert (fresh[:, 1].abs() <= 0.25 * torch.pi + 1e-6).all()
    # By the time-out every env has ended once, and the statistics say so.
    assert ended.all()
    stats = env.pop_stats()
    assert stats[metrics.EPISODES] >= n


@pytest.mark.gpu
@on_gpu
def test_a_gpu_env_draws_from_one_generator_and_resumes_a_state_saved_per_block(warp_env):
    env = warp_env
    env.reset(seed=0)
    assert len(env.rng.generators) == 1
    state = env.get_state()
    per_block = state["generator"].repeat(16, 1)  # as GPU envs saved it before one generator
    per_block[1:, 0] += 1
    env.set_state({**state, "generator": per_block})
    assert torch.equal(env.rng.get_state(), per_block[:1])


@pytest.mark.gpu
@on_gpu
def test_env_resets_envs_fed_non_finite_actions(warp_env):
    env = warp_env
    env.reset(seed=0)
    actions = torch.zeros(env.num_envs, 1, device="cuda")
    actions[3] = float("nan")
    obs, _, terminated, _, _ = env.step(actions)
    assert terminated[3] and not terminated[:3].any()
    assert torch.isfinite(obs).all()
    assert env.episode_length[3] == 0


def pushing_actions(n: int, i: int) -> torch.Tensor:
    """Full pushes that drive some carts off the rail within tens of steps: episodes end and
    random resets happen while the step replays as a graph."""
    return torch.sin(torch.arange(n, device="cuda")[:, None] * 0.1 + i * 0.05).sign()


@pytest.mark.gpu
@on_gpu
@pytest.mark.parametrize("mode", ["same_step", "next_step"])
def test_graphed_step_equals_the_eager_step(mode):
    """The env's CUDA graph (captured after three eager steps) replays the same MDP as eager
    steps, in either autoreset mode: observations, rewards, flags, final observations,
    episodes, random resets, stats."""
    n, steps = 128, 120
    graphed = LabVecEnv(SPEC, CartpoleConfig(num_envs=n), backend="warp", device="cuda",
                        autoreset_mode=mode)
    eager = LabVecEnv(SPEC, CartpoleConfig(num_envs=n, cuda_graph=False), backend="warp",
                      device="cuda", autoreset_mode=mode)
    assert graphed._graphed is not None and eager._graphed is None
    for env in (graphed, eager):
        env.reset(seed=3)
    ended = 0
    for i in range(steps):
        actions = pushing_actions(n, i)
        got, want = graphed.step(actions), eager.step(actions)
        torch.testing.assert_close(got[0], want[0], rtol=0, atol=1e-5)  # obs
        torch.testing.assert_close(got[1], want[1], rtol=0, atol=1e-5)  # reward
        assert torch.equal(got[2], want[2]) and torch.equal(got[3], want[3])
        assert got[4].keys() == want[4].keys()
        if "final_obs" in want[4]:
            torch.testing.assert_close(got[4]["final_obs"], want[4]["final_obs"], rtol=0,
                                       atol=1e-5)
        assert torch.equal(got[4]["lab_episode"]["l"], want[4]["lab_episode"]["l"])
        ended += int((want[2] | want[3]).sum())
    assert ended > 10, "the pushes should end episodes, so that resets replay too"
    got, want = graphed.pop_stats(), eager.pop_stats()
    assert got.keys() == want.keys()
    for key in got:
        assert got[key] == pytest.approx(want[key], rel=1e-4, abs=1e-5), key
    for env in (graphed, eager):
        env.close()


@pytest.mark.gpu
@on_gpu
@needs_menagerie("unitree_go1")
def test_a_value_terms_share_read_between_replayed_steps_is_the_current_one():
    """Terms share values computed once per state (`robot.per_state`). A read between steps
    caches one, and a replayed step runs none of the task's Python: the next read must see the
    state the graph left, not the one cached (panda-lift's grasp, read after each step, stayed
    at its first value: loose)."""
    env = make_env("go1-flat", num_envs=4, seed=0, backend="warp", device="cuda")
    try:
        env.reset()
        robot = env.task.robot
        assert env._graphed is not None
        generator = torch.Generator(device="cuda").manual_seed(0)
        for _ in range(8):  # three eager warm-up steps, the capture, then replays
            env.step(torch.rand(4, 12, generator=generator, device="cuda") * 2 - 1)
            now = (2.0 * robot.joint_pos - robot.joint_upper - robot.joint_lower) / (
                robot.joint_upper - robot.joint_lower)
            torch.testing.assert_close(robot.joint_pos_normalized(), now)
    finally:
        env.close()


@pytest.mark.gpu
@on_gpu
def test_graphed_step_returns_fresh_tensors(warp_env):
    """A learner keeps `obs` while it steps to `next_obs`: the graph's replay must not overwrite
    what an earlier step returned."""
    env = warp_env
    env.reset(seed=0)
    actions = torch.ones(env.num_envs, 1, device="cuda")
    outputs = [env.step(actions) for _ in range(6)]  # the capture happens at the fourth
    kept = outputs[4][0].clone()
    env.step(-actions)
    assert torch.equal(outputs[4][0], kept)
    assert outputs[4][0].data_ptr() != outputs[5][0].data_ptr()
    # Outputs that are one tensor in the eager step are one tensor after a replay too.
    info = outputs[5][4]
    assert info["_final_obs"] is info["_lab_episode"]


@pytest.mark.gpu
@on_gpu
def test_eager_calls_between_replays_see_the_replayed_state(warp_env):
    """Between replays, eager code reads the env (a full reset, a learner's
    `env.observations()`): it must see what the last replay computed, also after an eager reset
    ran the task's code outside the graph."""
    env = warp_env
    env.reset(seed=0)
    actions = torch.ones(env.num_envs, 1, device="cuda")
    for _ in range(5):  # past the capture
        env.step(actions)
    env.reset(seed=1)  # eager: the task's reset and any per-step caches run outside the graph
    for i in range(3):
        obs, *_ = env.step(actions if i % 2 else -actions)
        assert torch.equal(env.observations(), obs)


class SyncingCartpole(Cartpole):
    """Reads a value back to the host in its step, which no CUDA graph can hold."""

    def reward_terms(self) -> dict[str, torch.Tensor]:
        terms = super().reward_terms()
        if terms["alive"].sum().item() < 0:
            raise AssertionError("unreachable")
        return terms


@pytest.mark.gpu
@on_gpu
def test_a_step_that_syncs_is_one_line_that_says_how_to_step_eagerly():
    spec = TaskSpec(name="syncing", task=SyncingCartpole, config=CartpoleConfig, model=MODEL)
    env = LabVecEnv(spec, CartpoleConfig(num_envs=16), backend="warp", device="cuda")
    env.reset(seed=0)
    actions = torch.zeros(16, 1, device="cuda")
    for _ in range(3):  # eager warm-up steps: syncing is only slow
        env.step(actions)
    with pytest.raises(LabError, match="could not be captured in a CUDA graph") as err:
        env.step(actions)
    assert "env.cuda_graph=false" in err.value.hint
    env.close()
    eager = LabVecEnv(spec, CartpoleConfig(num_envs=16, cuda_graph=False), backend="warp",
                      device="cuda")
    eager.reset(seed=0)
    for _ in range(5):
        obs, *_ = eager.step(actions)
    assert torch.isfinite(obs).all()
    eager.close()
