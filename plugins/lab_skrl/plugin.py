"""Registers skrl through the same hooks a third-party framework plugin would use."""

from lab_skrl.framework import SkrlFramework
from labcli.hookspecs import hookimpl

FRAMEWORK = SkrlFramework()


@hookimpl
def register_frameworks(register):
    register(FRAMEWORK)


@hookimpl
def register_wrappers(register):
    for spec in FRAMEWORK.wrappers():
        register(spec)
