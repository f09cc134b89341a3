"""Probes: Grad-CAM on the policy (Fig 6.1), mean-image distances (Fig 5.3), vector attention,
and the figures that draw them."""
import numpy as np
import pytest
import torch
from torch import nn

from ifo import figures
from ifo.nets import Policy
from ifo.probes import (action_mean_image_distances, grad_cam_maps, maze_probe_frames, maze_probes,
                        vector_attention)

ACTIONS = ["N", "S", "W", "E"]


def _frames(n=3, size=32, seed=0):
    return np.random.default_rng(seed).integers(0, 256, size=(n, size, size, 3), dtype=np.uint8)


def _no_hooks(model: nn.Module) -> bool:
    return all(not m._forward_hooks and not m._forward_pre_hooks and not m._backward_hooks
               for m in model.modules())


@pytest.fixture(scope="module")
def cnn_policy():
    torch.manual_seed(0)
    policy = Policy((32, 32, 3), 4, attention="gated")
    with torch.no_grad():  # give the BatchNorm layers statistics of their own
        policy.train()
        policy(torch.as_tensor(_frames(8, seed=1)))
        for m in policy.modules():  # and SA a voice, so the maps are not of an identity path only
            if hasattr(m, "gamma"):
                m.gamma.fill_(0.5)
    return policy


# ----------------------------------------------------------------------------- Grad-CAM
def test_grad_cam_shapes_values_and_determinism(cnn_policy):
    frames = _frames(3)
    first = grad_cam_maps(cnn_policy, frames)
    second = grad_cam_maps(cnn_policy, frames)
    assert first == second
    maps = np.array(first["maps"])
    assert maps.shape == (3, 16, 16)
    assert maps.min() >= 0 and maps.max() <= 1
    assert len(first["raw_max"]) == len(first["actions"]) == len(first["probabilities"]) == 3
    probs = np.array(first["probabilities"])
    assert probs.shape == (3, 4) and np.allclose(probs.sum(1), 1, atol=1e-3)
    assert first["actions"] == probs.argmax(1).tolist()  # the map explains the MAP action
    assert all(v >= 0 for v in first["raw_max"])
    assert np.array(grad_cam_maps(cnn_policy, frames, resolution=8)["maps"]).shape == (3, 8, 8)


@pytest.mark.parametrize("training", [True, False])
def test_grad_cam_leaves_the_model_alone(cnn_policy, training):
    cnn_policy.train(training)
    before = {k: v.clone() for k, v in cnn_policy.state_dict().items()}  # weights and BN buffers
    modes = [m.training for m in cnn_policy.modules()]
    rng_state = torch.get_rng_state()
    grad_cam_maps(cnn_policy, _frames(2))
    assert torch.equal(torch.get_rng_state(), rng_state)  # the run's random stream is not disturbed
    after = cnn_policy.state_dict()
    assert all(torch.equal(before[k], after[k]) for k in before)
    assert [m.training for m in cnn_policy.modules()] == modes
    assert not cnn_policy.encoder.last_conv._forward_hooks and _no_hooks(cnn_policy)
    assert all(p.grad is None for p in cnn_policy.parameters())


class _RedDetector(nn.Module):
    """A hand-built model that decides on red alone: channel 0 sees red, channel 1 green;
    the logit of action 0 reads only channel 0 (action 1 is a constant below it)."""

    def __init__(self):
        super().__init__()
        conv = nn.Conv2d(3, 2, 1, bias=False)
        with torch.no_grad():
            conv.weight.zero_()
            conv.weight[0, 0] = 1.0
            conv.weight[1, 1] = 1.0
        self.features = nn.Sequential(conv, nn.ReLU())
        self.fc = nn.Linear(2, 2)
        with torch.no_grad():
            self.fc.weight.copy_(torch.tensor([[1.0, 0.0], [0.0, 0.0]]))
            self.fc.bias.copy_(torch.tensor([0.0, -1.0]))

    def forward(self, x):
        return self.fc(self.features(x).mean(dim=(2, 3)))


