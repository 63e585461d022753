"""Command-line options generated from the typed configs, with each field's docstring as its help.

Every config dataclass documents its fields with a string right under each one (an *attribute docstring*,
as in :class:`~marlander_lite.training.presets.TrainConfig`). :class:`ConfigOptions` adds one ``argparse``
option per field to a command's parser: ``total_steps`` becomes ``--total-steps``, its help is the field's
docstring followed by the value it has now, and the type hint decides how the words are read:

=================================  ==========================================================
type hint                          on the command line
=================================  ==========================================================
``int``, ``float``, ``str``, Path   one value: ``--learning-rate 1e-4``
``bool``                           ``--normalize-rewards`` / ``--no-normalize-rewards``
``Literal["a", "b"]``              one of the names: ``--lr-schedule linear``
``tuple[int, ...]``                one or more values: ``--net-arch 64 64``
``tuple[float, float]``            exactly two: ``--dynamics.family.max-tilt-deg 15 30``
``A | B``                          whichever member the words fit: ``--platform-speed 0.3`` or ``0 0.6``
``X | None``                       also the word ``none``: ``--target-kl none``
a dataclass                        one option per field, dotted: ``--apf.k-p 2.0``
a ``dict`` of a dataclass's fields  the same, merged into the dict: ``--task.landing-tolerance 0.02``;
                                   ``--task JSON`` replaces the whole dict first
=================================  ==========================================================

Only the options given change the config they are applied to (a preset, or the dataclass defaults), so a
run's ``config.json`` records exactly what ran. A wrong value ends the command with one line naming the
option and what it takes (``argument --seed: expected a non-negative integer ..., got '-1'``).

This is what tyro (the library CleanRL uses for its scripts) does for one command. It is written here
because tyro 1.0 runs its own parser: it cannot be mounted as one ``argparse`` subcommand among the
others, its errors are multi-line panels (one-line errors need its private ``tyro._errors`` hook), and it
offers only the keys already present in a ``dict`` field's default (the preset's six training aids, not
the 30 other :class:`~marlander_lite.task.TaskConfig` fields).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import functools
import inspect
import itertools
import json
import math
import re
import textwrap
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

SPELLINGS = "config_option_spellings"
"""Namespace attribute: the dest of each generated option given -> the spelling the user typed."""


@functools.cache
def field_docs(cls: type) -> dict[str, str]:
    """The attribute docstring of each field of the dataclass ``cls`` (and its dataclass bases), read with ``ast``."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass):
            continue
        body = ast.parse(textwrap.dedent(inspect.getsource(klass))).body[0].body  # type: ignore[attr-defined]
        for node, after in itertools.pairwise(body):
            if (
                isinstance(node, ast.AnnAssign)
                and isinstance(node.target, ast.Name)
                and isinstance(after, ast.Expr)
                and isinstance(after.value, ast.Constant)
                and isinstance(after.value.value, str)
            ):
                docs[node.target.id] = inspect.cleandoc(after.value.value)
    return docs


def plain(doc: str) -> str:
    """A docstring as terminal text: Sphinx roles and double backquotes dropped, on one line.

    ``:class:`~a.B``` -> ``B``; ``:meth:`~a.B.c``` -> ``B.c``; ``:class:`a.B``` -> ``a.B``; ````x```` -> ``x``.
    """
    text = re.sub(r":(meth|attr):`~([^`]+)`", lambda m: ".".join(m.group(2).split(".")[-2:]), doc)
    text = re.sub(r":\w+:`~([^`]+)`", lambda m: m.group(1).rsplit(".", 1)[-1], text)
    text = re.sub(r":\w+:`([^`]+)`", r"\1", text)
    return " ".join(text.replace("``", "").split())


@dataclasses.dataclass(frozen=True)
class FieldOption:
    """How one field departs from the generated option (all optional)."""

    flags: tuple[str, ...] = ()
    """Option strings, the first shown first (default: ``--`` + the dotted field name with dashes)."""
    parse: Callable[[str], Any] | None = None
    """Reads the field from one word instead of the type hint; raises ``ValueError`` or ``ArgumentTypeError``."""
    choices: tuple[str, ...] = ()
    """Allowed words for a ``str`` field that the type hint does not restrict."""
    metavar: str | None = None
    note: str = ""
    """Appended to the docstring in the help."""
    show: Callable[[Any], str] | None = None
    """Writes the current value in the help (default: as it would be typed)."""


