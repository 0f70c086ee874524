"""lab's Gaussian action distribution for RSL-RL: RSL-RL's own in everything but how samples
are drawn, and drawing them does not wait for the GPU."""

from __future__ import annotations

import pytest
import torch
from conftest import no_device_waits
from lab_rsl_rl.distribution import GaussianDistribution
from rsl_rl.modules import GaussianDistribution as RslRlGaussian

DEVICES = ["cpu", pytest.param("cuda", marks=[pytest.mark.gpu, pytest.mark.skipif(
    not torch.cuda.is_available(), reason="needs a CUDA GPU")])]


def pair(device: str, std_type: str = "scalar") -> tuple[RslRlGaussian, GaussianDistribution]:
    torch.manual_seed(0)
    theirs = RslRlGaussian(3, init_std=0.5, std_type=std_type).to(device)
    ours = GaussianDistribution(3, init_std=0.5, std_type=std_type).to(device)
    ours.load_state_dict(theirs.state_dict())
    with torch.no_grad():
        for dist in (theirs, ours):
            next(dist.parameters()).copy_(
                torch.log(torch.tensor([0.2, 1.0, 3.0])) if std_type == "log"
                else torch.tensor([0.2, 1.0, 3.0]))
    return theirs, ours


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("std_type", ["scalar", "log"])
def test_samples_follow_the_same_gaussian(device, std_type):
    theirs, ours = pair(device, std_type)
    mean = torch.tensor([-1.0, 0.0, 2.0], device=device).expand(200_000, 3)
    for dist in (theirs, ours):
        dist.update(mean)
    samples = ours.sample()
    assert samples.shape == (200_000, 3) and not samples.requires_grad
    std = torch.tensor([0.2, 1.0, 3.0], device=device)
    # 200,000 draws: the mean's standard error is std / 447, the std's about std / 632.
    torch.testing.assert_close(samples.mean(0), mean[0], atol=4 * 3.0 / 447, rtol=0)
    torch.testing.assert_close(samples.std(0), std, rtol=4 / 632, atol=0)
    # Everything but sampling is RSL-RL's: log-probabilities, entropy, parameters, export.
    torch.testing.assert_close(ours.log_prob(samples), theirs.log_prob(samples))
    torch.testing.assert_close(ours.entropy, theirs.entropy)
    torch.testing.assert_close(ours.std, theirs.std)
    x = torch.randn(5, 3, device=device)
    torch.testing.assert_close(ours.as_deterministic_output_module()(x), x)


@pytest.mark.parametrize("device", DEVICES)
def test_sampling_does_not_wait_for_the_gpu(device):
    theirs, ours = pair(device)
    mean = torch.zeros(4096, 3, device=device)
    for dist in (theirs, ours):
        dist.update(mean)
    with no_device_waits(device):
        with pytest.raises(RuntimeError, match="synchroniz"):
            theirs.sample()  # RSL-RL's torch.normal checks its std on the host
        ours.sample()
