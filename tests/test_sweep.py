"""`lab sweep`: the space file and every bad input (no Ray: checked before Ray starts), the one
line without Ray installed, and real sweeps of cartpole with rsl_rl on a local Ray: trials are
lab runs, each iteration reaches Tune, ASHA's stops end as clean runs, best.yaml retrains, and
an interrupted sweep resumes."""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from oneline import assert_one_line_error
from typer.testing import CliRunner

from labcli.commands.app import app
from labcli.errors import LabError
from labcli.plugins import registry
from labcli.runs import rundir, space

SPACE = {"agent.learning_rate": {"loguniform": [1.0e-4, 1.0e-2]},
         "agent.entropy_coef": {"uniform": [0.0, 0.01]},
         "agent.num_learning_epochs": {"choice": [4, 8]}}
# Small: 64 envs, a trial's run a few seconds on one core.
SMALL = ["--task", "cartpole", "--framework", "rsl_rl", "--set", "env.num_envs=64",
         "--max-concurrent", "2"]


def lab(*args: str, logs: Path) -> object:
    return CliRunner().invoke(app, [*args], env={"LAB_LOGS_DIR": str(logs), "COLUMNS": "250"})


def space_file(tmp_path: Path, data: object, name: str = "space.yaml") -> Path:
    path = tmp_path / name
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data))
    return path


# The space file -------------------------------------------------------------------------------

def test_the_space_reads_each_distribution():
    parsed = space.parse({**SPACE, "agent.num_mini_batches": {"randint": [2, 8]},
                          "agent.gamma": {"uniform": ["9.5e-1", "9.9e-1"]}})
    assert parsed["agent.learning_rate"] == space.Distribution("loguniform", (1e-4, 1e-2))
    assert parsed["agent.num_learning_epochs"].values == (4, 8)
    assert parsed["agent.num_mini_batches"] == space.Distribution("randint", (2, 8))
    # YAML 1.1 reads 9.5e-1 as a string; a space means the number.
    assert parsed["agent.gamma"].values == (0.95, 0.99)
    low, inside, high = parsed["agent.learning_rate"].probes()
    assert low == 1e-4 and high == 1e-2 and 1e-4 < inside < 1e-2


def test_values_are_written_as_set_reads_them():
    assert space.override("agent.learning_rate", 1e-5) == "agent.learning_rate=1.0e-05"
    assert space.override("agent.actor_hidden_dims", (64, 64)) == \
        "agent.actor_hidden_dims=[64, 64]"
    assert space.as_config(["env.num_envs=64", "agent.learning_rate=1.0e-05"]) == \
        {"env": {"num_envs": 64}, "agent": {"learning_rate": 1e-5}}


def test_a_checked_space_passes(tmp_path):
    spec, fw = registry.get_task("cartpole"), registry.get_framework("rsl_rl")
    space.check(space.parse(SPACE), spec, fw, ["env.num_envs=64"], max_iterations=5)


