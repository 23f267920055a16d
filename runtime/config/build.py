"""Building typed configs from YAML: the schema walker, its errors, and tagged unions.

Every config is a tree of frozen dataclasses.  ``_build`` walks the YAML against the dataclass
fields and raises :class:`ConfigError` naming the file, the dotted key and what was expected, so
the CLI can print one line and exit 2.  Ranges and choices live in field metadata::

    speed: float = field(default=0.3, metadata=rng(0.0, 0.5))

and so does a string's parser (applied to each string of a list too)::

    nets: tuple[str, ...] = field(default=(), metadata={"check": (parse_network, "a network in CIDR form")})

A field may hold one of several dataclasses chosen by a key of its own mapping (a tagged union), e.g.
``base: {type: create_oi, ...}`` or ``allocation: {method: bs, ...}``.  The choices come from a
registry (a callable returning ``{tag value: dataclass}``, called when a config is built, so the list
of drivers or methods exists once, in its registry); a wrong tag names the allowed values::

    base: Any = union_field("type", drivers.registry.config_classes, default="create_oi")
"""
from __future__ import annotations

import dataclasses
import functools
import math
import sys
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Literal, Mapping

import yaml

from runtime.errors import InputError


class ConfigError(InputError):
    """A config value is missing or wrong; ``str()`` is the one line a person sees."""

    def __init__(self, file: str | Path, key: str, expected: str, got: Any = dataclasses.MISSING):
        self.file, self.key, self.expected = str(file), key, expected
        msg = f"{file}: {key}: expected {expected}" if key else f"{file}: expected {expected}"
        if got is not dataclasses.MISSING:
            msg += f", got {short_repr(got)}"
        super().__init__(msg)


class _Full(Exception):
    pass


def short_repr(value: Any, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters (then ``...``), at a cost bounded by ``limit``: a list of a
    billion shared elements, a self-containing list or a 5000-digit integer is never formatted whole."""
    out: list[str] = []
    room = limit + 1

    def emit(text: str) -> None:
        nonlocal room
        out.append(text[:room])
        room -= len(text)
        if room <= 0:
            raise _Full

    def walk(v: Any) -> None:
        if isinstance(v, (list, tuple)):
            emit("[" if isinstance(v, list) else "(")
            for i, e in enumerate(v):
                if i:
                    emit(", ")
                walk(e)
            emit("]" if isinstance(v, list) else ("," if len(v) == 1 else "") + ")")
        elif isinstance(v, dict):
            emit("{")
            for i, (k, e) in enumerate(v.items()):
                emit(", " if i else "")
                walk(k)
                emit(": ")
                walk(e)
            emit("}")
        elif isinstance(v, str):
            emit(repr(v[:room]))
        elif isinstance(v, int) and v.bit_length() > 256:
            emit(f"<an integer of {int(v.bit_length() * math.log10(2)) + 1} digits>")
        else:
            emit(repr(v))

    try:
        walk(value)
    except _Full:
        pass
    shown = "".join(out)
    return shown[:limit] + "..." if len(shown) > limit else shown


def rng(lo: float | None = None, hi: float | None = None, **extra: Any) -> dict:
    """Field metadata: numeric range, inclusive (``lo_open=True``: the low end excluded).  On a fixed-length tuple it
    holds for every element, unless ``items`` gives one range per element."""
    return {"lo": lo, "hi": hi, **extra}


@dataclass(frozen=True)
class Tagged:
    """A tagged union: the mapping's key ``tag`` picks the dataclass from ``choices()``."""
    tag: str
    choices: Callable[[], Mapping[str, type]]
    default: str

    def pick(self, value: Any, file: str, key: str) -> type:
        if not isinstance(value, dict):
            raise ConfigError(file, key, "a mapping", value)
        name = value.get(self.tag, self.default)
        if name is None:
            raise ConfigError(file, f"{key}.{self.tag}" if key else self.tag,
                              "one of " + "|".join(self.choices()) + " (required)")
        options = self.choices()
        if not isinstance(name, str) or name not in options:
            raise ConfigError(file, f"{key}.{self.tag}" if key else self.tag, "one of " + "|".join(options), name)
        return options[name]


def union_field(tag: str, choices: Callable[[], Mapping[str, type]], default: str | None) -> Any:
    """A dataclass field holding one of ``choices()`` picked by ``tag`` (absent: ``default``'s defaults;
    ``default`` None: the section is required).  Each choice is a frozen dataclass whose own ``tag`` field
    is a one-value Literal."""
    t = Tagged(tag, choices, default)
    if default is None:
        return field(metadata={"tagged": t})
    return field(default_factory=lambda: t.choices()[t.default](), metadata={"tagged": t})


# --------------------------------------------------------------------------- builder

@functools.cache
def hints(tp: type) -> dict[str, Any]:
    """``typing.get_type_hints(tp)``, evaluated once per config class (evaluating the annotations was 70 % of
    building a robot config: docs/config.md)."""
    return typing.get_type_hints(tp)


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin is Literal:
        return "one of " + "|".join(map(str, typing.get_args(tp)))
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in typing.get_args(tp))
    if origin is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {_type_name(args[0])}"
        return f"a list of {len(args)} numbers" if all(a in (float, int) for a in args) else "a list"
    if dataclasses.is_dataclass(tp):
        return "a mapping"
    if tp is type(None):
        return "null"
    return {float: "a number", int: "an integer", str: "a string", bool: "true/false"}.get(tp, str(tp))