def test_grad_cam_lights_up_the_informative_pixels_not_their_transpose():
    frame = np.zeros((1, 32, 32, 3), np.uint8)
    frame[0, 0:8, 20:32, 0] = 255  # red, top right: the model decides on this
    frame[0, 24:32, 0:12, 1] = 255  # green, bottom left: the model ignores it (and a transpose would land here)
    model = _RedDetector()
    out = grad_cam_maps(model, frame, target_layer=model.features)
    m = np.array(out["maps"][0])
    assert out["actions"] == [0]
    assert m.shape == (16, 16)
    total = m.sum()
    assert m[:8, 8:].sum() / total > 0.95  # top-right quadrant of the map
    assert m[8:, :8].sum() == 0  # nothing where the ignored green is
    assert _no_hooks(model)


def test_grad_cam_refuses_a_vector_policy():
    with pytest.raises(ValueError, match="image policy"):
        grad_cam_maps(Policy((4,), 2), np.zeros((1, 4), np.float32))


# ----------------------------------------------------------------------------- probe frames
def test_probe_frames_fixed_and_distinct():
    a = maze_probe_frames(5, 32, 6)
    b = maze_probe_frames(5, 32, 6)
    assert a.shape == (6, 32, 32, 3) and a.dtype == np.uint8
    assert np.array_equal(a, b)
    assert len({f.tobytes() for f in a}) == 6
    kinds = {p["kind"] for p in maze_probes(5, 6)}
    assert {"junction", "corridor"} <= kinds
    small = maze_probe_frames(3, 24, 6)  # small mazes too
    assert len({f.tobytes() for f in small}) == 6


# ----------------------------------------------------------------------------- Fig 5.3 numbers
def _labelled(n, seed, n_actions=4, shape=(8, 8, 3)):
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, size=(n, *shape), dtype=np.uint8), rng.integers(0, n_actions, size=n)


def test_action_mean_image_distances_endpoints_and_missing_actions():
    pre_s, pre_a = _labelled(200, 0)
    exp_s, exp_a = _labelled(100, 1)
    exp_s = exp_s // 2  # the expert's images differ from the random ones
    same_as_expert = action_mean_image_distances(pre_s, pre_a, exp_s, exp_a, exp_s, exp_a, 4)["distance"]
    assert same_as_expert == pytest.approx([0.0] * 4)
    same_as_random = action_mean_image_distances(pre_s, pre_a, pre_s, pre_a, exp_s, exp_a, 4)["distance"]
    assert same_as_random == pytest.approx([1.0] * 4)
    keep = exp_a != 3  # the policy never went East
    out = action_mean_image_distances(pre_s, pre_a, exp_s[keep], exp_a[keep], exp_s, exp_a, 4)
    assert out["distance"][3] is None and out["distance"][:3] == pytest.approx([0.0] * 3)
    assert out["pos_counts"][3] == 0
    # a half-way policy sits half-way; vector states work the same way
    vec_pre, vec_exp = np.zeros((4, 3)), np.ones((4, 3))
    acts = np.arange(4)
    half = action_mean_image_distances(vec_pre, acts, np.full((4, 3), 0.5), acts, vec_exp, acts, 4)
    assert half["distance"] == pytest.approx([0.5] * 4)


# ----------------------------------------------------------------------------- vector attention
def test_vector_attention():
    torch.manual_seed(0)
    model = Policy((4,), 2, attention="features")
    assert vector_attention(model) is None  # no forward pass yet
    model(torch.randn(5, 4))
    att = vector_attention(model)
    assert isinstance(att, list) and len(att) == 4 and sum(att) == pytest.approx(1.0, abs=1e-5)
    assert vector_attention(Policy((4,), 2, attention="gated")) is None


