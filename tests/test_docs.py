"""The documentation site (mkdocs.yml: docs/, README.md as its home page, the Python API from
docstrings) builds in strict mode: no warning, every internal link and anchor found."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_the_site_builds_without_a_warning(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-d", str(tmp_path / "site")],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert result.returncode == 0, result.stderr
    assert "WARNING" not in result.stderr, result.stderr
    home = (tmp_path / "site" / "index.html").read_text()
    assert 'href="guide/"' in home  # README's links into docs/, as the site's
    # The API page holds the docstrings themselves, not only their names.
    page = (tmp_path / "site" / "api" / "index.html").read_text()
    api = " ".join(re.sub(r"<[^>]+>", "", page).split())
    assert "The batched env of task" in api and "as lab train builds it" in api


def test_the_term_reference_is_the_configs_own():
    """docs/terms.md is what `python -m labcli.envs.mdp.reference` writes from the configs:
    every term with code of its own, each with a description and its settings."""
    from labcli.envs.mdp import config as c
    from labcli.envs.mdp import reference

    text = reference.markdown()
    assert (ROOT / "docs" / "terms.md").read_text() == text, (
        "docs/terms.md is stale: python -m labcli.envs.mdp.reference > docs/terms.md")
    for cls in (c.TrackLinVelXYExp, c.IllegalContact, c.RandomizeActuatorGains, c.HeightScan):
        assert f"\n### {cls.__name__}\n" in text
    assert "(no description)" not in text
    # A setting's type, bounds and default, and its description where it has one.
    assert "| `margin` | float (≥ 0) | `0.3` | m inside the edge |" in text
    kinds = [line for line in text.splitlines() if line.startswith("## ")]
    assert kinds == ["## Actions", "## Commands", "## Observations", "## Rewards",
                     "## Terminations", "## Events", "## Curriculum", "## Success"]
