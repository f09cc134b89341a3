"""Networks: attention modules start as the identity (gamma = 0), shapes, IDM weight sharing."""
import contextlib

import pytest
import torch

from ifo.nets import (FeatureAttention, GatedResidual, ImageEncoder, InverseDynamics, MLP, Policy, SelfAttention2d,
                      feature_attention_map)


def test_sagan_attention_is_the_identity_until_gamma_moves():
    torch.manual_seed(0)
    att = SelfAttention2d(16)
    x = torch.randn(2, 16, 8, 8)
    assert att.gamma.item() == 0
    torch.testing.assert_close(att(x), x)
    with torch.no_grad():
        att.gamma.fill_(0.5)
    y = att(x)
    assert y.shape == x.shape and not torch.allclose(y, x)


def test_sagan_attention_mixes_positions():
    """Eqs 5.6-5.7: the softmax runs over positions, so a change at one position reaches the others."""
    torch.manual_seed(0)
    att = SelfAttention2d(8)
    with torch.no_grad():
        att.gamma.fill_(1.0)
    x = torch.randn(1, 8, 4, 4)
    x2 = x.clone()
    x2[0, :, 0, 0] += 5.0
    changed = (att(x2) - att(x)).abs().sum(1)[0]
    assert changed[3, 3] > 1e-4  # a far position felt the change


@pytest.mark.parametrize("module", [GatedResidual(6), FeatureAttention(6)])
def test_vector_attention_starts_as_the_identity(module):
    x = torch.randn(5, 6)
    torch.testing.assert_close(module(x), x)


def test_feature_attention_weights_are_a_distribution_over_state_variables():
    mlp = MLP(4, 2, attention="features")
    x = torch.randn(7, 4)
    assert mlp(x).shape == (7, 2)
    weights = mlp.feature_attention.last_weights
    assert weights.shape == (7, 4, 4)
    torch.testing.assert_close(weights.sum(-1), torch.ones(7, 4))
    model = Policy((4,), 2, attention="features")
    model(x)
    att = feature_attention_map(model)
    assert att.shape == (4,) and att.sum().item() == pytest.approx(1.0, abs=1e-5)
    assert feature_attention_map(Policy((4,), 2, attention="gated")) is None


def test_unknown_attention_kind_is_refused():
    with pytest.raises(ValueError, match="attention must be one of"):
        MLP(4, 2, attention="transformer")


def test_vector_models_shapes():
    idm = InverseDynamics((4,), 2, attention="gated")
    s, s2 = torch.randn(3, 4), torch.randn(3, 4)
    assert idm(s, s2).shape == (3, 2)
    assert Policy((6,), 3, hidden=(32, 32)).mlp.body[0].in_features == 6


def test_image_models_encode_both_frames_with_the_same_weights():
    idm = InverseDynamics((32, 32, 3), 4, attention="gated").eval()
    frames = torch.randint(0, 255, (3, 32, 32, 3), dtype=torch.uint8)
    assert idm(frames, frames).shape == (3, 4)
    # one encoder for s_t and s_t+1: swapping the frames swaps the two feature halves
    feats = idm.encoder(frames)
    assert feats.shape == (3, idm.encoder.out_dim)
    assert len([m for m in idm.modules() if isinstance(m, ImageEncoder)]) == 1
    attn = [m for m in idm.modules() if isinstance(m, SelfAttention2d)]
    assert len(attn) == 2  # after the first two stages
    plain = InverseDynamics((32, 32, 3), 4, attention="none")
    assert not [m for m in plain.modules() if isinstance(m, SelfAttention2d)]


@pytest.mark.parametrize("obs_shape", [(4,), (16, 16, 3)])
def test_the_fused_optimizer_gives_adams_weights_to_the_last_digits(obs_shape):
    import numpy as np

    from ifo.components.learning import fit, make_optimizer
    from ifo.seeds import GLOBAL_RNG

    rng = np.random.default_rng(0)
    if len(obs_shape) == 1:
        s = rng.normal(size=(300, *obs_shape)).astype(np.float32)
    else:
        s = rng.integers(0, 256, size=(300, *obs_shape), dtype=np.uint8)
    actions = rng.integers(0, 2, size=300)
    weights = []
    for make in (make_optimizer, lambda m, lr: torch.optim.Adam(m.parameters(), lr=lr, foreach=False)):
        # the initial weights and dropout masks come from torch's global generator: hold it, as a Run does,
        # so a training another test left running in this process cannot draw from it in between
        with GLOBAL_RNG:
            torch.manual_seed(0)
            policy = Policy(obs_shape, 2, attention="gated")  # images: SAGAN
            fit(policy, policy, make(policy, 1e-3), [s], actions, 2, 64, torch.Generator().manual_seed(0))
        weights.append(torch.cat([p.detach().flatten() for p in policy.parameters()]))
    torch.testing.assert_close(*weights, rtol=1e-2, atol=1e-4)  # fused kernels round differently, nothing more


# ----------------------------------------------------------------------------- vector models trained by hand
def _gated_mlp(attention: str, layer_norm: bool = False) -> MLP:
    torch.manual_seed(0)
    mlp = MLP(8, 3, (32, 32), attention, layer_norm)
    with torch.no_grad():  # gamma away from 0, scaling away from the identity: every path carries gradient
        for block in mlp.modules():
            if isinstance(block, GatedResidual):
                block.gamma.fill_(0.3)
        mlp.standardize.mean.copy_(torch.randn(8))
        mlp.standardize.std.copy_(torch.rand(8) + 0.5)
    return mlp


