"""OnlineProDeb re-implementation: identity at start, shared grayscale nets per channel, trainable."""

import pytest
import torch

from edofproj.compensation.onlineprodeb import ONLINEPRODEB_PRESETS, OnlineProDebNet
from edofproj.errors import EdofprojError
from edofproj.imaging.projection import project


def images(*shape, seed=0):
    return torch.rand(*shape, generator=torch.Generator().manual_seed(seed))


def perturbed_net(seed: int = 0) -> OnlineProDebNet:
    """The fast preset with its zero-initialized tail randomized, so the output is not the identity."""
    torch.manual_seed(seed)
    net = OnlineProDebNet.from_preset("fast").eval()
    torch.nn.init.normal_(net.generator.tail.weight, std=0.2)
    return net


@pytest.mark.parametrize("shape", [(1, 3, 32, 32), (2, 3, 37, 45), (1, 3, 5, 9)])
def test_untrained_network_is_the_identity_at_any_size(shape):
    net = OnlineProDebNet.from_preset("fast")
    target, captured = images(*shape), images(*shape, seed=1)
    assert torch.equal(net(target, captured), target)


def test_channels_share_one_grayscale_network():
    net = perturbed_net()
    target, captured = images(2, 3, 24, 40), images(2, 3, 24, 40, seed=1)
    with torch.no_grad():
        out = net(target, captured)
        permutation = [2, 0, 1]
        permuted = net(target[:, permutation], captured[:, permutation])
        changed = captured.clone()
        changed[:, 1] = 1.0 - changed[:, 1]
        out_changed = net(target, changed)
    assert not torch.allclose(out, target, atol=1e-3)  # the captured image matters
    assert torch.allclose(permuted, out[:, permutation], atol=1e-6)
    assert torch.allclose(out_changed[:, [0, 2]], out[:, [0, 2]], atol=1e-6)
    assert not torch.allclose(out_changed[:, 1], out[:, 1], atol=1e-3)


def test_training_updates_extractors_and_generator_and_lowers_the_loss():
    torch.manual_seed(0)
    net = OnlineProDebNet.from_preset("fast")
    psf = torch.ones(1, 3, 5, 5) / 25 * 0.95
    target = images(1, 3, 16, 16)
    captured = project(target, psf)
    before = {name: p.detach().clone() for name, p in net.named_parameters()}
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-3)
    losses = []
    for _ in range(5):
        loss = ((project(net(target, captured), psf) - target) ** 2).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert losses[-1] < losses[0]
    for part in ("defocus_net", "luminance_net", "generator"):
        moved = [not torch.equal(p, before[n]) for n, p in net.named_parameters() if n.startswith(part)]
        assert all(moved), part


def test_presets_and_errors():
    assert set(ONLINEPRODEB_PRESETS) >= {"default", "fast"}
    default = sum(p.numel() for p in OnlineProDebNet().parameters())
    assert default == sum(p.numel() for p in OnlineProDebNet.from_preset("default").parameters())
    with pytest.raises(EdofprojError, match="preset"):
        OnlineProDebNet.from_preset("huge")
    with pytest.raises(EdofprojError, match="equal shape"):
        OnlineProDebNet.from_preset("fast")(images(1, 3, 8, 8), images(1, 3, 8, 9))
