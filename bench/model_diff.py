"""Two compiled MuJoCo models side by side, field by field: what sets a task of lab's apart
from a peer's recipe of it beyond the configs both print.

  python bench/model_diff.py dump --task yam-lift [--set env.KEY=VALUE ...] LAB.json
  python bench/model_diff.py dump --mjlab Mjlab-Lift-Cube-Yam MJLAB.json   # where mjlab is
  python bench/model_diff.py compare MJLAB.json LAB.json

`dump` writes a model's physics as JSON: its options; each body's mass, inertia and gravity
compensation; each joint's range, armature, damping and friction loss; each actuator's gains,
control and force ranges; each colliding geom's contact settings (keyed by body, type and
position, as Menagerie's geoms have no names); equalities and sites. With `--task`, lab's
model of the task (as `lab train` builds it); with `--mjlab`, mjlab's scene of the task, built
in a Python where mjlab and its MuJoCo are installed (mjlab 1.6.0 pins MuJoCo 3.11, so the two
dumps come from two environments). `compare` prints each field that differs, names stripped of
the entity prefixes mjlab gives them (`robot/`, `cube/`); bodies and geoms only one side has
(mjlab's terrain, its camera mount) are listed as such. Found this way: Menagerie's YAM keeps
its gripper's servo to targets of 0-41 mm (`ctrllimited`), which mjlab's does not.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import mujoco
import numpy as np

# Relative tolerance of two numbers called the same (the two MuJoCo versions' rounding).
TOLERANCE = 1e-4
OPTIONS = ["timestep", "impratio", "tolerance", "ls_tolerance", "noslip_iterations",
           "iterations", "ls_iterations", "cone", "integrator", "solver", "jacobian",
           "disableflags", "enableflags", "gravity"]


def _name(model: mujoco.MjModel, kind: mujoco.mjtObj, i: int) -> str:
    return mujoco.mj_id2name(model, kind, i) or f"#{i}"


def _rounded(values, digits: int = 6) -> list[float]:
    return [round(float(v), digits) for v in np.ravel(values)]


def dump(model: mujoco.MjModel) -> dict:
    """The model's physics by name, as JSON-ready dicts."""
    obj = mujoco.mjtObj
    joints = {}
    for j in range(model.njnt):
        dof = model.jnt_dofadr[j]
        joints[_name(model, obj.mjOBJ_JOINT, j)] = {
            "type": int(model.jnt_type[j]), "range": _rounded(model.jnt_range[j]),
            "limited": bool(model.jnt_limited[j]), "armature": float(model.dof_armature[dof]),
            "damping": float(model.dof_damping[dof]),
            "frictionloss": float(model.dof_frictionloss[dof]),
            "stiffness": float(model.jnt_stiffness[j]), "solref": _rounded(model.jnt_solref[j])}
    actuators = {}
    for a in range(model.nu):
        limited = bool(model.actuator_ctrllimited[a])
        # By the joint it drives: the two sides name a gripper's actuator differently.
        actuators[f"on {_name(model, obj.mjOBJ_JOINT, model.actuator_trnid[a, 0])}"] = {
            "gain": _rounded(model.actuator_gainprm[a, :3]),
            "bias": _rounded(model.actuator_biasprm[a, :3]),
            "ctrllimited": limited,
            # An unlimited actuator's range is not read: left out, not compared.
            "ctrlrange": _rounded(model.actuator_ctrlrange[a]) if limited else None,
            "forcelimited": bool(model.actuator_forcelimited[a]),
            "forcerange": _rounded(model.actuator_forcerange[a])}
    geoms = {}
    for g in range(model.ngeom):
        if not (model.geom_contype[g] or model.geom_conaffinity[g]):
            continue
        body = _name(model, obj.mjOBJ_BODY, model.geom_bodyid[g])
        key = f"{body} type {int(model.geom_type[g])} at {_rounded(model.geom_pos[g], 4)}"
        geoms[key] = {
            "size": _rounded(model.geom_size[g], 5), "contype": int(model.geom_contype[g]),
            "conaffinity": int(model.geom_conaffinity[g]), "condim": int(model.geom_condim[g]),
            "priority": int(model.geom_priority[g]), "friction": _rounded(model.geom_friction[g]),
            "solref": _rounded(model.geom_solref[g]), "solimp": _rounded(model.geom_solimp[g]),
            "margin": float(model.geom_margin[g]), "gap": float(model.geom_gap[g])}
    # Each MuJoCo version numbers its flags its own way: by name.
    flags = {field: [name for name, bit in bits.__members__.items()
                     if getattr(model.opt, field) & int(bit)]
             for field, bits in (("disableflags", mujoco.mjtDisableBit),
                                 ("enableflags", mujoco.mjtEnableBit))}
    return {
        "options": {k: flags[k] if k in flags else _rounded(getattr(model.opt, k))
                    for k in OPTIONS},
        "bodies": {_name(model, obj.mjOBJ_BODY, b): {
            "mass": float(model.body_mass[b]), "inertia": _rounded(model.body_inertia[b], 8),
            "gravcomp": float(model.body_gravcomp[b])} for b in range(1, model.nbody)},
        "joints": joints, "actuators": actuators, "geoms": geoms,
        "equalities": {f"{int(model.eq_type[e])} "
                       f"{_name(model, obj.mjOBJ_JOINT, model.eq_obj1id[e])}": {
                           "data": _rounded(model.eq_data[e, :5]),
                           "solref": _rounded(model.eq_solref[e])} for e in range(model.neq)},
        "sites": {_name(model, obj.mjOBJ_SITE, s): {
            "body": _name(model, obj.mjOBJ_BODY, model.site_bodyid[s]),
            "pos": _rounded(model.site_pos[s], 5)} for s in range(model.nsite)},
    }


