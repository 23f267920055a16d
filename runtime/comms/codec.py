"""Message dataclasses <-> MAVLink messages of the private dialect.

Generic over a registry: each dataclass maps to the MAVLink message ``MRTA_<SNAKE_NAME>``
(``TaskInfo`` -> ``MRTA_TASK_INFO``) whose fields carry the dataclass fields by name, except that
``sender`` is the MAVLink header's source system id and ``dest`` is the ``target_system`` field.
Field types: bool, int, float, and ``tuple[int, ...]`` (lists of robot or task ids), which travel as
MAVLink arrays padded with zeros (ids are never 0), so a list ends at its first 0.

Validation happens once, here: a dataclass may define ``invalid(self) -> str | None`` (why the message
cannot be acted on, or None); :func:`from_mavlink` raises :class:`InvalidMessage` for such a message, so
handlers trust what they get.  The fleet's classes (the runtime's own, :mod:`runtime.messages`,
and each registered allocation method's ``Method.messages``) are registered on first use.
"""
from __future__ import annotations

import dataclasses
import re
import struct
import sys
import typing
from dataclasses import dataclass
from types import ModuleType

_RESERVED = ("sender", "dest")
IDS = tuple[int, ...]                  # the one array type: robot or task ids


class InvalidMessage(ValueError):
    """A decoded message whose values the protocol does not allow (``str()``: why)."""


@dataclass(frozen=True)
class WireMapping:
    cls: type
    name: str                          # MAVLink message name, e.g. "MRTA_BID"
    fields: tuple[str, ...]            # dataclass fields carried in the payload (not sender/dest)
    kinds: tuple[type, ...]            # bool, int, float or IDS per field


_by_class: dict[type, WireMapping] = {}
_by_name: dict[str, WireMapping] = {}
_classes: dict[tuple[str, str], type] = {}      # (generated module name, message name) -> class
_modules: dict[type, ModuleType] = {}           # MAVLink (sub)class -> its generated module


def wire_name(cls: type) -> str:
    """``TaskInfo`` -> ``MRTA_TASK_INFO``."""
    return "MRTA_" + re.sub(r"(?<!^)(?=[A-Z])", "_", cls.__name__).upper()


_fleet_registered = False


def register_fleet() -> None:
    """Register the runtime's own message classes and every registered allocation method's (once)."""
    global _fleet_registered
    if _fleet_registered:
        return
    _fleet_registered = True
    from runtime.allocation.registry import all_methods
    from runtime.messages import FLEET_MESSAGES

    for cls in FLEET_MESSAGES:
        register(cls)
    for method in all_methods():
        for cls in method.messages:
            if cls not in _by_class:
                register(cls)


def register(cls: type, name: str | None = None) -> WireMapping:
    """Map dataclass ``cls`` to MAVLink message ``name`` (default :func:`wire_name`)."""
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls!r} is not a dataclass")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    missing = [r for r in _RESERVED if r not in names]
    if missing:
        raise TypeError(f"{cls.__name__}: agent messages need fields {', '.join(missing)}")
    fields = tuple(n for n in names if n not in _RESERVED)
    kinds = []
    for n in fields:
        kind = hints[n]
        if kind not in (bool, int, float, IDS):
            raise TypeError(f"{cls.__name__}.{n}: wire fields must be bool, int, float or tuple[int, ...], "
                            f"got {kind!r}")
        kinds.append(kind)
    m = WireMapping(cls, name or wire_name(cls), fields, tuple(kinds))
    _by_class[cls] = m
    _by_name[m.name] = m
    return m


def unregister(cls: type) -> None:
    """Forget ``cls`` (tests that register a message of a temporary dialect)."""
    m = _by_class.pop(cls, None)
    if m is not None and _by_name.get(m.name) is m:
        del _by_name[m.name]


def mappings() -> tuple[WireMapping, ...]:
    register_fleet()
    return tuple(_by_class.values())


