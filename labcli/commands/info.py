"""`lab info`."""

from __future__ import annotations

from labcli import __version__
from labcli.commands.common import out, table


def info() -> None:
    """Print versions of lab, MuJoCo, torch and the frameworks, the GL backend, and whether
    rendering, CUDA and MuJoCo Warp work here.

    Example: lab info
    """
    from labcli.runs import info as infos

    rows = table("", "", title=f"lab {__version__}")
    for name, value in infos.collect().items():
        rows.add_row(name, value)
    out().print(rows)