@pytest.mark.parametrize("data, phrases", [
    ({"agent.learnin_rate": {"loguniform": [1e-4, 1e-2]}},
     ["unknown key 'agent.learnin_rate'", "did you mean 'agent.learning_rate'"]),
    ({"learning_rate": {"uniform": [0.1, 0.2]}}, ["'learning_rate' is not an env.* or agent.*"]),
    ({"agent.learning_rate": {"normal": [0.1, 0.2]}},
     ["'agent.learning_rate' has an unknown distribution 'normal'", "uniform, loguniform"]),
    ({"agent.learning_rate": {"loguniforn": [0.1, 0.2]}}, ["did you mean 'loguniform'"]),
    ({"agent.learning_rate": {"uniform": [0.2, 0.1]}},
     ["'agent.learning_rate'", "low 0.2 is not below its high 0.1", "[0.1, 0.2]"]),
    ({"agent.num_mini_batches": {"randint": [8, 2]}},
     ["'agent.num_mini_batches'", "randint's low 8 is above its high 2"]),
    ({"agent.num_learning_epochs": {"randint": [1, 10**30]}},
     ["'agent.num_learning_epochs'", "randint [1, 1000000000000000000000000000000] leaves the "
      "64-bit integers Ray Tune draws from"]),
    ({"agent.num_learning_epochs": {"choice": []}},
     ["'agent.num_learning_epochs': choice needs a non-empty list"]),
    ({"agent.learning_rate": {"uniform": [0.1]}}, ["uniform needs [low, high]"]),
    ({"agent.learning_rate": {"uniform": ["a", 1]}}, ["bounds must be finite numbers"]),
    ({"agent.learning_rate": {"loguniform": [0.0, 0.1]}}, ["loguniform needs a positive low"]),
    ({"agent.learning_rate": {"uniform": [-1.0, 1.0]}},
     ["'agent.learning_rate'", "bad value for 'agent.learning_rate'", "expected float"]),
    # A range over an integer key would draw fractions: refused, naming the value it drew.
    ({"agent.num_learning_epochs": {"uniform": [4, 8]}},
     ["'agent.num_learning_epochs'", "valid integer", "a value uniform [4, 8] draws",
      "use randint or choice"]),
    ({"env.episode_length_s": {"choice": [5.0, 0]}}, ["'env.episode_length_s'", "greater than 0"]),
    ({"agent.num_mini_batches": {"choice": [4, 100000]}},
     ["'agent.num_mini_batches'", "more mini-batches than samples"]),
    ({"agent.max_iterations": {"choice": [5, 10]}}, ["cannot be swept", "--iterations"]),
    ({"env.num_envs": {"choice": [64, 128]}},
     ["'env.num_envs' is both swept and fixed with --set"]),
    ({"agent.learning_rate": [1e-4, 1e-2]}, ["must be one distribution"]),
    ([1, 2], ["must map keys to distributions"]),
    ("agent.learning_rate: {uniform: [0.1, 0.2]", ["is not valid YAML"]),
])
def test_a_bad_space_is_one_line_naming_the_key(tmp_path, data, phrases):
    path = space_file(tmp_path, data)
    result = lab("sweep", *SMALL, "--space", str(path), "--samples", "2", logs=tmp_path / "l")
    assert_one_line_error(result, str(path), *phrases)
    assert not (tmp_path / "l").exists()  # nothing written


@pytest.mark.parametrize("args, phrases", [
    (["--samples", "0"], ["--samples must be a positive integer"]),
    (["--samples", "2", "--metric", "speed"], ["--metric 'speed' is not one of success, return"]),
    (["--samples", "2", "--scheduler", "pbt"], ["--scheduler 'pbt'"]),
    (["--samples", "2", "--search", "grid"], ["--search 'grid'"]),
    (["--samples", "2", "--iterations", "0"], ["--iterations must be a positive integer"]),
    (["--samples", "2", "--name", "a/b"], ["--name 'a/b' is not a plain name"]),
    (["--samples", "2", "--set", "agent.learnin_rate=1"], ["unknown key 'agent.learnin_rate'"]),
    (["--samples", "2", "--search", "optuna", "--set", "env.num_envs=64"],
     ["--search optuna draws among numbers", "'agent.actor_hidden_dims'"]),
])
def test_bad_options_are_one_line(tmp_path, args, phrases):
    data = {**SPACE, "agent.actor_hidden_dims": {"choice": [[32, 32], [64, 64]]}} \
        if "optuna" in args else SPACE
    path = space_file(tmp_path, data)
    result = lab("sweep", "--task", "cartpole", "--framework", "rsl_rl", "--space", str(path),
                 *args, logs=tmp_path / "l")
    assert_one_line_error(result, *phrases)


def test_missing_options_and_resume_conflicts_are_one_line(tmp_path):
    assert_one_line_error(lab("sweep", "--task", "cartpole", logs=tmp_path),
                          "lab sweep needs --framework, --space, --samples", "--resume DIR")
    assert_one_line_error(lab("sweep", "--resume", str(tmp_path), "--samples", "3",
                              logs=tmp_path), "--samples cannot be given with it")
    assert_one_line_error(lab("sweep", "--resume", str(tmp_path), logs=tmp_path),
                          "is not a lab sweep: it has no sweep.yaml")


def test_an_existing_sweep_is_not_overwritten(tmp_path):
    (tmp_path / "sweeps" / "mine").mkdir(parents=True)
    result = lab("sweep", *SMALL, "--space", str(space_file(tmp_path, SPACE)), "--samples", "2",
                 "--name", "mine", logs=tmp_path)
    assert_one_line_error(result, "sweep", "mine exists", "lab sweep --resume")


def test_an_address_where_nothing_answers_is_one_line_at_once(tmp_path):
    """Ray's own client retried such an address for 822 s."""
    pytest.importorskip("ray.tune")
    started = time.monotonic()
    result = lab("sweep", *SMALL, "--space", str(space_file(tmp_path, SPACE)), "--samples", "2",
                 "--address", "127.0.0.1:1", logs=tmp_path / "l")
    assert_one_line_error(result, "cannot join Ray at 127.0.0.1:1: nothing answers at "
                          "127.0.0.1:1", "check --address")
    assert time.monotonic() - started < 30
    assert not (tmp_path / "l").exists()