def lab_model(task: str, sets: list[str]) -> mujoco.MjModel:
    """lab's model of the task, as `lab train` builds it (with its options)."""
    from labcli.gym import make_env

    env = make_env(task, 1, backend="cpu", overrides=sets, threads=1)
    try:
        return env.sim.model
    finally:
        env.close()


def mjlab_model(task: str) -> mujoco.MjModel:
    """mjlab's scene of the task compiled, with the options its simulation sets."""
    import mjlab.tasks  # noqa: F401  (registers the tasks)
    from mjlab.scene import Scene
    from mjlab.tasks.registry import load_env_cfg

    cfg = load_env_cfg(task)
    cfg.scene.num_envs = 1
    model = Scene(cfg.scene, device="cpu").compile()
    cfg.sim.mujoco.apply(model)
    return model


def _unprefixed(name: str) -> str:
    """A name without mjlab's entity prefixes (`robot/link_6` is `link_6`)."""
    return " ".join(part.rsplit("/", 1)[-1] for part in name.split(" "))


def _same(a, b) -> bool:
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, bool) or isinstance(b, bool):
        return a == b
    if isinstance(a, int | float) and isinstance(b, int | float):
        return math.isclose(a, b, rel_tol=TOLERANCE, abs_tol=TOLERANCE * 1e-3)
    return a == b


def compare(first: dict, second: dict) -> list[str]:
    """Each difference as a line: `section name: field first | second`, and the entries only
    one side has."""
    lines = []
    for section in first.keys() | second.keys():
        ours = {_unprefixed(k): v for k, v in first.get(section, {}).items()}
        theirs = {_unprefixed(k): v for k, v in second.get(section, {}).items()}
        for name in sorted(ours.keys() | theirs.keys()):
            if name not in theirs or name not in ours:
                lines.append(f"{section} {name}: only in the "
                             f"{'first' if name in ours else 'second'}")
                continue
            a, b = ours[name], theirs[name]
            if not isinstance(a, dict):
                a, b, fields = {"": a}, {"": b}, [""]
            else:
                fields = sorted(a.keys() | b.keys())
            for field in fields:
                x, y = a.get(field), b.get(field)
                if isinstance(x, str) and isinstance(y, str):
                    x, y = _unprefixed(x), _unprefixed(y)
                if not _same(x, y):
                    lines.append(f"{section} {name}: {field} {x} | {y}".replace(":  ", ": "))
    return sorted(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    verbs = parser.add_subparsers(dest="verb", required=True)
    dumping = verbs.add_parser("dump", help="a model's physics as JSON")
    source = dumping.add_mutually_exclusive_group(required=True)
    source.add_argument("--task", help="lab's task")
    source.add_argument("--mjlab", help="mjlab's task (in a Python with mjlab installed)")
    dumping.add_argument("--set", dest="sets", action="append", default=[],
                         metavar="env.KEY=VALUE", help="with --task: a setting of lab's")
    dumping.add_argument("out", type=Path)
    comparing = verbs.add_parser("compare", help="the fields two dumps differ in")
    comparing.add_argument("first", type=Path)
    comparing.add_argument("second", type=Path)
    args = parser.parse_args()
    if args.verb == "dump":
        model = lab_model(args.task, args.sets) if args.task else mjlab_model(args.mjlab)
        args.out.write_text(json.dumps(dump(model), indent=1) + "\n")
        print(f"wrote {args.out}: {model.nbody - 1} bodies, {model.njnt} joints, "
              f"{model.nu} actuators")
        return
    lines = compare(json.loads(args.first.read_text()), json.loads(args.second.read_text()))
    print("\n".join(lines) if lines else "no difference")
    print(f"{len(lines)} differences between {args.first} and {args.second}")


if __name__ == "__main__":
    main()
