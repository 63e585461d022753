"""Frozen dataclasses from parsed YAML, with errors that say where and what is allowed.

:func:`build` checks a mapping against a dataclass's fields (unknown and missing keys), converts
each value by the field's type hint (numbers, text, booleans, tuples, mappings, ``Literal``
choices, optional values, nested dataclasses) and lets the dataclass's ``__post_init__`` check
the values; every error is a :class:`ConfigError` naming the key, e.g.
``config.rates: rates.loop_hz must be in [policy_hz, 250] ...``.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any, Literal, get_args, get_origin, get_type_hints


class ConfigError(ValueError):
    """The lab config is wrong; the message says where and what is allowed."""


def check(ok: bool, message: str) -> None:
    """Raise :class:`ConfigError` with ``message`` unless ``ok``."""
    if not ok:
        raise ConfigError(message)


def build(cls: type, data: Any, where: str) -> Any:
    """An instance of dataclass ``cls`` from the mapping ``data``; ``where`` names it in errors."""
    if not isinstance(data, dict):
        raise ConfigError(f"{where} must be a mapping of keys to values, got {type(data).__name__}.")
    hints = get_type_hints(cls)
    fields = [f.name for f in dataclasses.fields(cls)]
    unknown = sorted(set(data) - set(fields))
    check(not unknown, f"{where}: unknown key(s) {unknown}; allowed: {', '.join(fields)}.")
    required = [
        f.name
        for f in dataclasses.fields(cls)
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    missing = [name for name in required if name not in data]
    check(not missing, f"{where}: missing key(s) {missing}; required: {', '.join(required)}.")
    values = {name: convert(value, hints[name], f"{where}.{name}") for name, value in data.items()}
    try:
        return cls(**values)
    except ConfigError as error:
        raise ConfigError(f"{where}: {error}") from None


def convert(value: Any, hint: Any, where: str) -> Any:
    """``value`` converted to the type ``hint`` (or a :class:`ConfigError` naming ``where``)."""
    origin, args = get_origin(hint), get_args(hint)
    if dataclasses.is_dataclass(hint):
        return build(hint, value, where)
    if origin in (types.UnionType, typing.Union):
        if value is None and type(None) in args:
            return None
        (inner,) = [a for a in args if a is not type(None)]
        return convert(value, inner, where)
    if origin is Literal:
        check(value in args, f"{where} is {value!r}; allowed: {', '.join(map(str, args))}.")
        return value
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            check(isinstance(value, list | tuple), f"{where} must be a list.")
            return tuple(convert(v, args[0], f"{where}[{i}]") for i, v in enumerate(value))
        check(
            isinstance(value, list | tuple) and len(value) == len(args),
            f"{where} must be a list of {len(args)} values, got {value!r}.",
        )
        return tuple(convert(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args, strict=True)))
    if origin is dict:
        check(isinstance(value, dict), f"{where} must be a mapping, got {value!r}.")
        return {str(k): convert(v, args[1], f"{where}.{k}") for k, v in value.items()}
    if hint is bool:
        check(isinstance(value, bool), f"{where} must be true or false, got {value!r}.")
        return value
    if hint is int:
        check(isinstance(value, int) and not isinstance(value, bool), f"{where} must be an integer, got {value!r}.")
        return value
    if hint is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
        check(ok, f"{where} must be a finite number, got {value!r}.")
        return float(value)
    if hint is str:
        check(isinstance(value, str | int | float) and not isinstance(value, bool), f"{where} must be text.")
        return str(value)
    raise TypeError(f"No YAML conversion for {hint!r} at {where}.")
