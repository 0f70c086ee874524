"""The hooks a `lab` plugin can implement. Each calls `register(...)` once per thing it provides."""

from pluggy import HookimplMarker, HookspecMarker

hookspec = HookspecMarker("lab")
hookimpl = HookimplMarker("lab")


@hookspec
def register_tasks(register):
    """Register tasks: call register(TaskSpec(...)) for each."""


@hookspec
def register_frameworks(register):
    """Register learning frameworks: call register(FrameworkSpec(...)) for each."""


@hookspec
def register_wrappers(register):
    """Register env or framework wrappers: call register(WrapperSpec(...)) for each."""
