"""Videos: the env-stage 'video' wrapper writes mp4s of env 0 that decode, and that move."""

from __future__ import annotations

import io
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import pytest
from conftest import needs_menagerie
from rich.console import Console

from labcli.envs.render import gl
from labcli.envs.render.scene import HEIGHT, WIDTH
from labcli.envs.wrappers import Step, validate
from labcli.errors import LabError
from labcli.plugins import registry
from labcli.runs import training, video
from labcli.runs.play import Agent, Show, play, sanity

# Cartpole steps 0.02 s: 0.3 s episodes end after 15 steps.
SMALL = ["agent.n_steps=8", "agent.batch_size=16", "agent.n_epochs=1", "env.episode_length_s=0.3"]


def frames(path: Path) -> list[np.ndarray]:
    return imageio.mimread(path, memtest=False)


def assert_moving_video(path: Path, count: int) -> None:
    """The file decodes to `count` frames of the renderer's size, not blank, that change over
    time: the cart and pole move, so some pixels change by much between first and last."""
    got = frames(path)
    assert len(got) == count, f"{path.name}: {len(got)} frames"
    first, last = (f.astype(np.int16) for f in (got[0], got[-1]))
    assert first.shape == (HEIGHT, WIDTH, 3)
    assert first.std() > 10, "a blank frame"
    changed = (np.abs(last - first).max(axis=2) > 40).sum()
    assert changed > 100, f"only {changed} pixels changed between the first and last frame"


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> training.TrainOutcome:
    """A cartpole run of 3 SB3 iterations of 8 steps with 15-step episodes, recording 10 steps
    every 12."""
    return training.train(
        "cartpole", "sb3", num_envs=4, max_iterations=3, overrides=SMALL,
        logs_dir=tmp_path_factory.mktemp("logs"), console=Console(file=io.StringIO()),
        command=["lab", "test"], video=video.VideoSettings(length=10, interval=12))


def test_headless_default_is_egl():
    if not gl.has_display():
        assert gl.backend() == gl.HEADLESS[0]


def test_train_video_records_env_0_at_the_interval(trained):
    folder = trained.run.dir / "videos" / "train"
    assert sorted(p.name for p in folder.iterdir()) == ["step-0.mp4", "step-12.mp4"]
    for path in folder.iterdir():
        assert_moving_video(path, 10)


def test_play_video_goes_to_the_run_dir_and_is_flushed_when_play_ends(trained):
    # 2 episodes end after 15 steps: the 50-step recording is cut short, and still written.
    _, eps = play(episodes=2, run_dir=trained.run.dir, show=Show(video.VideoSettings(50, None)))
    (path,) = eps.videos
    assert path.parent.parent == trained.run.dir / "videos" / "play" and path.name == "step-0.mp4"
    assert eps.lengths == [15, 15] and len(frames(path)) == 15
    # A second play keeps the first one's video.
    _, again = play(episodes=1, run_dir=trained.run.dir, show=Show(video.VideoSettings(5, None)))
    (second,) = again.videos
    assert second.parent != path.parent and len(frames(path)) == 15 and len(frames(second)) == 5


def test_sanity_agent_video_outside_any_run(tmp_path):
    _, eps = sanity("cartpole", Agent.random, episodes=1, num_envs=1, logs_dir=tmp_path,
                    show=Show(video.VideoSettings(20, None)))
    (path,) = eps.videos
    assert path.is_relative_to(tmp_path / "sanity" / "cartpole")
    assert_moving_video(path, 20)


def test_the_video_wrapper_must_come_before_the_adapter():
    adapter = registry.get_wrapper("sb3.adapter")
    validate([video.VideoSettings().step(Path("v")), Step(adapter)], "sb3")
    with pytest.raises(LabError, match="wrapper 'video' .env stage. comes after 'sb3.adapter'"):
        validate([Step(adapter), video.VideoSettings().step(Path("v"))], "sb3")
    assert registry.get_wrapper("video") is video.VIDEO  # registered like any plugin's


@pytest.mark.parametrize("length, interval", [(1, 10), (10, 0)])
def test_bad_video_settings(length, interval):
    with pytest.raises(LabError, match="--video-"):
        video.VideoSettings(length, interval)


def test_without_imageio_ffmpeg_a_video_is_refused_before_any_work(monkeypatch, tmp_path):
    """imageio would otherwise write the .mp4 with another format's writer and fail only when
    the first video ends (a traceback, after the training or play it recorded)."""
    import importlib.util

    from labcli.envs.render.video import VideoRecorder
    from labcli.gym import make_env

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "imageio_ffmpeg" else real(name, *a))
    env = make_env("cartpole", num_envs=2)
    with pytest.raises(LabError) as err:
        VideoRecorder(env, tmp_path)
    env.close()
    assert err.value.message == "writing mp4 videos needs imageio-ffmpeg, which is not installed"
    assert not list(tmp_path.iterdir())


@needs_menagerie("unitree_go2")
def test_a_robot_without_a_camera_of_its_own_is_followed_not_left_behind():
    """Menagerie's Go2 has no camera: MuJoCo's free camera would stay where the robot started
    while it walks out of the video."""
    import mujoco
    from lab_locomotion import go2

    from labcli.envs import models
    from labcli.envs.render.scene import SceneRenderer

    model = models.load_spec(go2.MODEL).compile()
    assert model.ncam == 0
    camera = SceneRenderer(model).camera
    assert camera.type == mujoco.mjtCamera.mjCAMERA_TRACKING
    assert camera.trackbodyid == model.body("base").id
