"""agent.tf32: CUDA's float32 matrix products in TF32 while a run trains (as mjlab trains),
torch's process-wide settings put back when it ends."""

import pytest
import torch
import yaml
from conftest import needs_menagerie, needs_warp
from rich.console import Console

from labcli.envs.mdp.math import QUAT_OUTER_TO_ROTATION
from labcli.gym import make_env
from labcli.plugins import registry
from labcli.runs import config, precision
from labcli.runs.training import train


def _settings() -> tuple:
    matmul, cudnn = torch.backends.cuda.matmul, torch.backends.cudnn
    if hasattr(matmul, "fp32_precision"):
        return matmul.fp32_precision, cudnn.fp32_precision
    return matmul.allow_tf32, cudnn.allow_tf32


def _tf32() -> bool:
    return _settings() in {("tf32", "tf32"), (True, True)}


def test_tf32_holds_within_the_block_and_torch_s_settings_come_back_after_an_error():
    before = _settings()
    with precision.tf32(True):
        assert _tf32()
        with precision.tf32(False):
            assert not _tf32()
        assert _tf32()
    with pytest.raises(KeyError), precision.tf32(True):
        raise KeyError("a run that failed")
    assert _settings() == before


def test_a_run_trains_in_full_float32_by_default_and_a_resume_may_change_that(tmp_path):
    seen: list[bool] = []

    def tell(iteration, steps, figures):
        seen.append(_tf32())
        return False

    before = _settings()
    first = train("cartpole", "rsl_rl", num_envs=8, max_iterations=2, logs_dir=tmp_path,
                  on_iteration=tell, console=Console(quiet=True))
    assert seen == [False, False] and _settings() == before
    params = first.run.dir / "params" / "agent.yaml"
    assert yaml.safe_load(params.read_text())["tf32"] is False
    seen.clear()
    train("cartpole", "rsl_rl", max_iterations=3, logs_dir=tmp_path,
          checkpoint=str(first.run.dir), overrides=["agent.tf32=true"], on_iteration=tell,
          console=Console(quiet=True))
    assert seen == [True] and _settings() == before
    assert yaml.safe_load(params.read_text())["tf32"] is True


@pytest.mark.parametrize("framework", ["rsl_rl", "skrl", "sb3", "rl_games"])
def test_only_g1_flat_s_gpu_defaults_train_in_tf32(framework):
    """Measured there (docs/benchmarks.md); panda-lift learnt less in TF32 and stays float32."""
    fw = registry.get_framework(framework)
    for task, gpu_tf32 in (("g1-flat", True), ("g1-rough", False), ("panda-lift", False),
                           ("go1-flat", False)):
        spec = registry.get_task(task)
        assert config.resolve(spec, fw, gpu_scale=True)[1].tf32 is gpu_tf32, task
        assert config.resolve(spec, fw)[1].tf32 is False, task


def _matmul_error() -> float:
    """The relative error of a float32 matrix product on the GPU against float64's."""
    gen = torch.Generator("cuda").manual_seed(0)
    a, b = (torch.randn(512, 512, device="cuda", generator=gen) for _ in range(2))
    exact = a.double() @ b.double()
    return float((a @ b - exact).norm() / exact.norm())


@pytest.mark.gpu
@needs_warp()
def test_on_a_gpu_a_tf32_run_s_products_lose_tf32_s_digits_and_training_goes_on(tmp_path):
    """TF32 keeps 10 bits of the mantissa: a product's relative error grows from float32's
    ~1e-7 to ~1e-4 inside a tf32 run (on an Ampere or later GPU), and the env's and update's
    CUDA graphs run under it."""
    if torch.cuda.get_device_capability()[0] < 8:
        pytest.skip("TF32 needs an Ampere or later GPU")
    errors: list[float] = []

    def tell(iteration, steps, figures):
        errors.append(_matmul_error())
        return False

    outcome = train("cartpole", "rsl_rl", backend="warp", num_envs=256, max_iterations=3,
                    logs_dir=tmp_path, overrides=["agent.tf32=true"], on_iteration=tell,
                    console=Console(quiet=True))
    assert len(errors) == 3 and min(errors) > 5e-5
    assert _matmul_error() < 1e-5
    assert outcome.summary["iterations"] == 3


@pytest.mark.gpu
@needs_warp()
@needs_menagerie("unitree_go1")
def test_on_a_gpu_the_env_s_rotations_keep_float32_s_digits_in_a_tf32_run():
    """The env's values do not follow the learner's precision: its robot's rotation, made in
    eager steps and in the step's CUDA graph under TF32, is float32's (TF32: ~1e-3 off)."""
    if torch.cuda.get_device_capability()[0] < 8:
        pytest.skip("TF32 needs an Ampere or later GPU")
    env = make_env("go1-flat", num_envs=64, backend="warp", seed=0)
    env.reset(seed=0)
    gen = torch.Generator("cuda").manual_seed(0)
    to_r = torch.tensor(QUAT_OUTER_TO_ROTATION, dtype=torch.float64, device="cuda")
    with precision.tf32(True):
        for _ in range(6):  # three eager steps, the capture, replays
            env.step(torch.rand(64, 12, device="cuda", generator=gen) * 2 - 1)
            robot = env.task.robot
            q = robot.root_quat.double()
            exact = ((q[:, :, None] * q[:, None, :]).view(64, 16) @ to_r).view(64, 3, 3)
            assert (robot.rotation.double() - exact).abs().max() < 1e-6
    env.close()
