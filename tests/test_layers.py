"""The house keeps its floors (docs/architecture.md): commands -> runs -> plugins -> envs -> refs
-> errors, each importing only what lies below it, and the built-in plugins only the plugin API.
The contracts live in pyproject.toml; import-linter checks them over every import, including
those inside functions."""

from __future__ import annotations

from pathlib import Path

import pytest
from importlinter.cli import lint_imports

import labcli

ROOT = Path(__file__).parents[1]


def test_import_contracts_hold():
    assert lint_imports(config_filename=str(ROOT / "pyproject.toml"), no_cache=True) == 0


def test_every_part_of_labcli_is_on_a_floor():
    """A new subpackage or module must be placed in the layers, or the contract says nothing
    about it."""
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    (layers,) = [c["layers"] for c in config["contracts"] if c["type"] == "layers"]
    placed = {name.strip() for layer in layers for name in layer.split("|")}
    package = Path(labcli.__file__).parent
    parts = {f"labcli.{path.stem}" for path in package.iterdir()
             if path.suffix == ".py" and not path.stem.startswith("__")
             or (path / "__init__.py").is_file()}
    assert parts == placed
