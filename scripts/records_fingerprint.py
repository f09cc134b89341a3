"""Fingerprints of the records a set of small runs produce: one line per configuration with a
hash of its evaluations (AER, Performance, returns of every iteration), of its final policy
weights, and of its whole records (timings left out; this one also moves when a change only
adds a new diagnostic field).

A change that must not move a number (a refactor, a speed-up "with the same numbers") is
checked by running this before and after it and comparing the lines:

    python scripts/records_fingerprint.py > before.txt
    ... change ...
    python scripts/records_fingerprint.py | diff before.txt -
"""
from __future__ import annotations

import hashlib
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ifo.config import RunConfig  # noqa: E402
from ifo.run import Run  # noqa: E402
from ifo.runtime import limit_threads  # noqa: E402

TINY = dict(iterations=2, pre_size=2000, episodes_per_iteration=10, eval_episodes=10, policy_epochs=2,
            expert_episodes=2)
CASES = {
    "cartpole-bc": dict(env="cartpole", method="bc"),
    "cartpole-bco": dict(env="cartpole", method="bco"),
    "cartpole-bco-alpha": dict(env="cartpole", method="bco-alpha"),
    "cartpole-abco": dict(env="cartpole", method="abco"),
    "cartpole-iupe": dict(env="cartpole", method="iupe"),
    "cartpole-iupe-features": dict(env="cartpole", method="iupe", attention="features", eval_explore=True),
    "cartpole-abco-whole": dict(env="cartpole", method="bco-alpha", sampling="abco-whole", seed=3),
    "acrobot-iupe": dict(env="acrobot", method="iupe", seed=1),
    "mountaincar-bco-alpha": dict(env="mountaincar", method="bco-alpha"),
    "lunarlander-iupe": dict(env="lunarlander", method="iupe", seed=2),
    "maze3-iupe": dict(env="maze3", method="iupe", expert_episodes=10),
    "maze3-bco-alpha-vector": dict(env="maze3", method="bco-alpha", obs_mode="vector", expert_episodes=10),
    "maze3-abco-thesis": dict(env="maze3", method="abco", expert_episodes=10, maze_eval_layouts="demonstration",
                              deadlock_guard=True),
    "maze3-cril": dict(env="maze3", method="cril", expert_episodes=10, seed=4),
}


def digest(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True).encode()).hexdigest()[:16]


def fingerprint(case: dict) -> tuple[str, str, str]:
    run = Run(RunConfig.from_dict({**TINY, **case}))
    run.run()
    records = [{k: v for k, v in r.items() if k != "seconds"} for r in run.records]
    weights = hashlib.sha256(b"".join(v.detach().numpy().tobytes() for v in run.policy.state_dict().values()))
    return digest([r["evaluation"] for r in records]), weights.hexdigest()[:16], digest(records)


def main(names: list[str]) -> None:
    limit_threads()
    for name in names or CASES:
        evaluation, weights, records = fingerprint(CASES[name])
        print(f"{name:28s} evaluation {evaluation}  policy {weights}  records {records}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
