"""Do MuJoCo's C engine and MuJoCo Warp step a task's hardest states alike?

  python bench/backend_agreement.py --task go1-rough [--envs 128] [--steps 200] [--states 256]
                                    [--horizon 100] [--limit 100] [--set env.KEY=VALUE ...]

A CPU rollout of `--envs` envs under random actions (resets included) is sampled every 5 env
steps; the `--states` samples with the most constraint rows (contacts, limits) are then stepped
`--horizon` physics steps from the same state and controls, in MuJoCo (float64) and in MuJoCo Warp
(float32, on CUDA where torch sees a GPU, else on warp's CPU device, which needs no GPU). First it
prints the contacts each engine finds in those states (how many, how deep, how many vertical);
every 20 steps the largest joint speed in each and how many worlds passed `--limit`; at the end
how many passed it in MuJoCo Warp and not in MuJoCo. The states are those MuJoCo's rollout
reached, which MuJoCo Warp's own may not; per-env randomized fields (friction, masses) are the
model's own in both.
"""

from __future__ import annotations

import argparse

import mujoco
import numpy as np
import torch

from labcli.gym import make_env

SAMPLE_EVERY = 5
REPORT_EVERY = 20


def hardest_states(task: str, sets: list[str], envs: int, steps: int, count: int):
    """The task's model and config, and the `count` sampled (qpos, qvel, ctrl) with the most
    constraint rows, most first."""
    # One thread: one env of all of them, not shards, whose state this reads.
    env = make_env(task, envs, backend="cpu", overrides=sets, threads=1)
    cfg = env.cfg
    # A fresh build, the model both engines are given (the cpu backend's own has its options).
    model = env.task_spec.task_class.build_model(cfg, env.task_spec.model)
    data = mujoco.MjData(model)
    actions = torch.Generator().manual_seed(0)
    samples = []
    try:
        env.reset(seed=0)
        for step in range(steps):
            noise = torch.randn(envs, env.single_action_space.shape[0], generator=actions)
            env.step(noise.clamp(-3.0, 3.0))
            if step % SAMPLE_EVERY == SAMPLE_EVERY - 1:
                for qpos, qvel, ctrl in zip(env.sim.qpos.numpy(), env.sim.qvel.numpy(),
                                            env.sim.ctrl.numpy(), strict=True):
                    data.qpos[:], data.qvel[:] = qpos, qvel
                    mujoco.mj_forward(model, data)
                    samples.append((data.nefc, qpos.copy(), qvel.copy(), ctrl.copy()))
    finally:
        env.close()
    samples.sort(key=lambda s: -s[0])
    return model, cfg, samples[:count]


def contact_summary(dist: np.ndarray, normal_z: np.ndarray, states: int) -> str:
    """Contacts a state, the deepest and the share whose normal is within 30° of vertical: a
    height field's prism side met as its top (docs/benchmarks.md) shows as deep vertical ones."""
    if not len(dist):
        return "no contacts"
    vertical = float((np.abs(normal_z) >= np.cos(np.radians(30))).mean())
    return (f"{len(dist) / states:.1f} contacts a state, the deepest {-dist.min() * 1000:.0f} "
            f"mm, {vertical:.0%} of them within 30° of vertical")


def compare(model: mujoco.MjModel, cfg, states, horizon: int, limit: float) -> None:
    import mujoco_warp as mjw
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    device = "cuda:0" if torch.cuda.is_available() else "cpu"
    qpos, qvel, ctrl = (np.array([s[i] for s in states]) for i in (1, 2, 3))
    datas = []
    for i in range(len(states)):
        data = mujoco.MjData(model)
        data.qpos[:], data.qvel[:], data.ctrl[:] = qpos[i], qvel[i], ctrl[i]
        datas.append(data)
    with wp.ScopedDevice(device):
        m = mjw.put_model(model)
        m.opt.warn_overflow = 0  # the solver's spent iterations are MuJoCo's too
        sizes = {k: v for k, v in (("nconmax", cfg.nconmax), ("njmax", cfg.njmax)) if v}
        d = mjw.put_data(model, datas[0], nworld=len(states), **sizes)
        for name, values in (("qpos", qpos), ("qvel", qvel), ("ctrl", ctrl)):
            getattr(d, name).assign(wp.array(values.astype(np.float32)))
        print(f"{len(states)} states, {states[0][0]}-{states[-1][0]} constraint rows in "
              f"MuJoCo; MuJoCo Warp on {device}")
        mjw.forward(m, d)  # the contacts of the states as given; the steps recompute them
        n = int(d.nacon.numpy()[0])
        for data in datas:
            mujoco.mj_forward(model, data)
        in_c = contact_summary(np.concatenate([data.contact.dist for data in datas]),
                               np.concatenate([data.contact.frame[:, 2] for data in datas]),
                               len(states))
        in_warp = contact_summary(d.contact.dist.numpy()[:n], d.contact.frame.numpy()[:n, 0, 2],
                                  len(states))
        print(f"contacts at the start: {in_c} in MuJoCo; {in_warp} in MuJoCo Warp")
        for step in range(1, horizon + 1):
            mjw.step(m, d)
            for data in datas:
                mujoco.mj_step(model, data)
            if step % REPORT_EVERY == 0 or step == horizon:
                warp_speed = np.nan_to_num(np.abs(d.qvel.numpy()), nan=np.inf).max(axis=1)
                c_speed = np.abs(np.array([data.qvel for data in datas])).max(axis=1)
                print(f"step {step:4d}: largest joint speed {warp_speed.max():.3g} in MuJoCo "
                      f"Warp, {c_speed.max():.3g} in MuJoCo; worlds past {limit:g}: "
                      f"{int((warp_speed > limit).sum())} and {int((c_speed > limit).sum())}")
    apart = int(((warp_speed > limit) & (c_speed <= limit)).sum())
    print(f"past {limit:g} in MuJoCo Warp and not in MuJoCo: {apart} of {len(states)} worlds")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--task", required=True)
    p.add_argument("--set", action="append", default=[], dest="sets", metavar="env.KEY=VALUE")
    p.add_argument("--envs", type=int, default=128)
    p.add_argument("--steps", type=int, default=200, help="env steps of the CPU rollout")
    p.add_argument("--states", type=int, default=256)
    p.add_argument("--horizon", type=int, default=100, help="physics steps from each state")
    p.add_argument("--limit", type=float, default=100.0, help="joint speed, rad/s or m/s")
    a = p.parse_args()
    model, cfg, states = hardest_states(a.task, a.sets, a.envs, a.steps, a.states)
    compare(model, cfg, states, a.horizon, a.limit)


if __name__ == "__main__":
    main()
