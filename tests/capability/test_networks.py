"""The capability CNN's architecture (paper 000 Fig. 4)."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from qz_drake.capability.networks import CapabilityNet, NetworkConfig, _max_pool_2x2, extra_inputs  # noqa: E402

torch.set_num_threads(1)


def test_layers_follow_the_paper():
    net = CapabilityNet("orthogonal")
    for conv in (net.conv1, net.conv2):
        assert conv.out_channels == 4 and conv.kernel_size == (5, 5) and conv.padding == (2, 2)
    assert net.conv1.in_channels == 1 and net.conv2.in_channels == 4
    # 20 -> pool -> 10 -> pool -> 5: four 5 x 5 maps flattened into the patch's dense layer.
    assert net.patch_dense.in_features == 4 * 5 * 5
    assert net.dense1.in_features == NetworkConfig().patch_features + 18
    assert net.dense2.out_features == 1
    assert CapabilityNet("turn").dense1.in_features == NetworkConfig().patch_features + 19
    assert (extra_inputs("diagonal"), extra_inputs("turn")) == (18, 19)


def test_probabilities_batched_and_in_range():
    torch.manual_seed(0)
    net = CapabilityNet("turn").eval()
    patch, extra = torch.randn(7, 20, 20) * 0.1, torch.randn(7, 19)
    p = net.probability(patch, extra)
    assert p.shape == (7,) and bool(((p > 0) & (p < 1)).all())
    # Batched evaluation equals one query at a time.
    one = torch.stack([net.probability(patch[i:i + 1], extra[i:i + 1])[0] for i in range(7)])
    assert torch.allclose(p, one, atol=1e-6)


def test_fast_pooling_is_max_pool():
    x = torch.randn(3, 4, 20, 20)
    assert torch.equal(_max_pool_2x2(x), torch.nn.functional.max_pool2d(x, 2))


def test_input_scaling_is_a_saved_buffer():
    net = CapabilityNet("orthogonal")
    patches, extra = torch.randn(50, 20, 20) * 0.2 + 0.1, torch.randn(50, 18) * 0.3
    net.set_input_scaling(patches, extra)
    state = net.state_dict()
    assert float(state["patch_mean"]) == pytest.approx(float(patches.mean()))
    assert np.allclose(state["extra_scale"].numpy(), extra.std(dim=0).numpy(), rtol=1e-5)