# ----------------------------------------------------------------------------- figures
def _cam_record(iteration=1, n=3):
    maps = np.random.default_rng(iteration).random((n, 16, 16)).round(3).tolist()
    return {"iteration": iteration, "attention": {"grad_cam": {
        "maps": maps, "raw_max": [0.1] * n, "actions": [1, 3, 0][:n],
        "probabilities": [[0.1, 0.6, 0.2, 0.1], [0.1, 0.1, 0.1, 0.7], [0.4, 0.2, 0.2, 0.2]][:n],
        "probes": [{"kind": "junction"}, {"kind": "corridor"}, {"kind": "junction"}][:n]}}}


def test_grad_cam_panel():
    records = [_cam_record(1), _cam_record(2)]
    frames = _frames(3)
    fig = figures.grad_cam_panel(records, theme="screen", frames=frames, action_names=ACTIONS)
    kinds = [t.type for t in fig.data]
    assert kinds.count("image") == 6 and kinds.count("heatmap") == 3  # frames; frames under the maps
    titles = [a.text for a in fig.layout.annotations]
    assert "S (60%)" in titles and "E (70%)" in titles and "junction" in titles
    assert "iteration 2" in fig.layout.title.text
    only_maps = figures.grad_cam_panel(records, iteration=1, action_names=ACTIONS)
    assert [t.type for t in only_maps.data] == ["heatmap"] * 3
    assert only_maps.layout.yaxis.autorange == "reversed"  # map row 0 on top, as in the image
    for empty in (figures.grad_cam_panel([]), figures.grad_cam_panel([{"iteration": 1, "policy": {}}])):
        assert len(empty.data) == 0 and empty.layout.annotations
    figures.grad_cam_panel(records, frames=frames, action_names=ACTIONS, theme="slide").to_json()


def test_state_attention():
    names = ["x", "v"]
    rec = {"iteration": 1, "policy": {"attention": [0.3, 0.7]}, "idm": {"attention": [0.1, 0.2, 0.3, 0.4]}}
    fig = figures.state_attention([rec], names)
    assert [t.type for t in fig.data] == ["bar", "bar"]
    assert list(fig.data[1].x) == ["x", "v", "Δx", "Δv"]
    assert len(figures.state_attention([{"iteration": 1, "policy": {"attention": [0.5, 0.5]}}], names).data) == 1
    for empty in (figures.state_attention([], names), figures.state_attention([{"iteration": 1, "policy": {}}], names)):
        assert len(empty.data) == 0 and empty.layout.annotations


def test_action_distance_curves():
    records = [{"iteration": i, "attention": {"mean_image_distance": {"distance": [1.0 / i, 0.5, None, 0.2]}}}
               for i in (1, 2, 3)]
    fig = figures.action_distance_curves(records + [{"iteration": 4}], ACTIONS)
    assert len(fig.data) == 4 and [t.name for t in fig.data] == ACTIONS
    assert list(fig.data[2].y) == [None] * 3
    assert sorted(s.y0 for s in fig.layout.shapes) == [0, 1]
    assert {"expert", "random (I_pre)"} <= {a.text for a in fig.layout.annotations}
    for empty in (figures.action_distance_curves([], ACTIONS),
                  figures.action_distance_curves([{"iteration": 1}], ACTIONS)):
        assert len(empty.data) == 0 and empty.layout.annotations


def test_a_braided_maze_run_probes_its_own_world():
    """The attention probes of a run in the braided world are frames of braided mazes (not of the perfect
    twin's), and the page redraws the same frames from the record."""
    from ifo.envs.maze import layout_pool
    from ifo.figure_registry import EnvView

    probes = maze_probes(5, loops=1.0)
    pool = layout_pool(5, "eval", 1.0)
    for p in probes:
        layout = pool[p["layout_index"]]
        assert min(bin(int(x)).count("1") for x in layout.ravel()) >= 2  # braided: no dead ends
    braided, perfect = maze_probe_frames(5, 32, loops=1.0), maze_probe_frames(5, 32)
    assert braided.shape == perfect.shape and not np.array_equal(braided, perfect)
    view = EnvView.of({"env": "maze5-loops", "obs_mode": "image", "image_size": 32})
    assert (view.maze_size, view.maze_loops) == (5, 1.0)
