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
    # Three outcomes (the default): walked, no plan, executed and failed; the factored two
    # outputs or the paper's one success output on request.
    assert net.dense2.out_features == 3
    assert CapabilityNet("orthogonal", NetworkConfig(outcomes=False)).dense2.out_features == 2
    assert CapabilityNet("orthogonal", NetworkConfig(outcomes=False, factored=False)).dense2.out_features == 1
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


def test_the_second_output_is_the_chance_that_the_blc_plans_the_move():
    torch.manual_seed(1)
    net = CapabilityNet("diagonal", NetworkConfig(outcomes=False)).eval()
    patch, extra = torch.randn(5, 20, 20) * 0.1, torch.randn(5, 18)
    logits = net(patch, extra)
    assert logits.shape == (5, 2)
    assert torch.allclose(net.probability(patch, extra), torch.sigmoid(logits[:, 0]))
    assert torch.allclose(net.plan_probability(patch, extra), torch.sigmoid(logits[:, 1]))
    single = CapabilityNet("diagonal", NetworkConfig(outcomes=False, factored=False)).eval()
    assert single(patch, extra).shape == (5,) and single.plan_probability(patch, extra) is None


def test_the_two_output_loss_trains_each_output_on_its_label():
    """Success on the trial's success, the plan output on whether the BLC planned it."""
    from qz_drake.capability.training import _loss

    for name in ("mse", "bce"):
        logits = torch.zeros(2, 2, requires_grad=True)
        labels = torch.tensor([[1.0, 0.0], [0.0, 0.0]])  # (planned, success): walk failed; not planned
        _loss(name, logits, labels).backward()
        assert logits.grad[0, 0] > 0.0 and logits.grad[1, 0] > 0.0  # success pushed down on both
        assert logits.grad[0, 1] < 0.0 and logits.grad[1, 1] > 0.0  # plan up where planned, else down
        single = torch.zeros(2, requires_grad=True)
        _loss(name, single, labels).backward()
        assert single.grad[0] > 0.0 and single.grad[1] > 0.0


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


def test_the_three_outcome_loss_pushes_up_the_outcome_that_happened():
    from qz_drake.capability.training import _loss

    # (planned, success): walked; not planned; executed and failed.
    labels = torch.tensor([[1.0, 1.0], [0.0, 0.0], [1.0, 0.0]])
    for name in ("mse", "bce"):
        logits = torch.zeros(3, 3, requires_grad=True)
        _loss(name, logits, labels).backward()
        for row, outcome in enumerate((0, 1, 2)):
            assert logits.grad[row, outcome] < 0.0  # raised
            assert all(logits.grad[row, o] > 0.0 for o in range(3) if o != outcome)


def test_an_ensemble_answers_with_its_members_mean_and_their_spread():
    from qz_drake.capability.networks import CapabilityEnsemble

    torch.manual_seed(3)
    members = [CapabilityNet("turn").eval() for _ in range(4)]
    ensemble = CapabilityEnsemble(members).eval()
    patch, extra = torch.randn(6, 20, 20) * 0.1, torch.randn(6, 19)
    each = torch.stack([m.probability(patch, extra) for m in members])
    assert torch.allclose(ensemble.probability(patch, extra), each.mean(0), atol=1e-6)
    assert torch.allclose(ensemble.spread(patch, extra), each.std(0, unbiased=False), atol=1e-6)
    assert bool((ensemble.spread(patch, extra) > 0).all())  # members from other seeds disagree
    outcomes = ensemble.outcome_probabilities(patch, extra)
    assert torch.allclose(outcomes.sum(1), torch.ones(6), atol=1e-5)
    assert torch.allclose(ensemble.plan_probability(patch, extra), outcomes[:, 0] + outcomes[:, 2], atol=1e-6)
    assert torch.allclose(ensemble.failure_probability(patch, extra), outcomes[:, 2], atol=1e-6)
    # One member is a network alone: no disagreement.
    assert torch.equal(CapabilityEnsemble(members[:1]).spread(patch, extra), torch.zeros(6))
    with pytest.raises(ValueError, match="share"):
        CapabilityEnsemble([members[0], CapabilityNet("orthogonal")])
