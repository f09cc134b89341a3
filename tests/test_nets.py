"""Networks: attention modules start as the identity (gamma = 0), shapes, IDM weight sharing."""
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

    rng = np.random.default_rng(0)
    if len(obs_shape) == 1:
        s = rng.normal(size=(300, *obs_shape)).astype(np.float32)
    else:
        s = rng.integers(0, 256, size=(300, *obs_shape), dtype=np.uint8)
    actions = rng.integers(0, 2, size=300)
    weights = []
    for make in (make_optimizer, lambda m, lr: torch.optim.Adam(m.parameters(), lr=lr, foreach=False)):
        torch.manual_seed(0)
        policy = Policy(obs_shape, 2, attention="gated")  # images: SAGAN
        fit(policy, policy, make(policy, 1e-3), [s], actions, 2, 64, torch.Generator().manual_seed(0))
        weights.append(torch.cat([p.detach().flatten() for p in policy.parameters()]))
    torch.testing.assert_close(*weights, rtol=1e-2, atol=1e-4)  # fused kernels round differently, nothing more
