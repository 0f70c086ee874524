"""yam-lift's physics beside mjlab's Mjlab-Lift-Cube-Yam under the same actions: a scripted
grasp (the cube lifted 10 cm, `lab_manipulation.scripted`) recorded in lab and replayed in
mjlab, step by step.

  python bench/replay_diff.py lab [--set env.KEY=VALUE ...] LAB.npz
  python bench/replay_diff.py mjlab LAB.npz MJLAB.npz      # in a Python with mjlab 1.6.0
  python bench/replay_diff.py compare LAB.npz MJLAB.npz

`lab` runs two envs of yam-lift on the CPU: the cubes settle, the grasp is planned from where
they rest, and each step's joint positions and cube position (in the arm's base frame) are
written with the actions and the settled state. `mjlab` lets mjlab's two envs settle as long,
puts their cubes where lab's rest, replays the actions and writes the same. `compare` prints
how far apart the arms' joints settled, the largest joint difference of the two envs over the
replay (median, 90th percentile and largest over the steps; each env's up to an episode's end
on either side, as when the hand presses on the floor), and each side's cube height over its rest at
the end. `bench/model_diff.py` compares the two compiled models field by field; this, what
those fields do.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

ENVS = 2
JOINTS = 8  # the arm's six and the two fingers', in both models' order


def record_lab(sets: list[str]) -> dict[str, np.ndarray]:
    from lab_manipulation.scripted import CUBE_POS, CUBE_QUAT, SETTLE_STEPS, grasp, settle

    from labcli.gym import make_env

    env = make_env("yam-lift", num_envs=ENVS, seed=0, backend="cpu", device="cpu",
                   overrides=["env.observation_noise=false", *sets])
    try:
        env.reset()
        settle(env)
        settled = env.sim.qpos.double().numpy()
        joints_at_rest = settled[:, :JOINTS].copy()
        cube_rest = np.concatenate([settled[:, CUBE_POS], settled[:, CUBE_QUAT]], axis=1)
        actions = grasp(env)
        joints, cubes, ended = [], [], []
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            qpos = env.sim.qpos.double().numpy()
            joints.append(qpos[:, :JOINTS].copy())
            cubes.append(qpos[:, CUBE_POS].copy())  # the base stands at the world's origin
            ended.append((terminated | truncated).numpy().copy())
    finally:
        env.close()
    return {"settled_joints": joints_at_rest, "cube_rest": cube_rest,
            "settle_steps": np.array(SETTLE_STEPS), "actions": torch.stack(actions).numpy(),
            "joints": np.stack(joints), "cubes": np.stack(cubes), "ended": np.stack(ended)}


def replay_mjlab(lab: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    import mjlab.tasks  # noqa: F401 (registers the tasks)
    from mjlab.envs import ManagerBasedRlEnv
    from mjlab.tasks.registry import load_env_cfg

    cfg = load_env_cfg("Mjlab-Lift-Cube-Yam")
    cfg.scene.num_envs = ENVS
    env = ManagerBasedRlEnv(cfg, device="cpu")
    env.reset()
    robot, cube = env.scene["robot"], env.scene["cube"]
    zero = torch.zeros(ENVS, lab["actions"].shape[2])
    for _ in range(int(lab["settle_steps"])):  # as long as lab's cubes settled
        env.step(zero)
    settled_joints = robot.data.joint_pos.double().numpy().copy()
    base = robot.data.root_link_pos_w.clone()
    rest = torch.tensor(lab["cube_rest"], dtype=torch.float32)
    cube.write_root_link_pose_to_sim(torch.cat([rest[:, :3] + base, rest[:, 3:]], dim=1))
    cube.write_root_link_velocity_to_sim(torch.zeros(ENVS, 6))
    env.sim.forward()
    joints, cubes, ended = [], [], []
    for action in lab["actions"]:
        _, _, terminated, truncated, _ = env.step(torch.from_numpy(action))
        joints.append(robot.data.joint_pos.double().numpy().copy())
        cubes.append((cube.data.root_link_pos_w - base).double().numpy().copy())
        ended.append((terminated | truncated).numpy().copy())
    return {"settled_joints": settled_joints, "joints": np.stack(joints),
            "cubes": np.stack(cubes), "ended": np.stack(ended)}


def compare(lab: dict[str, np.ndarray], mjlab: dict[str, np.ndarray]) -> dict[str, float]:
    settled = np.abs(mjlab["settled_joints"] - lab["settled_joints"]).max()
    # Each env's steps before its first episode's end on either side.
    live = np.cumsum(lab["ended"] | mjlab["ended"], axis=0) == 0
    apart = np.abs(mjlab["joints"] - lab["joints"]).max(axis=2)  # [steps, envs]
    per_step = np.where(live, apart, np.nan)
    per_step = per_step[~np.isnan(per_step).all(axis=1)]
    worst = np.nanmax(per_step, axis=1)
    rest = lab["cube_rest"][:, 2]
    row = {"settled_joints_apart": float(settled),
           "joints_apart_median": float(np.median(worst)),
           "joints_apart_p90": float(np.percentile(worst, 90)),
           "joints_apart_max": float(worst.max()), "steps_compared": int(len(worst)),
           "ended_envs": int((~live[-1]).sum()),
           "lab_cube_raised": (lab["cubes"][-1, :, 2] - rest).tolist(),
           "mjlab_cube_raised": (mjlab["cubes"][-1, :, 2] - rest).tolist()}
    print(f"joints settled apart by up to {row['settled_joints_apart']:.4f} rad (m for a finger)")
    print(f"over {row['steps_compared']} steps, the largest joint difference: median "
          f"{row['joints_apart_median']:.4f}, 90th percentile {row['joints_apart_p90']:.4f}, "
          f"largest {row['joints_apart_max']:.4f} ({row['ended_envs']} of {ENVS} envs' "
          "episodes ended early)")
    print("the cubes raised at the end (m): lab "
          + ", ".join(f"{z:.3f}" for z in row["lab_cube_raised"]) + "; mjlab "
          + ", ".join(f"{z:.3f}" for z in row["mjlab_cube_raised"]))
    return row


def _load(path: Path) -> dict[str, np.ndarray]:
    with np.load(path) as arrays:
        return dict(arrays)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    verbs = p.add_subparsers(dest="verb", required=True)
    recording = verbs.add_parser("lab", help="record the scripted grasp in lab's yam-lift")
    recording.add_argument("--set", dest="sets", action="append", default=[],
                           help="a config override, as lab train's --set")
    recording.add_argument("out", type=Path)
    replaying = verbs.add_parser("mjlab", help="replay a recording in mjlab's task")
    replaying.add_argument("lab", type=Path)
    replaying.add_argument("out", type=Path)
    comparing = verbs.add_parser("compare", help="the two side by side")
    comparing.add_argument("lab", type=Path)
    comparing.add_argument("mjlab", type=Path)
    a = p.parse_args()
    if a.verb == "lab":
        np.savez(a.out, **record_lab(a.sets))
    elif a.verb == "mjlab":
        np.savez(a.out, **replay_mjlab(_load(a.lab)))
    else:
        compare(_load(a.lab), _load(a.mjlab))


if __name__ == "__main__":
    main()