def check(module: ModuleType, classes=None) -> None:
    """Raise ``ValueError`` unless every registered class (or each of ``classes``) has a matching message in
    ``module``."""
    register_fleet()
    for m in (_by_class.values() if classes is None else [_by_class[c] for c in classes]):
        msgid = getattr(module, f"MAVLINK_MSG_ID_{m.name}", None)
        if msgid is None:
            raise ValueError(f"dialect has no message {m.name} for {m.cls.__name__}")
        wire = set(module.mavlink_map[msgid].fieldnames)
        want = set(m.fields) | {"target_system"}
        if wire != want:
            raise ValueError(f"{m.name}: wire fields {sorted(wire)} do not match {m.cls.__name__} "
                             f"fields {sorted(want)}")


def to_mavlink(msg, module: ModuleType):
    """The dialect's MAVLink message object for ``msg``.  Raises ValueError for an id list longer than its
    array."""
    register_fleet()
    m = _by_class.get(type(msg))
    if m is None:
        raise TypeError(f"{type(msg).__name__} is not a registered agent message")
    cls = _classes.get((module.__name__, m.name))
    if cls is None:
        cls = _classes[(module.__name__, m.name)] = module.mavlink_map[getattr(module, f"MAVLINK_MSG_ID_{m.name}")]
    kwargs = {"target_system": int(msg.dest)}
    for name, kind in zip(m.fields, m.kinds):
        v = getattr(msg, name)
        if kind == IDS:
            size = _array_length(cls, name)
            ids = [int(i) for i in v]
            if len(ids) > size or 0 in ids:
                raise ValueError(f"{type(msg).__name__}.{name}: expected at most {size} non-zero ids, got {ids}")
            kwargs[name] = ids + [0] * (size - len(ids))
        else:
            kwargs[name] = float(v) if kind is float else int(v)
    return cls(**kwargs)


def _array_length(mavcls, name: str) -> int:
    return mavcls.array_lengths[mavcls.ordered_fieldnames.index(name)]


def encode(msg, mav) -> bytes:
    """One MAVLink 2 frame for ``msg``, packed (and signed, if ``mav`` signs) by pymavlink.

    ``mav`` is a generated ``MAVLink`` object; its ``srcSystem`` is the sender on the wire.
    Raises ``ValueError`` naming the message if a field does not fit its wire type.
    """
    mavmsg = to_mavlink(msg, _module_of(mav))
    try:
        frame = mavmsg.pack(mav)
    except struct.error as e:  # an integer outside its wire type
        raise ValueError(f"{type(msg).__name__}: cannot encode {msg!r}: {e}") from None
    mav.seq = (mav.seq + 1) % 256
    return frame


def from_mavlink(mavmsg):
    """The dataclass for a decoded MAVLink message, or None if it is not one of ours.  Raises
    :class:`InvalidMessage` if the class's ``invalid()`` finds a value the protocol does not allow."""
    register_fleet()
    m = _by_name.get(mavmsg.get_type())
    if m is None:
        return None
    kwargs = {"sender": mavmsg.get_srcSystem(), "dest": int(mavmsg.target_system)}
    for name, kind in zip(m.fields, m.kinds):
        v = getattr(mavmsg, name)
        if kind == IDS:
            v = list(v)
            kwargs[name] = tuple(int(i) for i in (v[:v.index(0)] if 0 in v else v))
        else:
            kwargs[name] = bool(v) if kind is bool else kind(v)
    msg = m.cls(**kwargs)
    check_msg = getattr(msg, "invalid", None)
    if check_msg is not None:
        why = check_msg()
        if why:
            raise InvalidMessage(f"{type(msg).__name__} from {msg.sender}: {why}")
    return msg


def is_agent(mavmsg) -> bool:
    register_fleet()
    return mavmsg.get_type() in _by_name


def _module_of(mav) -> ModuleType:
    """The generated module that defines ``mav``'s class (or a class it derives from)."""
    mod = _modules.get(type(mav))
    if mod is not None:
        return mod
    for klass in type(mav).__mro__:
        mod = sys.modules.get(klass.__module__)
        if mod is not None and hasattr(mod, "mavlink_map"):
            _modules[type(mav)] = mod
            return mod
    raise TypeError(f"{type(mav).__name__} is not a generated pymavlink MAVLink class")

