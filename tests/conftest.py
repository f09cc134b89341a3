import os

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")

from dataclasses import fields  # noqa: E402

import pytest  # noqa: E402

from ifo.config import RunConfig  # noqa: E402
from ifo.runtime import limit_threads  # noqa: E402

limit_threads()


def make_tiny_config(**overrides) -> RunConfig:
    """A CartPole run small enough for a unit test (a second or two per iteration); the small sizes a
    method's learner does not have (GAIL's has no I_pre) are left out."""
    from ifo.methods import get_method

    base = dict(env="cartpole", method="bco-alpha", iterations=2, pre_size=2000, episodes_per_iteration=10,
                eval_episodes=10, policy_epochs=2, expert_episodes=2, round_steps=512)
    settings = {**base, **overrides}
    own = get_method(settings["method"]).learner_class.Config.field_names() | {f.name for f in fields(RunConfig)}
    return RunConfig.from_dict({k: v for k, v in settings.items() if k in own or k in overrides})


@pytest.fixture
def tiny_config():
    return make_tiny_config