def _build(tp: Any, value: Any, file: str, key: str, meta: dict | None = None) -> Any:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _build(inner[0], value, file, key, meta)
    if origin is Literal:
        if value not in typing.get_args(tp):
            raise ConfigError(file, key, _type_name(tp), value)
        return value
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(file, key, _type_name(tp), value)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_build(args[0], v, file, f"{key}[{i}]", meta) for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(file, key, _type_name(tp), value)
        metas = (meta or {}).get("items") or (meta,) * len(args)
        return tuple(_build(a, v, file, f"{key}[{i}]", m) for i, (a, v, m) in enumerate(zip(args, value, metas)))
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(file, key, "a mapping", value)
        fields = {f.name: f for f in dataclasses.fields(tp) if f.name != "source"}
        for k in value:
            if k not in fields:
                shown = k if isinstance(k, str) and k.isprintable() and k.strip() == k and k else repr(k)
                raise ConfigError(file, f"{key}.{shown}" if key else shown,
                                  "no such key (known: " + ", ".join(fields) + ")")
        kwargs = {}
        th = hints(tp)
        for name, f in fields.items():
            sub = f"{key}.{name}" if key else name
            tagged = f.metadata.get("tagged")
            if tagged is not None and name in value:
                v = value[name]
                if typing.get_origin(th[name]) is tuple:          # a list of union members
                    if not isinstance(v, (list, tuple)):
                        raise ConfigError(file, sub, "a list of mappings", v)
                    kwargs[name] = tuple(_build(tagged.pick(e, file, f"{sub}[{i}]"), e, file, f"{sub}[{i}]")
                                         for i, e in enumerate(v))
                else:
                    kwargs[name] = _build(tagged.pick(v, file, sub), v, file, sub)
            elif name in value:
                kwargs[name] = _build(th[name], value[name], file, sub, dict(f.metadata))
            elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                what = (f"a mapping with {tagged.tag}: one of {'|'.join(tagged.choices())}" if tagged
                        else _type_name(th[name]))
                raise ConfigError(file, sub, f"{what} (required)")
        if "source" in {f.name for f in dataclasses.fields(tp)}:
            kwargs["source"] = file
        return tp(**kwargs)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(file, key, "true/false", value)
        return value
    if tp in (int, float):
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        try:
            if ok and (not math.isfinite(value) or (tp is int and not float(value).is_integer())):
                ok = False
        except OverflowError:            # an integer too large for a float
            raise ConfigError(file, key, f"{_type_name(tp)} (at most {sys.float_info.max:.3g})", value) from None
        if not ok:
            raise ConfigError(file, key, _type_name(tp), value)
        value = tp(value)
        lo, hi, lo_open = (meta or {}).get("lo"), (meta or {}).get("hi"), (meta or {}).get("lo_open", False)
        if (lo is not None and (value <= lo if lo_open else value < lo)) or (hi is not None and value > hi):
            raise ConfigError(file, key, f"a number in {'(' if lo_open else '['}{lo}, {hi}]", value)
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(file, key, "a string", value)
        check = (meta or {}).get("check")       # (parse, what is expected): parse raises ValueError saying why
        if check is not None:
            try:
                check[0](value)
            except ValueError as exc:
                raise ConfigError(file, key, f"{check[1]} ({exc})", value) from None
        return value
    raise TypeError(f"unsupported config type {tp!r} at {key}")


MAX_BYTES = 1 << 20        # a config file's size
MAX_DEPTH = 32             # levels of nesting
MAX_VALUES = 500_000       # values (scalars, lists, mappings) once aliases are expanded
MAX_INT_CHARS = 1000       # characters of an integer literal (Python refuses > 4300 digits; base 60 is slow)


