import numpy as np
import pytest

from ifo.metrics import aer, performance, trajectory_fidelity


def test_aer_is_the_mean_episode_return():
    assert aer([10, 20, 30]) == 20
    with pytest.raises(ValueError):
        aer([])


def test_performance_normalises_between_random_and_expert():
    assert performance([500, 500], 20, 500) == pytest.approx(1.0)
    assert performance([20], 20, 500) == pytest.approx(0.0)
    assert performance([260], 20, 500) == pytest.approx(0.5)
    # below random and above expert are meaningful (thesis Sec 7.3)
    assert performance([-300], -200, -100) == pytest.approx(-1.0)
    assert performance([-90], -200, -100) == pytest.approx(1.1)


def test_performance_averages_per_episode_ratios_with_per_episode_references():
    # Eq 4.2 averages each episode's ratio: maze layouts have their own references
    returns = np.array([1.0, 0.5])
    random_ref = np.array([0.0, 0.0])
    expert_ref = np.array([1.0, 0.25])
    assert performance(returns, random_ref, expert_ref) == pytest.approx((1.0 + 2.0) / 2)


def test_performance_undefined_when_references_equal():
    with pytest.raises(ValueError, match="undefined"):
        performance([1.0], 5.0, 5.0)


def test_fidelity_is_zero_for_the_expert_and_grows_as_behaviour_departs():
    rng = np.random.default_rng(0)
    expert = rng.normal(size=(300, 4))
    assert trajectory_fidelity(expert, expert) == pytest.approx(0.0, abs=1e-6)
    near = trajectory_fidelity(expert + 0.1, expert)
    far = trajectory_fidelity(expert + 3.0, expert)
    assert 0 < near < far


def test_fidelity_on_images_uses_pooled_pixels():
    a = np.zeros((5, 32, 32, 3), dtype=np.uint8)
    b = np.full((5, 32, 32, 3), 255, dtype=np.uint8)
    assert trajectory_fidelity(a, a) == pytest.approx(0.0, abs=1e-6)
    assert trajectory_fidelity(a, b) > 0
