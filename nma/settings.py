"""The machinery of settings, shared by the config schema (nma.schema) and the tasks' own schemas: a
field's allowed range or choices beside its default (`bounded`, `choice`), and `Schema`, the base
that checks every field on construction."""

from __future__ import annotations

import math
from dataclasses import MISSING as DC_MISSING
from dataclasses import field, fields
from typing import Any, ClassVar, Dict, List, get_args, get_origin, get_type_hints

from .errors import ConfigError


def _parse_range(spec: str) -> tuple[float, float, bool, bool]:
    lo, hi = (float(s) for s in spec[1:-1].split(","))
    return lo, hi, spec[0] == "(", spec[-1] == ")"


def bounded(default: Any = DC_MISSING, spec: str = "(-inf, inf)", *, factory=None, doc: str = ""):
    """A number (or a list of numbers, each) in the interval `spec`, e.g. "(0, 1]" or "[1, inf)"."""
    _parse_range(spec)
    meta = {"range": spec, "doc": doc}
    if factory is not None:
        return field(default_factory=factory, metadata=meta)
    return field(default=default, metadata=meta)


def choice(default: str, options: tuple[str, ...], doc: str = ""):
    return field(default=default, metadata={"choices": tuple(options), "doc": doc})


def option(default: Any, doc: str):
    """A setting with no range (a flag, a name), documented where it is declared."""
    return field(default=default, metadata={"doc": doc})


def like(
    options_cls: type, name: str, default: Any = DC_MISSING, doc: str = "", choices: tuple = ()
):
    """A config field that redeclares the field `name` of the plain options class `options_cls` with
    another default (an auto value, say): its range and doc are the options class's, `doc` added
    (and `choices`, where given, the names it takes)."""
    f = next(f for f in fields(options_cls) if f.name == name)
    meta = {
        **f.metadata,
        "doc": "; ".join(d for d in (f.metadata.get("doc", ""), doc) if d),
        **({"choices": tuple(choices)} if choices else {}),
    }
    return field(default=f.default if default is DC_MISSING else default, metadata=meta)


def with_options(options_cls: type):
    """A class decorator for a config schema (under @dataclass, so applied first): every field of
    the plain options class `options_cls`, with its type, default, range and doc, declared once
    there, and then the schema's own fields; a field the schema declares itself (with `like`, say)
    keeps the schema's declaration."""

    def add(cls):
        own = dict(cls.__dict__.get("__annotations__", {}))
        hints = get_type_hints(options_cls)
        merged = {}
        for f in fields(options_cls):
            if f.name in own:
                merged[f.name] = own.pop(f.name)
                continue
            merged[f.name] = hints[f.name]
            setattr(cls, f.name, field(default=f.default, metadata=f.metadata))
        cls.__annotations__ = {**merged, **own}
        return cls

    return add


def in_range(x: float, spec: str) -> bool:
    lo, hi, lo_open, hi_open = _parse_range(spec)
    if not math.isfinite(x):
        return False
    return (x > lo if lo_open else x >= lo) and (x < hi if hi_open else x <= hi)


def check_range(path: str, value: float, spec: str) -> None:
    """ConfigError naming `path` unless the number `value` lies in the interval `spec`."""
    if not in_range(float(value), spec):
        raise ConfigError(f"{path} must be {_kind(float)} in {spec}, got {value!r}")


def _kind(tp) -> str:
    return {
        int: "an integer",
        float: "a finite number",
        bool: "true or false",
        str: "a string",
    }.get(tp, str(tp))


def _check_type(path: str, value: Any, tp) -> None:
    origin = get_origin(tp)
    if origin is None and tp in (int, float, bool, str):
        ok = (
            isinstance(value, bool)
            if tp is bool
            else isinstance(value, int) and not isinstance(value, bool)
            if tp is int
            else isinstance(value, (int, float)) and not isinstance(value, bool)
            if tp is float
            else isinstance(value, str)
        )
        if not ok:
            raise ConfigError(f"{path} must be {_kind(tp)}, got {value!r}")
    elif origin in (list, List):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{path} must be a list, got {value!r}")
        (item,) = get_args(tp)
        for i, v in enumerate(value):
            _check_type(f"{path}[{i}]", v, item)
    elif origin in (dict, Dict):
        if not isinstance(value, dict):
            raise ConfigError(f"{path} must be a mapping, got {value!r}")
        _, item = get_args(tp)
        for k, v in value.items():
            _check_type(f"{path}.{k}", v, item)
    elif origin is not None and type(None) in get_args(tp):  # Optional[X]
        if value is not None:
            _check_type(path, value, _bare(tp))


def _bare(tp):
    """X of Optional[X]; any other type as it is."""
    args = get_args(tp)
    return next(a for a in args if a is not type(None)) if type(None) in args else tp


def _points(path: str, value: Any, kind: type) -> None:
    """A list of pairs of numbers (kind int: grid node indices)."""
    for i, p in enumerate(value):
        if not isinstance(p, (list, tuple)) or len(p) != 2:
            raise ConfigError(
                f"{path}[{i}] must be a pair {'[i, j]' if kind is int else '[x, y]'}, got {p!r}"
            )
        for v in p:
            _check_type(f"{path}[{i}]", v, kind)
            if not math.isfinite(v):
                raise ConfigError(f"{path}[{i}] must be finite, got {p!r}")


def _flat_numbers(value):
    if isinstance(value, (list, tuple)):
        for v in value:
            yield from _flat_numbers(v)
    elif value is not None:
        yield value


def _every_number(value):
    """Every number inside nested lists, tuples and mappings (a task's cases, a scene's groups)."""
    if isinstance(value, dict):
        for v in value.values():
            yield from _every_number(v)
    elif isinstance(value, (list, tuple)):
        for v in value:
            yield from _every_number(v)
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        yield value


class Schema:
    """Base of every config dataclass: type and range checks of each field, then `check()`."""

    prefix: ClassVar[str] = ""

    def __post_init__(self):
        hints = get_type_hints(type(self))
        for f in fields(self):
            value = getattr(self, f.name)
            path = f"{self.prefix}.{f.name}" if self.prefix else f.name
            if isinstance(value, Schema):
                continue  # checked on its own construction
            if isinstance(value, (list, tuple)) and value and isinstance(value[0], Schema):
                continue
            if (
                hints.get(f.name) is float
                and isinstance(value, int)
                and not isinstance(value, bool)
            ):
                value = float(value)
                setattr(self, f.name, value)
            _check_type(path, value, hints.get(f.name, Any))
            if "range" in f.metadata:
                spec = f.metadata["range"]
                for x in _flat_numbers(value):
                    if not in_range(float(x), spec):
                        what = _kind(int if _bare(hints.get(f.name)) is int else float)
                        if isinstance(value, (list, tuple)):
                            what = "a list of numbers, each"
                        raise ConfigError(f"{path} must be {what} in {spec}, got {value!r}")
            if any(isinstance(x, float) and not math.isfinite(x) for x in _every_number(value)):
                raise ConfigError(f"{path} must hold finite numbers only, got {value!r}")
            if "choices" in f.metadata and value not in f.metadata["choices"]:
                raise ConfigError(
                    f"{path} must be one of {list(f.metadata['choices'])}, got {value!r}"
                )
        self.check()

    def check(self) -> None:
        """Rules that join several fields (override in a subclass)."""

    def fail(self, name: str, message: str, value: Any = DC_MISSING):
        got = "" if value is DC_MISSING else f", got {value!r}"
        raise ConfigError(f"{self.prefix + '.' if self.prefix else ''}{name} {message}{got}")