class ConfigOptions:
    """The options of one config dataclass on one parser; :meth:`apply` puts the given ones into a config.

    Args:
        parser: the command's parser; the options go into argument groups of it.
        cls: the config dataclass.
        base: the config whose values the help shows (:meth:`show_values` changes them later).
        mappings: ``dict`` fields that hold overrides of another dataclass's fields, e.g. ``{"task": TaskConfig}``.
        skip: dotted field names left out (set by hand-written options, or by another field).
        fields: per dotted field name, a :class:`FieldOption`.
        title: heading of the group of top-level fields in the help.
        shown: dotted field names (or prefixes of them) whose help shows this text as the default, not a value.
    """

    def __init__(
        self,
        parser: argparse.ArgumentParser,
        cls: type,
        base: Any,
        *,
        mappings: Mapping[str, type] | None = None,
        skip: Sequence[str] = (),
        fields: Mapping[str, FieldOption] | None = None,
        title: str | None = None,
        shown: Mapping[str, str] | None = None,
    ) -> None:
        self.parser, self.cls, self.shown = parser, cls, dict(shown or {})
        self.mappings, self.skip, self.fields = dict(mappings or {}), set(skip), dict(fields or {})
        self.actions: dict[str, argparse.Action] = {}  # dotted field name -> its option
        self.docs: dict[str, str] = {}
        self._add(cls, (), title or f"{cls.__name__} fields", None)
        self.show_values(base)

    # ------------------------------------------------------------------------------------------ building

    def _add(self, cls: type, path: tuple[str, ...], title: str, description: str | None) -> None:
        group = self.parser.add_argument_group(title, description)
        hints, docs = typing.get_type_hints(cls), field_docs(cls)
        nested: list[tuple[type, tuple[str, ...], str | None]] = []
        for field in dataclasses.fields(cls):
            key = ".".join((*path, field.name))
            if key in self.skip or not field.init:
                continue
            doc = plain(docs.get(field.name, ""))
            if key in self.mappings:
                self._add_json(group, key, self.mappings[key], doc)
                nested.append((self.mappings[key], (*path, field.name), doc))
            elif (inner := _dataclass_in(hints[field.name])) is not None:
                nested.append((inner, (*path, field.name), doc))
            else:
                self._add_field(group, key, hints[field.name], doc)
        for inner, inner_path, doc in nested:
            name = ".".join(inner_path)
            self._add(inner, inner_path, f"--{_dashed(name)}.KEY: {inner.__name__} fields", doc or None)

    def _add_field(self, group: Any, key: str, hint: Any, doc: str) -> None:
        custom = self.fields.get(key, FieldOption())
        flags = custom.flags or (f"--{_dashed(key)}",)
        if hint is bool and custom.parse is None:
            *head, last = flags[0].split(".")
            negative = ".".join([*head, f"no-{last.removeprefix('--')}"])
            negative = negative if negative.startswith("--") else f"--{negative}"
            action = group.add_argument(*flags, negative, action=_SetField, nargs=0, dest=f"config:{key}")
        else:
            reader = _Reader(hint, custom.parse, custom.choices)
            action = group.add_argument(
                *flags,
                action=_SetField,
                read=reader,
                nargs=reader.nargs,
                metavar=custom.metavar or reader.metavar,
                dest=f"config:{key}",
            )
        self.actions[key], self.docs[key] = action, " ".join(filter(None, (doc, custom.note)))

    def _add_json(self, group: Any, key: str, target: type, doc: str) -> None:
        allowed = [f.name for f in dataclasses.fields(target) if f"{key}.{f.name}" not in self.skip]

        def read(text: str) -> dict[str, Any]:
            value = json.loads(text)
            if not isinstance(value, dict):
                raise ValueError(f"expected a JSON object of {target.__name__} fields, got {text!r}")
            unknown = sorted(set(value) - set(allowed))
            if unknown:
                raise ValueError(f"unknown {target.__name__} field(s) {unknown}; allowed: {', '.join(allowed)}")
            return value

        note = f"JSON: replaces the whole dict; --{_dashed(key)}.KEY options then change single keys."
        self.fields.setdefault(key, FieldOption(parse=read, metavar="JSON", note=note, show=json.dumps))
        self._add_field(group, key, dict, doc)

    # ------------------------------------------------------------------------------------------ using

    def show_values(self, config: Any) -> None:
        """Let the help show each field's value in ``config`` (e.g. the preset the command starts from)."""
        for key, action in self.actions.items():
            fixed = [text for name, text in self.shown.items() if key == name or key.startswith(f"{name}.")]
            show = self.fields.get(key, FieldOption()).show or _typed
            value = fixed[0] if fixed else show(self._value_at(config, key))
            action.help = f"{self.docs[key]} (default: {value})".replace("%", "%%")

    def given(self, args: argparse.Namespace) -> dict[str, str]:
        """Dotted field name -> the spelling typed, for each generated option on the command line."""
        spellings = getattr(args, SPELLINGS, {})
        return {key: spellings[f"config:{key}"] for key in self.actions if f"config:{key}" in spellings}

    def apply(self, config: Any, args: argparse.Namespace) -> Any:
        """``config`` with every option given in ``args`` applied (dict fields merged, nested configs replaced)."""
        changes = {key: getattr(args, f"config:{key}") for key in self.given(args)}
        return _apply(config, (), changes, self)

    def _value_at(self, config: Any, key: str) -> Any:
        value, path = config, ()
        for name in key.split("."):
            path = (*path, name)
            owner = self._owner(path[:-1])
            value = value.get(name, _default(owner, name)) if isinstance(value, Mapping) else getattr(value, name)
            if value is None and ".".join(path) != key:  # an unset nested config: show its defaults
                value = self._owner(path)()
        return value

    def _owner(self, path: tuple[str, ...]) -> type:
        """The dataclass whose fields the dict or config at ``path`` holds."""
        cls = self.cls
        for depth in range(len(path)):
            key = ".".join(path[: depth + 1])
            cls = self.mappings.get(key) or _dataclass_in(typing.get_type_hints(cls)[path[depth]])  # type: ignore[assignment]
        return cls


