"""Methods are the one BCO loop (`ifo.run.Run.step`) with components switched on.

Each method's file states its algorithm in the thesis's terms and the components it
uses; adding a method means adding a file and a line to METHODS.
"""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Method:
    name: str
    title: str
    summary: str
    uses_idm: bool = True  # False only for BC, which learns from the expert's actions
    iterative: bool = True  # False: one pass (BCO)
    components: dict = field(default_factory=dict)  # defaults for RunConfig fields


from ifo.methods.bc import BC  # noqa: E402
from ifo.methods.bco import BCO, BCO_ALPHA  # noqa: E402
from ifo.methods.abco import ABCO  # noqa: E402
from ifo.methods.iupe import IUPE  # noqa: E402

METHODS: dict[str, Method] = {m.name: m for m in (BC, BCO, BCO_ALPHA, ABCO, IUPE)}
PLANNED = ("cril", "sail", "gail", "gaifo", "ilpo")  # the thesis's other methods, not built yet


class UnknownMethod(ValueError):
    pass


def get_method(name: str) -> Method:
    key = name.strip().lower().replace("_", "-").replace("(", "-").replace(")", "").replace("α", "alpha")
    key = {"bcoalpha": "bco-alpha", "bco-a": "bco-alpha"}.get(key, key)
    if key in METHODS:
        return METHODS[key]
    if key in PLANNED:
        raise UnknownMethod(f"method {name!r} is planned but not implemented yet; available: {', '.join(METHODS)}")
    raise UnknownMethod(f"unknown method {name!r}; available: {', '.join(METHODS)}")