def made_sweep(tmp_path: Path, **changes: object) -> Path:
    """A sweep dir as `lab sweep` starts one (sweep.yaml, space.yaml), with `changes` made to
    its sweep.yaml by hand."""
    sweep_dir = tmp_path / "sweeps" / "hand"
    sweep_dir.mkdir(parents=True)
    spec = {"task": "cartpole", "framework": "rsl_rl", "space": SPACE, "samples": 4,
            "metric": "success", "scheduler": "asha", "search": "random", "fixed": [],
            "iterations": 5, "name": "hand", "logs_dir": str(tmp_path), "max_concurrent": None}
    (sweep_dir / "sweep.yaml").write_text(yaml.safe_dump({**spec, **changes}))
    (sweep_dir / "space.yaml").write_text(yaml.safe_dump(SPACE))
    return sweep_dir


@pytest.mark.parametrize("changes, phrase", [
    ({"samples": -3}, "--samples must be a positive integer, got -3"),
    ({"max_concurrent": 0}, "--max-concurrent must be a positive integer, got 0"),
    ({"samples": "x"}, "samples is 'x', not of the kind lab wrote"),
    ({"metric": "bogus"}, "--metric 'bogus' is not one of success, return"),
    ({"fixed": [3]}, "fixed is [3], not a list of KEY=VALUE strings"),
    ({"name": "../x"}, "is not a plain name"),
])
def test_a_hand_edited_sweep_yaml_is_refused_on_resume_before_any_trial(tmp_path, changes,
                                                                       phrase):
    sweep_dir = made_sweep(tmp_path, **changes)
    result = lab("sweep", "--resume", str(sweep_dir), logs=tmp_path)
    assert_one_line_error(result, f"{sweep_dir / 'sweep.yaml'} is damaged", phrase,
                          "restore it, or start a new sweep")


def test_a_sweep_run_by_another_driver_is_not_resumed_beside_it(tmp_path):
    pytest.importorskip("ray.tune")
    sweep_dir = made_sweep(tmp_path)
    with rundir.holding(sweep_dir, lambda: LabError("held")):  # as a running `lab sweep` does
        result = lab("sweep", "--resume", str(sweep_dir), logs=tmp_path)
    assert_one_line_error(result, f"sweep {sweep_dir} is being run by another lab sweep",
                          "wait for it to end")


def test_a_signing_key_that_cannot_be_made_is_one_line_before_any_trial(tmp_path):
    pytest.importorskip("ray.tune")
    (tmp_path / "not-a-dir").write_text("")
    result = CliRunner().invoke(app, ["sweep", *SMALL, "--space", str(space_file(tmp_path, SPACE)),
                                      "--samples", "2"],
                                env={"LAB_LOGS_DIR": str(tmp_path / "l"), "COLUMNS": "250",
                                     "LAB_CONFIG_DIR": str(tmp_path / "not-a-dir")})
    assert_one_line_error(result, "the key that signs sweep state", "cannot be used",
                          "LAB_CONFIG_DIR")
    assert not (tmp_path / "l").exists()


def test_without_ray_sweep_says_how_to_install_it(tmp_path, monkeypatch):
    for module in ("ray", "ray.tune"):
        monkeypatch.setitem(sys.modules, module, None)  # `import ray` fails as uninstalled
    result = lab("sweep", *SMALL, "--space", str(space_file(tmp_path, SPACE)), "--samples", "2",
                 logs=tmp_path / "l")
    assert_one_line_error(result, "needs Ray Tune, which is not installed",
                          'pip install "lab[sweep]"', 'pip install -e ".[sweep]"')
    assert not (tmp_path / "l").exists()


def test_trials_share_the_cores():
    from labcli.runs.sweep import fit_trials

    two = {"CPU": 2.0}
    fit = fit_trials(two, False, [], None)
    assert (fit.resources, fit.concurrent, fit.extra) == ({"cpu": 1}, 2, ["env.threads=1"])
    fit = fit_trials({"CPU": 16.0}, False, [], 4)
    assert (fit.resources, fit.concurrent, fit.extra) == ({"cpu": 4}, 4, ["env.threads=4"])
    fit = fit_trials(two, False, ["env.threads=2"], None)
    assert (fit.resources, fit.concurrent, fit.extra) == ({"cpu": 2}, 1, [])
    fit = fit_trials({"CPU": 16.0, "GPU": 4.0}, True, [], None)
    assert (fit.resources, fit.concurrent) == ({"cpu": 1, "gpu": 1}, 4)
    with pytest.raises(LabError, match="env.threads=4 asks more cores"):
        fit_trials(two, False, ["env.threads=4"], None)


