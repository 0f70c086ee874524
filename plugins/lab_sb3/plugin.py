"""Registers SB3 through the same hooks a third-party framework plugin would use."""

from lab_sb3.framework import Sb3Framework
from labcli.hookspecs import hookimpl

FRAMEWORK = Sb3Framework()


@hookimpl
def register_frameworks(register):
    register(FRAMEWORK)


@hookimpl
def register_wrappers(register):
    for spec in FRAMEWORK.wrappers():
        register(spec)