class _Refused(Exception):
    """A document the bounded loader will not load: ``expected`` at ``mark``."""

    def __init__(self, mark, expected: str):
        super().__init__(expected)
        self.mark, self.expected = mark, expected


class _BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader with bounded cost: it counts, while composing, the values each node stands for once
    aliases are expanded (a few hundred bytes of nested aliases can stand for 10^9 values) and refuses
    documents above :data:`MAX_VALUES`, nested deeper than :data:`MAX_DEPTH`, with an alias to a collection
    that contains it, or with an integer literal longer than :data:`MAX_INT_CHARS`.  Values that a tag's
    constructor cannot build (a date 2020-13-45) are refused at their line."""

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0
        self._values: dict[int, int] = {}      # id(node) -> values it stands for, once composed

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            mark = self.peek_event().start_mark
            node = super().compose_node(parent, index)
            if id(node) not in self._values:
                raise _Refused(mark, "no alias inside the collection it names (a recursive alias)")
            return node
        self._depth += 1
        if self._depth > MAX_DEPTH:
            raise _Refused(self.peek_event().start_mark, f"at most {MAX_DEPTH} levels of nesting")
        try:
            node = super().compose_node(parent, index)
        finally:
            self._depth -= 1
        if isinstance(node, yaml.SequenceNode):
            count = 1 + sum(self._values[id(n)] for n in node.value)
        elif isinstance(node, yaml.MappingNode):
            count = 1 + sum(self._values[id(k)] + self._values[id(v)] for k, v in node.value)
        else:
            count = 1
            if node.tag == "tag:yaml.org,2002:int" and len(node.value) > MAX_INT_CHARS:
                raise _Refused(node.start_mark, f"an integer of at most {MAX_INT_CHARS} characters")
        if count > MAX_VALUES:
            raise _Refused(node.start_mark, f"at most {MAX_VALUES} values once aliases are expanded")
        self._values[id(node)] = count
        return node

    def construct_object(self, node, deep=False):
        try:
            return super().construct_object(node, deep)
        except (ValueError, OverflowError) as exc:       # e.g. a timestamp with month 13
            raise _Refused(node.start_mark, f"a value its tag allows ({str(exc).splitlines()[0][:60]})") from None


def _read_yaml(path: str | Path) -> Any:
    """The YAML document in ``path`` (an empty one: ``{}``) at bounded cost, or ConfigError naming the file and
    line: not readable, larger than :data:`MAX_BYTES`, not UTF-8, not valid YAML, or refused by
    :class:`_BoundedLoader`."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            raw = fh.read(MAX_BYTES + 1)
    except OSError as exc:
        raise ConfigError(path, "", f"a readable YAML file ({exc.strerror})") from None
    if len(raw) > MAX_BYTES:
        raise ConfigError(path, "", f"a YAML file of at most {MAX_BYTES} bytes")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise ConfigError(path, f"line {line}", f"UTF-8 text (byte {raw[exc.start]:#04x} is not)") from None
    loader = None
    try:
        loader = _BoundedLoader(text)          # checks the characters at once: a NUL is a YAMLError here
        node = loader.get_single_node()
        return (loader.construct_document(node) if node is not None else None) or {}
    except _Refused as exc:
        raise ConfigError(path, f"line {exc.mark.line + 1}" if exc.mark else "document", exc.expected) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark else "document"
        raise ConfigError(path, where, "valid YAML") from None
    finally:
        if loader is not None:
            loader.dispose()


def from_dict(tp: type, data: Any, file: str = "<dict>") -> Any:
    """Build a config dataclass from plain data (as loaded from YAML)."""
    return _build(tp, data, file, "")


def load(tp: type, path: str | Path) -> Any:
    return _build(tp, _read_yaml(path), str(path), "")


def deep_merge(a: Any, b: Any) -> Any:
    """Return ``a`` with mappings in ``b`` merged in (``b`` wins)."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = dict(a)
        for k, v in b.items():
            out[k] = deep_merge(a.get(k), v) if k in a else v
        return out
    return b


def to_dict(cfg: Any) -> Any:
    """Plain data for a config (inverse of :func:`from_dict`, ``source`` dropped)."""
    if dataclasses.is_dataclass(cfg):
        return {f.name: to_dict(getattr(cfg, f.name)) for f in dataclasses.fields(cfg) if f.name != "source"}
    if isinstance(cfg, tuple):
        return [to_dict(v) for v in cfg]
    return cfg


def parse_hostport(text: str, file: str = "<arg>", key: str = "address") -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not (port.isascii() and port.isdigit()) or not (0 < int(port) < 65536):
        raise ConfigError(file, key, "host:port with port in 1..65535", text)
    return host, int(port)
