"""Out-of-tree packages really installed: built with pip into a private --target dir, and put on
sys.path for a test, then forgotten."""

from __future__ import annotations

import importlib
import shutil
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from labcli.plugins import registry


def pip_install(package: Path, root: Path) -> Path:
    """`package` pip-installed (not editable) under `root`; returns its site dir. Built from a
    copy, as an in-tree build would leave build/ and *.egg-info in the repo; offline, with the
    setuptools already installed."""
    source, site = root / "source", root / "site"
    shutil.copytree(package, source,
                    ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    result = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation",
         "--no-index", "--disable-pip-version-check", "--quiet", "--target", str(site),
         str(source)],
        capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    return site


@contextmanager
def on_sys_path(site: Path) -> Iterator[None]:
    """Makes the distributions in `site` installed for the duration, then forgets every plugin,
    module and registry entry they brought, so that later tests see the stock set."""
    plugins_before = {name for name, _ in registry.pm.list_name_plugin()}
    modules_before = set(sys.modules)
    sys.path.insert(0, str(site))
    importlib.invalidate_caches()
    try:
        yield
    finally:
        sys.path.remove(str(site))
        for name, _ in registry.pm.list_name_plugin():
            if name not in plugins_before:
                registry.pm.unregister(name=name)
        for name in set(sys.modules) - modules_before:
            if str(site) in (getattr(sys.modules[name], "__file__", None) or ""):
                del sys.modules[name]
        importlib.invalidate_caches()
        registry.reload()
