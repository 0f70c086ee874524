"""Registers RSL-RL through the same hooks a third-party framework plugin would use."""

from lab_rsl_rl.framework import RslRlFramework
from labcli.hookspecs import hookimpl

FRAMEWORK = RslRlFramework()


@hookimpl
def register_frameworks(register):
    register(FRAMEWORK)


@hookimpl
def register_wrappers(register):
    for spec in FRAMEWORK.wrappers():
        register(spec)