def _apply(
    value: Any, path: tuple[str, ...], changes: dict[str, Any], options: ConfigOptions, in_dict: bool = False
) -> Any:
    """``value`` (a dataclass, a dict of fields, or None) at ``path`` with the dotted ``changes`` under it."""
    prefix = "".join(f"{p}." for p in path)
    mine = {k[len(prefix) :]: v for k, v in changes.items() if k.startswith(prefix)}
    if not mine:
        return value
    in_dict = in_dict or ".".join(path) in options.mappings
    if value is None:  # an unset nested config (PointMassParams.family): start from its defaults
        value = dataclasses.asdict(options._owner(path)()) if in_dict else options._owner(path)()
    updates: dict[str, Any] = {}
    for name in dict.fromkeys(k.split(".")[0] for k in mine):
        if name in mine:  # the field itself (a JSON dict replaces the whole dict)
            updates[name] = mine[name]
        if any(k.startswith(f"{name}.") for k in mine):
            current = updates[name] if name in updates else _child(value, name)
            updates[name] = _apply(current, (*path, name), changes, options, in_dict)
    return {**value, **updates} if isinstance(value, Mapping) else dataclasses.replace(value, **updates)


def _child(value: Any, name: str) -> Any:
    return value.get(name) if isinstance(value, Mapping) else getattr(value, name)


def changed_options(config: Any, base: Any, skip: Sequence[str] = (), prefix: str = "") -> list[str]:
    """The generated options that turn the dataclass ``base`` into ``config``, e.g. ``["--apf.k-p", "2.0"]``.

    Nested dataclasses are compared field by field; ``skip`` names dotted fields written some other way.
    """
    words: list[str] = []
    for field in dataclasses.fields(config):
        key, new, old = prefix + field.name, getattr(config, field.name), getattr(base, field.name)
        if key in skip or new == old:
            continue
        if dataclasses.is_dataclass(new) and dataclasses.is_dataclass(old):
            words += changed_options(new, old, skip, prefix=f"{key}.")
        elif isinstance(new, bool):
            words.append(f"--{_dashed(key)}" if new else f"--{_dashed(prefix)}no-{_dashed(field.name)}")
        else:
            words += [f"--{_dashed(key)}", *(map(_typed, new) if isinstance(new, tuple) else [_typed(new)])]
    return words


class _SetField(argparse.Action):
    """Stores a generated option's value (read from its words) and the spelling the user typed."""

    def __init__(self, option_strings: list[str], dest: str, read: _Reader | None = None, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, default=argparse.SUPPRESS, **kwargs)
        self.read = read

    def __call__(self, parser: Any, namespace: Any, values: Any, option_string: str | None = None) -> None:
        spelled = option_string or self.option_strings[0]
        if self.read is None:  # a bool pair: the second spelling is the --no- one
            value: Any = spelled != self.option_strings[-1]
        else:
            try:
                value = self.read(values)
            except (ValueError, argparse.ArgumentTypeError) as error:
                raise argparse.ArgumentError(None, f"argument {spelled}: {error}") from None
        setattr(namespace, self.dest, value)
        setattr(namespace, SPELLINGS, {**getattr(namespace, SPELLINGS, {}), self.dest: spelled})


