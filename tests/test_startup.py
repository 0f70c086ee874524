"""`lab` answers at once: the commands that list, configure and complete import no torch, MuJoCo
or learning library, and `lab train` says what it is about to do before importing them. Timings
are measured by bench/bench_startup.py, not here."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap

import pytest

HEAVY = ("torch", "mujoco", "stable_baselines3", "rsl_rl", "skrl", "gymnasium", "warp", "ray",
         "optuna")
# Runs a command in a fresh interpreter, as the console script does, and prints the heavy
# modules it imported.
PROBE = textwrap.dedent("""
    import sys
    from labcli.commands.app import app
    try:
        app(sys.argv[1:], prog_name="lab")
    except SystemExit as exc:
        assert exc.code in (0, None), exc.code
    heavy = sorted({name.split(".")[0] for name in sys.modules} & set(HEAVY))
    print("HEAVY=" + ",".join(heavy), file=sys.stderr)
""").replace("HEAVY)", f"{HEAVY!r})")
TORCH_IMPORTED = re.compile(r"^import time:.*\|\s+torch$")
COMPLETION = {"_LAB_COMPLETE": "complete_bash", "COMP_WORDS": "lab train --task ca",
              "COMP_CWORD": "3"}


def heavy_imports(*args: str, env: dict[str, str] | None = None, logs) -> tuple[str, str]:
    result = subprocess.run([sys.executable, "-c", PROBE, *args], capture_output=True,
                            text=True, env={**os.environ, "LAB_LOGS_DIR": str(logs),
                                            **(env or {})}, timeout=60)
    assert result.returncode == 0, result.stderr
    (line,) = [line for line in result.stderr.splitlines() if line.startswith("HEAVY=")]
    return line.removeprefix("HEAVY="), result.stdout


@pytest.mark.parametrize("args", [["--help"], ["--version"], ["list"], ["runs"],
                                  ["config", "show", "--task", "cartpole", "--framework", "sb3"],
                                  ["train", "--help"], ["sweep", "--help"]])
def test_light_commands_import_no_heavy_library(args, tmp_path):
    heavy, out = heavy_imports(*args, logs=tmp_path)
    assert heavy == "", f"lab {' '.join(args)} imported {heavy}"
    assert out  # each printed what it is for


def test_mujoco_warp_without_a_gpu_keeps_config_show_light(tmp_path):
    """With MuJoCo Warp installed where NVIDIA's driver does not load (a laptop with
    lab[warp]), picking the CPU's defaults asks no torch whether a GPU is usable."""
    from labcli.runs.plan import cuda_driver_loads

    if cuda_driver_loads():
        pytest.skip("NVIDIA's driver loads here: torch is asked, as it must be")
    site = tmp_path / "site"
    (site / "mujoco_warp").mkdir(parents=True)
    (site / "mujoco_warp" / "__init__.py").write_text("")
    env = {"PYTHONPATH": os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))}
    found = subprocess.run([sys.executable, "-c", "import importlib.util as u; "
                            "print(u.find_spec('mujoco_warp').origin)"], capture_output=True,
                           text=True, env={**os.environ, **env}, check=True)
    assert found.stdout.strip() == str(site / "mujoco_warp" / "__init__.py")
    heavy, out = heavy_imports("config", "show", "--task", "cartpole", "--framework", "sb3",
                               env=env, logs=tmp_path / "logs")
    assert heavy == ""
    assert "num_envs" in out


def test_completion_imports_no_heavy_library(tmp_path):
    heavy, out = heavy_imports(env=COMPLETION, logs=tmp_path)
    assert heavy == ""
    assert out.split() == ["cartpole"]


def test_train_announces_itself_before_importing_torch(tmp_path):
    """With -X importtime, Python reports each import on stderr as it happens: the line that
    says what lab train will do must come before torch's."""
    proc = subprocess.Popen(
        [sys.executable, "-X", "importtime", "-m", "labcli", "train", "--task", "cartpole",
         "--framework", "rsl_rl", "--max-iterations", "1"],
        stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
        env={**os.environ, "LAB_LOGS_DIR": str(tmp_path)})
    seen = []
    try:
        for line in proc.stderr:
            seen.append(line)
            if TORCH_IMPORTED.match(line.rstrip()):
                break
    finally:
        proc.kill()
        proc.wait()
    announced = [i for i, line in enumerate(seen) if line.startswith("train cartpole with rsl_rl")]
    assert announced, "".join(seen[-5:])
    assert TORCH_IMPORTED.match(seen[-1].rstrip())  # torch came, after the announcement
