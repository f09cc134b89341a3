import os

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")

import pytest  # noqa: E402

from ifo.config import RunConfig  # noqa: E402
from ifo.runtime import limit_threads  # noqa: E402

limit_threads()


def make_tiny_config(**overrides) -> RunConfig:
    """A CartPole run small enough for a unit test (a second or two per iteration)."""
    base = dict(env="cartpole", method="bco-alpha", iterations=2, pre_size=2000, episodes_per_iteration=10,
                eval_episodes=10, policy_epochs=2, expert_episodes=2)
    return RunConfig.from_dict({**base, **overrides})


@pytest.fixture
def tiny_config():
    return make_tiny_config