# Real sweeps on a local Ray -------------------------------------------------------------------

def reports(sweep_dir: Path, trial_id: str) -> list[dict]:
    """What Tune received from a trial, one line per report (Tune's result.json)."""
    lines = (sweep_dir / trial_id / "result.json").read_text().splitlines()
    return [json.loads(line) for line in lines if line.strip()]


# Its first rung (iteration 1) comes before any episode has ended: every trial reports NaN
# there, which numpy's percentile warns of; the sweep's output stays lab's own.
@pytest.mark.filterwarnings("error:All-NaN slice encountered:RuntimeWarning")
def test_a_sweep_trains_lab_runs_and_its_best_yaml_retrains(tmp_path):
    pytest.importorskip("ray.tune")
    logs = tmp_path / "logs"
    path = space_file(tmp_path, SPACE)
    result = lab("sweep", *SMALL, "--space", str(path), "--samples", "4", "--iterations", "10",
                 "--name", "small", logs=logs)
    assert result.exit_code == 0, result.output
    sweep_dir = logs / "sweeps" / "small"
    assert "4 trials of sweep small, best success first" in result.stdout
    results = json.loads((sweep_dir / "results.json").read_text())
    trials = results["trials"]
    assert len(trials) == 4 and {t["state"] for t in trials} <= {"finished", "stopped"}
    metrics = [t["metric"] for t in trials]
    assert metrics == sorted(metrics, reverse=True)  # best first

    # Each trial is a lab run that `lab runs` lists, trained with what the trial drew.
    listed = json.loads(lab("runs", "--json", logs=logs).stdout)
    assert {Path(row["dir"]).name for row in listed} == \
        {Path(t["run_dir"]).name for t in trials}
    for trial in trials:
        run = rundir.Run(Path(trial["run_dir"]))
        agent, env = run.params(rundir.AGENT_PARAMS), run.params(rundir.ENV_PARAMS)
        assert env["num_envs"] == 64 and env["threads"] == 1  # fixed, and sized to one core
        for key, value in trial["params"].items():
            assert agent[key.removeprefix("agent.")] == value
        summary = run.summary()
        assert summary["checkpoint"] == f"model_{summary['iterations']}.pt"
        # Every iteration reached Tune, as the run counts them; a trial that ASHA stopped
        # ended as a clean run: checkpointed at its last iteration, state 'interrupted'.
        told = reports(sweep_dir, trial["trial_id"])
        assert [r["training_iteration"] for r in told] == \
            list(range(1, summary["iterations"] + 1))
        assert told[-1]["steps"] == summary["steps"]
        assert summary["state"] == ("finished" if trial["state"] == "finished"
                                    else "interrupted")
        assert (summary["iterations"] == 10) == (trial["state"] == "finished")

    # best.yaml: the fixed settings, the trials' length and the best trial's draw.
    best = yaml.safe_load((sweep_dir / "best.yaml").read_text())
    top = trials[0]
    assert best["env"] == {"num_envs": 64}
    assert best["agent"] == {"max_iterations": 10, **{k.removeprefix("agent."): v
                                                      for k, v in top["params"].items()}}
    trained = lab("train", "--task", "cartpole", "--framework", "rsl_rl", "--config",
                  str(sweep_dir / "best.yaml"), "--max-iterations", "2", logs=tmp_path / "again")
    assert trained.exit_code == 0, trained.output
    (again,) = rundir.find(tmp_path / "again")
    agent = again.params(rundir.AGENT_PARAMS)
    assert all(agent[k] == v for k, v in best["agent"].items() if k != "max_iterations")


def under_way(logs: Path) -> bool:
    """A trial's run has finished, and another has written a checkpoint."""
    runs = [(run, (run.summary() or {}).get("state")) for run in rundir.find(logs)]
    return any(state == "finished" for _, state in runs) and any(
        state == "running" and list(run.dir.glob("model_*.pt")) for run, state in runs)


