"""One source for settings: a configuration field declares its help text and bounds once, and
the command line's flags (`add_arguments`) and the app's widgets (`ifo.ui.settings`) are
generated from it.

    pre_size: int | None = option(None, "|I_pre|: random-policy transitions", low=10)

`option()` is `dataclasses.field` with metadata: help (one plain sentence), title (the widget's
label), choices, low/high bounds, `labels` (what a widget shows for each choice), `advanced`
(in the app's "More settings" rather than the sidebar's first lines) and `widget` ("radio" to
show a few choices side by side), and `work` (how an iteration's work grows with the setting: 1 in
proportion, 2 with its square, as an image's side; 0 not, or not simply). `check_field` applies the
bounds with a message that names the field as the command line spells it; `heavier_than_default`
names the settings that multiply an iteration's work.
"""
from __future__ import annotations

import argparse
import dataclasses
import functools
import types
import typing
from dataclasses import dataclass, fields
from typing import Any

_MISSING = dataclasses.MISSING


def option(default: Any = None, help: str = "", *, title: str = "", choices: tuple | None = None,
           low: float | None = None, high: float | None = None, labels: dict | None = None, advanced: bool = False,
           widget: str = "", work: int = 0, default_factory: Any = _MISSING) -> Any:
    meta = {"help": help, "title": title, "choices": choices, "low": low, "high": high, "labels": labels or {},
            "advanced": advanced, "widget": widget, "work": work}
    if default_factory is not _MISSING:
        return dataclasses.field(default_factory=default_factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


@dataclass(frozen=True)
class Spec:
    """What a field says about itself (for the CLI, the widgets and the checks)."""

    name: str
    kind: type  # int, float, bool, str or tuple (of ints)
    optional: bool  # None allowed: "the method's or the environment's choice"
    default: Any
    help: str
    choices: tuple | None
    low: float | None
    high: float | None
    labels: dict
    advanced: bool
    title: str
    widget: str
    work: int = 0  # an iteration's work grows as setting ** work (0: not, or not simply)

    @property
    def flag(self) -> str:
        return "--" + self.name.replace("_", "-")

    @property
    def label(self) -> str:
        return self.title or self.name.replace("_", " ").capitalize()


def _kind(annotation) -> tuple[type, bool]:
    hint = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if hint in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        kind, _ = _kind(inner[0])
        return kind, True
    if hint is tuple or annotation is tuple:
        return tuple, False
    return annotation, False


@functools.cache  # a class's fields do not change, and get_type_hints is slow (every page run asks)
def specs(cls) -> tuple[Spec, ...]:
    hints = typing.get_type_hints(cls)
    out = []
    for f in fields(cls):
        if not f.metadata or "help" not in f.metadata:
            continue  # not a setting (e.g. a nested configuration)
        kind, optional = _kind(hints[f.name])
        default = f.default if f.default is not _MISSING else (f.default_factory() if f.default_factory is not _MISSING
                                                               else None)
        m = f.metadata
        out.append(Spec(f.name, kind, optional or default is None, default, m["help"], m["choices"], m["low"],
                        m["high"], m["labels"], m["advanced"], m["title"], m["widget"], m["work"]))
    return tuple(out)


def check_field(spec: Spec, value: Any) -> None:
    """ValueError in plain words if `value` is not allowed for this field (None passes when optional)."""
    if value is None:
        if not spec.optional:
            raise ValueError(f"{spec.name} needs a value")
        return
    if spec.kind is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{spec.name} must be true or false, got {value!r}")
        return
    if spec.kind is int and (not isinstance(value, int) or isinstance(value, bool)):
        raise ValueError(f"{spec.name} must be a whole number, got {value!r}")
    if spec.kind is float and (not isinstance(value, (int, float)) or isinstance(value, bool) or value != value):
        raise ValueError(f"{spec.name} must be a number, got {value!r}")
    if spec.choices is not None and value not in spec.choices:
        raise ValueError(f"{spec.name} must be one of {', '.join(map(str, spec.choices))}; got {value!r}")
    if spec.kind in (int, float):
        bound = (lambda b: f"{int(b)}") if spec.kind is int else (lambda b: f"{b:g}")
        if spec.low is not None and value < spec.low:
            raise ValueError(f"{spec.name} must be at least {bound(spec.low)}, got {value!r}")
        if spec.high is not None and value > spec.high:
            raise ValueError(f"{spec.name} must be at most {bound(spec.high)}, got {value!r}")
    if spec.kind is tuple:
        if not value or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in value):
            raise ValueError(f"{spec.name} must list positive whole numbers, got {value!r}")


def heavier_than_default(field_specs, values: dict, defaults: dict, at_least: float = 4.0) -> list[tuple]:
    """(spec, value, default, factor) for each chosen setting that multiplies the work of the part of an
    iteration it sizes by `at_least` or more against its default (e.g. a 256-pixel maze image: 64x the
    networks' work per image), so a page can say so before a Step takes minutes."""
    out = []
    for s in field_specs:
        value, default = values.get(s.name), defaults.get(s.name)
        if not s.work or value is None or not default or default <= 0:
            continue
        factor = (value / default) ** s.work
        if factor >= at_least:
            out.append((s, value, default, factor))
    return out


def parse_bool(text: str) -> bool:
    v = str(text).strip().lower()
    if v in ("1", "true", "yes", "on"):
        return True
    if v in ("0", "false", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")


def _parse_int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None


def _parse_float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None


def _parse_ints(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in str(text).split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected whole numbers separated by commas, got {text!r}") from None


PARSERS = {bool: parse_bool, int: _parse_int, float: _parse_float, tuple: _parse_ints, str: str}


def add_arguments(parser: argparse.ArgumentParser | argparse._ArgumentGroup, cls, skip: tuple[str, ...] = ()) -> None:
    """One flag per field of `cls` (default None: the field's own default applies later)."""
    for s in specs(cls):
        if s.name in skip:
            continue
        metavar = {bool: "BOOL", tuple: "N,N"}.get(s.kind)
        default = "" if s.default is None else f" (default: {','.join(map(str, s.default)) if s.kind is tuple else s.default})"
        parser.add_argument(s.flag, dest=s.name, type=PARSERS.get(s.kind, str), default=None,
                            choices=s.choices if s.kind is str else None, metavar=metavar,
                            help=(s.help + default).replace("%", "%%"))  # argparse formats help with %


def given(namespace: argparse.Namespace, cls) -> dict:
    """The fields of `cls` set on the command line."""
    return {s.name: getattr(namespace, s.name) for s in specs(cls)
            if getattr(namespace, s.name, None) is not None}
