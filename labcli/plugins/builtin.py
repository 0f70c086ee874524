"""What lab itself registers, through the same hooks and entry-point group as any plugin: the
`video` env-stage wrapper."""

from labcli.envs.wrappers import Stage, WrapperSpec
from labcli.plugins.hookspecs import hookimpl

VIDEO = WrapperSpec("video", Stage.ENV, "labcli.envs.render.video:VideoRecorder",
                    description="mp4 of env 0 through MuJoCo's offscreen renderer")


@hookimpl
def register_wrappers(register):
    register(VIDEO)