class _Reader:
    """Reads a field's value from its command-line words, following the type hint."""

    def __init__(self, hint: Any, parse: Callable[[str], Any] | None, choices: tuple[str, ...]) -> None:
        self.parse, self.choices = parse, choices
        members = _members(hint)
        self.optional = type(None) in members
        self.members = [m for m in members if m is not type(None)]
        tuples = [m for m in self.members if typing.get_origin(m) is tuple]
        fixed = len(self.members) == 1 and tuples and Ellipsis not in typing.get_args(tuples[0])
        self.nargs: Any = None
        if parse is None and tuples:
            self.nargs = len(typing.get_args(tuples[0])) if fixed and not self.optional else "+"
        self.metavar: Any = _metavar(self.members[0]) if parse is None else "VALUE"
        if isinstance(self.metavar, tuple) and self.nargs != len(self.metavar):
            self.metavar = self.metavar[0]  # shown as "FLOAT [FLOAT ...]"
        if choices:
            self.metavar = "{" + ",".join(choices) + "}"

    def __call__(self, values: str | list[str]) -> Any:
        words = [values] if isinstance(values, str) else list(values)
        if self.optional and [w.lower() for w in words] == ["none"]:
            return None
        if self.parse is not None:
            return self.parse(words[0])
        for member in self.members:
            try:
                value = _read_member(member, words)
            except ValueError:
                continue
            if self.choices and value not in self.choices:
                raise ValueError(f"invalid choice {value!r}; allowed: {', '.join(self.choices)}")
            return value
        if len(self.members) == 1 and typing.get_origin(self.members[0]) is Literal and len(words) == 1:
            allowed = ", ".join(map(str, typing.get_args(self.members[0])))
            raise ValueError(f"invalid choice {words[0]!r}; allowed: {allowed}")
        wanted = [*map(_describe, self.members), *(["none"] if self.optional else [])]
        wanted = ", ".join(wanted[:-1]) + " or " + wanted[-1] if len(wanted) > 1 else wanted[0]
        raise ValueError(f"expected {wanted}, got {' '.join(words)!r}")


def _read_member(member: Any, words: list[str]) -> Any:
    """``words`` read as the type ``member``; ``ValueError`` if they do not fit it."""
    if typing.get_origin(member) is tuple:
        items = typing.get_args(member)
        if len(items) == 2 and items[1] is Ellipsis:
            return tuple(_read_word(items[0], w) for w in words)
        if len(items) != len(words):
            raise ValueError
        return tuple(_read_word(item, w) for item, w in zip(items, words, strict=True))
    if len(words) != 1:
        raise ValueError
    return _read_word(member, words[0])


def _read_word(kind: Any, word: str) -> Any:
    if typing.get_origin(kind) is Literal:
        for allowed in typing.get_args(kind):
            if word == str(allowed):
                return allowed
        raise ValueError
    if kind is float:
        value = float(word)
        if not math.isfinite(value):
            raise ValueError
        return value
    return kind(word)  # int, str, Path


def _describe(member: Any) -> str:
    """What a type accepts, for error messages: "an integer", "2 numbers"..."""
    names = {int: "an integer", float: "a number", str: "a text", Path: "a path"}
    if typing.get_origin(member) is Literal:
        return "one of " + ", ".join(map(str, typing.get_args(member)))
    if typing.get_origin(member) is tuple:
        items = typing.get_args(member)
        plural = {int: "integers", float: "numbers"}.get(items[0], "values")
        return f"one or more {plural}" if items[-1] is Ellipsis else f"{len(items)} {plural}"
    return names.get(member, member.__name__)


def _metavar(member: Any) -> str | tuple[str, ...]:
    names = {int: "INT", float: "FLOAT", str: "TEXT", Path: "PATH", dict: "JSON"}
    if typing.get_origin(member) is Literal:
        return "{" + ",".join(map(str, typing.get_args(member))) + "}"
    if typing.get_origin(member) is tuple:
        items = typing.get_args(member)
        return tuple(names.get(i, "VALUE") for i in items if i is not Ellipsis)
    return names.get(member, "VALUE")


def _members(hint: Any) -> tuple[Any, ...]:
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return typing.get_args(hint)
    return (hint,)


def _dataclass_in(hint: Any) -> type | None:
    """The dataclass of a ``C`` or ``C | None`` hint, else None."""
    found = [m for m in _members(hint) if isinstance(m, type) and dataclasses.is_dataclass(m)]
    return found[0] if found else None


def _default(cls: type, name: str) -> Any:
    field = {f.name: f for f in dataclasses.fields(cls)}[name]
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return field.default


def _dashed(key: str) -> str:
    return key.replace("_", "-")


def _typed(value: Any) -> str:
    """``value`` as it would be typed on the command line."""
    if value is None:
        return "none"
    if isinstance(value, list | tuple):
        return " ".join(_typed(v) for v in value)
    if isinstance(value, Mapping):
        return json.dumps(value)
    return str(value)
