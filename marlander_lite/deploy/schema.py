"""Reading a lab config safely: a strict YAML loader, and pydantic v2 validation of the config dataclasses.

Two steps turn a file into a :class:`~marlander_lite.deploy.config.LabConfig`:

1. :func:`read_yaml` parses the text with :class:`StrictYamlLoader`, a ``yaml.SafeLoader`` that
   refuses what a lab config never needs and an attacker (or a typo) could abuse: a file larger
   than :data:`MAX_FILE_BYTES`, a key repeated in one mapping (YAML would silently keep the last
   one: ``max_speed: 0.3`` then ``max_speed: 3.0``), more than :data:`MAX_ALIASES` aliases (a
   "billion laughs" bomb expands a few hundred bytes into gigabytes), nesting deeper than
   :data:`MAX_DEPTH` (Python would hit its recursion limit).
2. :func:`validate` checks the parsed data against the config's frozen dataclasses with a
   pydantic ``TypeAdapter``. Each dataclass carries :data:`SCHEMA_CONFIG` (unknown keys are
   errors, NaN and infinity are refused) and its fields carry their constraints as ``Annotated``
   types (``Annotated[Real, Field(gt=0, le=3)]``); numbers, text and booleans are *strict* (no
   ``"2"`` for 2, no ``1`` for true). Each dataclass's ``__post_init__`` then checks what involves
   several fields with :func:`check`.

Every problem becomes one :class:`ConfigError` whose message names the field path, e.g.
``limits.max_speed: Input should be less than or equal to 3 (got 5.0)``.
"""

from __future__ import annotations

import dataclasses
import functools
import reprlib
import types
import typing
from typing import Annotated, Any, get_args, get_origin, get_type_hints

import yaml
from pydantic import ConfigDict, Field, Strict, TypeAdapter, ValidationError

MAX_FILE_BYTES = 64 * 1024
"""A lab config is a few kilobytes; anything larger is refused before parsing."""
MAX_ALIASES = 16
"""YAML aliases (``*name``) allowed in one file; each may copy a whole subtree."""
MAX_DEPTH = 16
"""Deepest nesting of mappings and lists allowed (the config itself needs 4)."""
MAX_REPORTED = 6
"""At most this many problems are listed in one error message."""

SCHEMA_CONFIG = ConfigDict(extra="forbid", allow_inf_nan=False)
"""pydantic settings of every config dataclass: unknown keys and non-finite numbers are errors."""
Real = Annotated[float, Strict()]
"""A finite number (an integer is accepted, text is not)."""
Whole = Annotated[int, Strict()]
"""An integer (not a boolean, not text)."""
Flag = Annotated[bool, Strict()]
"""``true`` or ``false`` (not 0/1, not ``"yes"``)."""
Text = Annotated[str, Strict()]
"""Text."""
NAME_PATTERN = r"^[A-Za-z0-9_.\-]{1,64}$"
Name = Annotated[str, Strict(), Field(pattern=NAME_PATTERN)]
"""A rigid-body or pad name: 1-64 letters, digits, ``_``, ``.`` or ``-``."""
URI_PATTERN = (
    r"^(radio://(\d+|\*)/(\d|[1-9]\d|1[01]\d|12[0-5])/(250K|1M|2M)(/[0-9A-Fa-f]{10})?(\?[\w=&]*)?"
    r"|usb://\d+|debug://\d+/\d+)$"
)
"""cflib URIs: ``radio://<dongle>/<channel 0-125>/<250K|1M|2M>[/<10 hex digits address>]``,
``usb://<n>``, or ``debug://<n>/<n>`` (cflib's debug driver, used by the tests)."""
Uri = Annotated[str, Strict(), Field(pattern=URI_PATTERN)]
Coordinate = Annotated[Real, Field(ge=-100, le=100)]
"""A world coordinate (m)."""
ParamName = Annotated[Text, Field(pattern=r"^[A-Za-z_]\w*\.[A-Za-z_]\w*$")]
"""A Crazyflie parameter name, ``group.name``."""
PATTERN_HELP = {
    URI_PATTERN: "a cflib URI such as radio://0/80/2M/E7E7E7E7E7 (channel 0-125, 250K/1M/2M), usb://0 or debug://0/0",
    NAME_PATTERN: "a name of 1-64 letters, digits, '_', '.' or '-'",
}
"""What each text pattern means, for error messages."""


class ConfigError(ValueError):
    """The lab config is wrong; the message says where and what is allowed."""


def check(ok: bool, message: str) -> None:
    """Raise :class:`ConfigError` with ``message`` unless ``ok``."""
    if not ok:
        raise ConfigError(message)


class StrictYamlLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses duplicate keys, too many aliases and too deep nesting."""

    def __init__(self, stream: Any) -> None:
        super().__init__(stream)
        self._depth = 0
        self._aliases = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        mark = self.peek_event().start_mark
        if self.check_event(yaml.AliasEvent):
            self._aliases += 1
            check(
                self._aliases <= MAX_ALIASES,
                f"line {mark.line + 1}: more than {MAX_ALIASES} YAML aliases (*name); a lab config needs none.",
            )
        self._depth += 1
        try:
            check(self._depth <= MAX_DEPTH, f"line {mark.line + 1}: nested deeper than {MAX_DEPTH} levels.")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_mapping(self, node: Any, deep: bool = False) -> Any:
        seen: dict[Any, int] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key, line = self.construct_object(key_node, deep=True), key_node.start_mark.line + 1
            try:
                first = seen.get(key)
            except TypeError:
                raise ConfigError(f"line {line}: a key must be text, got {_short(key)}.") from None
            if first is not None:
                message = f"key {_short(key)} repeats the one on line {first}; YAML would silently keep the last"
                raise ConfigError(f"line {line}: {message}.")
            seen[key] = line
        return super().construct_mapping(node, deep=deep)


def read_yaml(raw: bytes) -> Any:
    """Parse the bytes of a config file with :class:`StrictYamlLoader`; :class:`ConfigError` if refused."""
    check(len(raw) <= MAX_FILE_BYTES, f"the file has {len(raw)} bytes; a lab config has at most {MAX_FILE_BYTES}.")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as error:
        raise ConfigError(f"the file is not UTF-8 text ({error}).") from None
    loader = None
    try:
        loader = StrictYamlLoader(text)  # the reader already refuses control characters here
        return loader.get_single_data()
    except yaml.YAMLError as error:
        raise ConfigError(f"not valid YAML: {' '.join(str(error).split())}") from None
    except RecursionError:
        raise ConfigError(f"nested too deeply (at most {MAX_DEPTH} levels).") from None
    finally:
        if loader is not None:
            loader.dispose()


@functools.cache
def _adapter(cls: type) -> TypeAdapter:
    return TypeAdapter(cls)


def validate(cls: type, data: Any) -> Any:
    """An instance of the config dataclass ``cls`` from parsed YAML ``data``; :class:`ConfigError` naming fields."""
    if data is None:
        raise ConfigError("the config is empty; it needs at least drones, pads and mocap.")
    try:
        return _adapter(cls).validate_python(data)
    except ValidationError as error:
        problems = [_describe(cls, e) for e in error.errors(include_url=False)]
        more = f" (and {len(problems) - MAX_REPORTED} more)" if len(problems) > MAX_REPORTED else ""
        raise ConfigError("; ".join(problems[:MAX_REPORTED]) + more) from None


def _path(loc: tuple[Any, ...]) -> str:
    """``('drones', 1, 'uri')`` -> ``drones[1].uri``."""
    text = ""
    for part in loc:
        if isinstance(part, int):
            text += f"[{part}]"
        elif part == "[key]":
            text += " (a key)"
        elif not str(part).isidentifier():
            text += f"[{part!r}]"
        else:
            text += f".{part}" if text else str(part)
    return text or "config"


def _describe(cls: type, error: dict[str, Any]) -> str:
    """One pydantic error as ``path: what is wrong (got ...)``."""
    loc, kind = tuple(error["loc"]), error["type"]
    where = _path(loc)
    if kind == "value_error":  # a ConfigError from a __post_init__: its message says it all
        return f"{where}: {error['ctx']['error']}"
    if kind == "missing":
        return f"{where}: required but missing"
    if kind == "string_pattern_mismatch":
        pattern = error["ctx"]["pattern"]
        return f"{where}: must be {PATTERN_HELP.get(pattern, f'text matching {pattern}')}, got {_short(error['input'])}"
    if kind == "unexpected_keyword_argument":
        allowed = _allowed_keys(cls, loc[:-1])
        return f"{where}: unknown key; allowed: {', '.join(allowed)}"
    if kind in ("dataclass_type", "dict_type"):
        return f"{where}: must be a mapping of keys to values, got {_short(error['input'])}"
    return f"{where}: {error['msg']} (got {_short(error['input'])})"


_REPR = reprlib.Repr()
_REPR.maxstring, _REPR.maxother, _REPR.maxlist, _REPR.maxdict, _REPR.maxlevel = 40, 40, 4, 4, 2


def _short(value: Any) -> str:
    """A short ``repr`` (a huge value would make a huge message)."""
    return _REPR.repr(value)


def _allowed_keys(cls: type, loc: tuple[Any, ...]) -> list[str]:
    """Field names of the dataclass found at ``loc`` inside ``cls`` (for "allowed:" hints)."""
    hint: Any = cls
    for part in loc:
        hint = _unwrap(hint)
        if dataclasses.is_dataclass(hint) and isinstance(part, str):
            hint = get_type_hints(hint, include_extras=True).get(part, Any)
        elif get_origin(hint) in (tuple, dict):
            hint = get_args(hint)[-1] if get_origin(hint) is dict else get_args(hint)[0]
    hint = _unwrap(hint)
    return [f.name for f in dataclasses.fields(hint)] if dataclasses.is_dataclass(hint) else []


def _unwrap(hint: Any) -> Any:
    """Strip ``Annotated[...]`` and ``X | None`` down to the type that holds the fields."""
    while True:
        origin = get_origin(hint)
        if origin is Annotated:
            hint = get_args(hint)[0]
        elif origin in (types.UnionType, typing.Union):
            hint = next(a for a in get_args(hint) if a is not type(None))
        else:
            return hint
