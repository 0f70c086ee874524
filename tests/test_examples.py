"""examples/: each runs as a user runs it, for a few iterations."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

EXAMPLES = Path(__file__).parents[1] / "examples"


def test_cleanrl_style_ppo_runs_on_a_lab_env(tmp_path):
    result = subprocess.run(
        [sys.executable, str(EXAMPLES / "cleanrl_ppo.py"), "--num-envs", "16", "--num-steps",
         "16", "--total-timesteps", "768", "--num-minibatches", "4", "--update-epochs", "2",
         "--set", "episode_length_s=0.2"],
        capture_output=True, text=True, cwd=tmp_path, env={**os.environ, "PYTHONUNBUFFERED": "1"},
        timeout=300)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert [line.split()[1] for line in lines] == ["1/3", "2/3", "3/3"], result.stdout
    # 0.2 s episodes are 10 steps: every 16-step rollout ends some.
    for line in lines:
        assert re.search(r"episodic_return=[\d.-]+ success=[\d.]+ SPS=\d+$", line), line
