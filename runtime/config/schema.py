"""JSON Schema (draft 2020-12) of a config, read from the same dataclass declarations the walker builds configs with
(:mod:`runtime.config.build`): a field's type, its range (``rng``), its default, the keys a section knows, and the
tagged unions (``base.type``, ``allocation.method``, ``scenario.type``, a mission's task ``kind``) with one branch per
registered choice.  A section added to a config, or a driver or method added to its registry, is in the schema with
no further code.

The schema checks what the walker checks; what needs more than one value or a file (a peer that is the robot
itself, a map's size against its resolution, a point inside the arena, a key file) is left to ``mrta daemon
--check`` and the loaders.  ``mrta schema robot|fleet|world`` prints it (:mod:`runtime.config.schema_cli`; docs/config.md: an editor using
it).
"""
from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any, Literal

from runtime.config.build import Tagged, hints, to_dict

DRAFT = "https://json-schema.org/draft/2020-12/schema"


def schema(tp: type, title: str) -> dict:
    """The JSON Schema of configs of class ``tp`` (RobotConfig, WorldConfig, FleetConfig)."""
    return {"$schema": DRAFT, **of_dataclass(tp), "title": title}


def of_dataclass(tp: type) -> dict:
    """An object with the dataclass's fields as properties, no other keys; fields without a default required."""
    props, required = {}, []
    th = hints(tp)
    for f in dataclasses.fields(tp):
        if f.name == "source":
            continue
        tagged = f.metadata.get("tagged")
        if tagged is not None:
            sub = of_union(tagged)
            if typing.get_origin(th[f.name]) is tuple:
                sub = {"type": "array", "items": sub}
        else:
            sub = of_type(th[f.name], dict(f.metadata))
        if f.default is not dataclasses.MISSING:
            sub["default"] = to_dict(f.default)
        elif f.default_factory is not dataclasses.MISSING:
            sub["default"] = to_dict(f.default_factory())
        else:
            required.append(f.name)
        props[f.name] = sub
    out = {"title": tp.__name__, "type": "object", "properties": props, "additionalProperties": False}
    if required:
        out["required"] = required
    doc = (tp.__doc__ or "").strip()
    if doc and not doc.startswith(f"{tp.__name__}("):          # not the signature dataclass writes
        out["description"] = " ".join(doc.split("\n\n")[0].split())
    return out


def of_union(tagged: Tagged) -> dict:
    """One branch per choice, told apart by the tag's value; the default choice's branch also takes no tag."""
    branches = []
    for name, cls in tagged.choices().items():
        branch = of_dataclass(cls)
        branch["properties"][tagged.tag] = {"const": name}
        if name != tagged.default:
            branch["required"] = sorted(set(branch.get("required", [])) | {tagged.tag})
        branches.append(branch)
    return {"type": "object", "oneOf": branches}


def of_type(tp: Any, meta: dict) -> dict:
    """The schema of one field's type, with its range (``rng`` metadata) on numbers."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in typing.get_args(tp) if a is not type(None)]
        return {"anyOf": [of_type(inner[0], meta), {"type": "null"}]}
    if origin is Literal:
        return {"enum": list(typing.get_args(tp))}
    if origin is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return {"type": "array", "items": of_type(args[0], meta)}
        metas = meta.get("items") or (meta,) * len(args)
        return {"type": "array", "prefixItems": [of_type(a, m) for a, m in zip(args, metas)],
                "minItems": len(args), "maxItems": len(args)}
    if dataclasses.is_dataclass(tp):
        return of_dataclass(tp)
    if tp in (int, float):
        out: dict = {"type": "integer" if tp is int else "number"}
        lo, hi = meta.get("lo"), meta.get("hi")
        if lo is not None:
            out["exclusiveMinimum" if meta.get("lo_open") else "minimum"] = lo
        if hi is not None:
            out["maximum"] = hi
        return out
    if tp is bool:
        return {"type": "boolean"}
    if tp is str:
        check = meta.get("check")
        return {"type": "string", "description": check[1]} if check else {"type": "string"}
    raise TypeError(f"no JSON Schema for config type {tp!r}")