def test_an_interrupted_sweep_resumes_its_trials_from_their_checkpoints(tmp_path):
    """Ctrl-C (SIGINT to the process group, as a terminal sends it) once a trial has ended:
    the running trials end as interrupted lab runs, and --resume finishes every trial, the
    interrupted ones going on from their runs' checkpoints."""
    pytest.importorskip("ray.tune")
    logs = tmp_path / "logs"
    path = space_file(tmp_path, SPACE)
    # One trial at a time: the first has finished, the second is cut, the third never starts.
    args = ["sweep", "--task", "cartpole", "--framework", "rsl_rl", "--set", "env.num_envs=64",
            "--set", "agent.save_interval=2", "--max-concurrent", "1", "--space", str(path),
            "--samples", "3", "--iterations", "12", "--scheduler", "none", "--name", "cut"]
    proc = subprocess.Popen([sys.executable, "-m", "labcli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True,
                            env={**os.environ, "LAB_LOGS_DIR": str(logs), "COLUMNS": "250"})
    sweep_dir = logs / "sweeps" / "cut"
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and not under_way(logs):
            time.sleep(0.5)
        os.killpg(proc.pid, signal.SIGINT)
        output, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, output
    assert f"lab sweep --resume {sweep_dir}" in output
    before = {t["trial_id"]: t for t in
              json.loads((sweep_dir / "results.json").read_text())["trials"]}
    assert sorted(t["state"] for t in before.values()) == ["finished", "interrupted", "pending"]
    cut = [t for t in before.values() if t["state"] == "interrupted"]
    for trial in cut:  # stopped as Ctrl-C stops `lab train`: checkpointed, resumable
        summary = rundir.Run(Path(trial["run_dir"])).summary()
        assert summary["checkpoint"] == f"model_{summary['iterations']}.pt"

    # Its Ray Tune state is signed with the user's key: a copy changed in any way, unsigned,
    # or signed with another key is refused before Ray unpickles any of it.
    assert (sweep_dir / "state.sig").is_file()
    refused = ["not Ray Tune state your lab sweep signed", "carries no signature of yours",
               "not Ray Tune state your lab sweep signed"]
    for case, phrase in zip(("changed", "unsigned", "other key"), refused, strict=True):
        copy = tmp_path / case
        shutil.copytree(sweep_dir, copy)
        if case == "changed":
            with open(copy / "tuner.pkl", "ab") as out:
                out.write(b"\0")
        elif case == "unsigned":
            (copy / "state.sig").unlink()
        env = {"LAB_CONFIG_DIR": str(tmp_path / "other")} if case == "other key" else {}
        result = CliRunner().invoke(app, ["sweep", "--resume", str(copy)],
                                    env={"LAB_LOGS_DIR": str(logs), "COLUMNS": "250", **env})
        assert_one_line_error(result, phrase, "start this one again under a new --name")

    resumed = lab("sweep", "--resume", str(sweep_dir), logs=logs)
    assert resumed.exit_code == 0, resumed.output
    after = {t["trial_id"]: t for t in
             json.loads((sweep_dir / "results.json").read_text())["trials"]}
    assert len(after) == 3 and {t["state"] for t in after.values()} == {"finished"}
    for trial in cut:
        run = rundir.Run(Path(after[trial["trial_id"]]["run_dir"]))
        assert run.dir == Path(trial["run_dir"])  # the same run, gone on
        assert len(run.manifest()["sessions"]) == 2
        told = reports(sweep_dir, trial["trial_id"])
        assert told[-1]["training_iteration"] == run.summary()["iterations"] == 12
    assert math.isfinite(after[next(iter(after))]["metric"])


def test_an_optuna_sweep_runs_its_trials_under_an_address_space_limit(tmp_path):
    """--search optuna: Optuna's sampler draws each trial within the space. Under `ulimit -v
    8G` (each process's address space), where Ray's default object store hung the sweep."""
    pytest.importorskip("optuna")
    pytest.importorskip("ray.tune")
    resource = pytest.importorskip("resource")
    logs = tmp_path / "logs"
    limit = 8 * 2**30
    result = subprocess.run(
        [sys.executable, "-m", "labcli", "sweep", *SMALL, "--space",
         str(space_file(tmp_path, SPACE)), "--samples", "2", "--iterations", "3", "--search",
         "optuna", "--scheduler", "none", "--name", "tpe"], capture_output=True, text=True,
        timeout=300, env={**os.environ, "LAB_LOGS_DIR": str(logs), "COLUMNS": "250"},
        preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_AS, (limit, limit)))
    assert result.returncode == 0, result.stdout + result.stderr
    trials = json.loads((logs / "sweeps" / "tpe" / "results.json").read_text())["trials"]
    assert [t["state"] for t in trials] == ["finished", "finished"]
    for trial in trials:
        params = trial["params"]
        assert 1e-4 <= params["agent.learning_rate"] <= 1e-2
        assert 0.0 <= params["agent.entropy_coef"] <= 0.01
        assert params["agent.num_learning_epochs"] in (4, 8)