@pytest.mark.parametrize("attention", ["none", "gated"])
@pytest.mark.parametrize("weighted", [False, True])
def test_hand_written_gradients_are_autograds_bit_for_bit(attention, weighted):
    """`MLP.loss_and_gradients` replaces loss.backward() in `fit` for speed: it must not move a digit."""
    mlp = _gated_mlp(attention)
    x, y = torch.randn(128, 8), torch.randint(0, 3, (128,))
    weight = torch.tensor([0.5, 1.0, 2.0]) if weighted else None
    loss = torch.nn.functional.cross_entropy(mlp(x), y, weight=weight)
    loss.backward()
    expected = {name: p.grad.clone() for name, p in mlp.named_parameters()}
    mlp.zero_grad(set_to_none=True)
    hand_loss, logits = mlp.loss_and_gradients(x, y, weight)
    assert torch.equal(hand_loss, loss.detach()) and torch.equal(logits, mlp(x).detach())
    for name, p in mlp.named_parameters():
        assert torch.equal(p.grad, expected[name]), name


def test_the_hand_written_pass_refuses_layers_it_does_not_know():
    assert _gated_mlp("gated").has_manual_gradients()
    assert not _gated_mlp("features").has_manual_gradients()
    assert not _gated_mlp("none", layer_norm=True).has_manual_gradients()


def _reference_fit(model, optimizer, inputs, targets, epochs, batch, gen, clip=None):
    """`fit` as it was before the hand-written pass: autograd and optimizer.step() on gathered batches."""
    xs = [torch.as_tensor(x) for x in inputs]
    y = torch.as_tensor(targets)
    for _ in range(epochs):
        order = torch.randperm(len(y), generator=gen)
        for start in range(0, len(y), batch):
            idx = order[start:start + batch]
            if len(idx) < 2:
                continue
            loss = torch.nn.functional.cross_entropy(model(*(x[idx] for x in xs)), y[idx])
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            if clip is not None:
                torch.nn.utils.clip_grad_value_(model.parameters(), clip)
            optimizer.step()


@pytest.mark.parametrize("attention,layer_norm,clip", [("gated", False, None), ("none", False, 1.0),
                                                      ("gated", True, 1.0)])
def test_fit_trains_an_idm_exactly_as_autograd_and_adam_would(attention, layer_norm, clip):
    """Same data, same seed: `fit` (hand-written gradients where it can, Adam's kernels called directly)
    leaves weights and Adam's state identical to the plain autograd loop's, to the last bit."""
    import numpy as np

    from ifo.components.learning import fit, make_optimizer

    rng = np.random.default_rng(0)
    s, s2 = rng.normal(size=(777, 4)).astype(np.float32), rng.normal(size=(777, 4)).astype(np.float32)
    a = rng.integers(0, 2, 777)
    models = []
    for train in ("fit", "reference"):
        torch.manual_seed(1)
        idm = InverseDynamics((4,), 2, attention=attention, layer_norm=layer_norm)
        idm.fit_input_scaling(torch.as_tensor(s), torch.as_tensor(s2))
        opt = make_optimizer(idm, 1e-3)
        gen = torch.Generator().manual_seed(5)
        if train == "fit":
            for _ in range(2):  # twice: the second call starts from Adam's existing state
                fit(idm, idm, opt, [s, s2], a, 3, 128, gen, clip_value=clip)
        else:
            for _ in range(2):
                _reference_fit(idm, opt, [s, s2], a, 3, 128, gen, clip)
        models.append((idm, opt))
    (mine, my_opt), (ref, ref_opt) = models
    for (name, p), q in zip(mine.named_parameters(), ref.parameters()):
        assert torch.equal(p, q), name
    for p, q in zip(mine.parameters(), ref.parameters()):
        for key in ("exp_avg", "exp_avg_sq", "step"):
            assert torch.equal(my_opt.state[p][key], ref_opt.state[q][key]), key


def test_warming_up_training_draws_no_random_numbers():
    """The app warms a new server process up (ifo.components.learning.warm_up) while sessions may be
    training: it must not move any random stream, or the same seed would stop giving the same numbers."""
    import numpy as np

    from ifo.components.learning import warm_up

    torch_state, numpy_state = torch.get_rng_state().clone(), np.random.get_state()[1].copy()
    warm_up()
    assert torch.equal(torch.get_rng_state(), torch_state)
    assert (np.random.get_state()[1] == numpy_state).all()


def test_the_runs_own_dropout_masks_are_torchs_from_a_generator_in_the_same_state():
    """The image heads' RunDropout draws from the run's generator (so two runs train at once): the same
    outputs and gradients as nn.Dropout after torch.manual_seed of the same seed, and nn.Dropout outside."""
    from ifo.nets import RunDropout, dropout_masks_from, uses_dropout

    x = torch.randn(64, 128)
    ours, torchs = RunDropout(0.5), torch.nn.Dropout(0.5)
    generator = torch.Generator()
    results = []
    for module, masks in ((ours, dropout_masks_from(generator.manual_seed(7))), (torchs, contextlib.nullcontext())):
        torch.manual_seed(7)
        xi = x.clone().requires_grad_()
        with masks:
            y = module(xi)
        (y * torch.arange(128.0)).sum().backward()
        results.append((y.detach(), xi.grad))
    assert torch.equal(results[0][0], results[1][0]) and torch.equal(results[0][1], results[1][1])
    assert 0.3 < (results[0][0] == 0).float().mean() < 0.7  # it does drop
    torch.manual_seed(7)
    assert torch.equal(ours(x), results[1][0])  # no run's generator: torch's own dropout
    assert torch.equal(ours.eval()(x), x)
    assert not uses_dropout(Policy((32, 32, 3), 4)) and uses_dropout(torch.nn.Sequential(torch.nn.Dropout(0.5)))
