"""`mrta schema robot|fleet|world`: the JSON Schema of a config (:mod:`runtime.config.schema`), for an editor's YAML
language server (docs/config.md)."""
from __future__ import annotations

import argparse
import importlib
import json

from runtime.errors import InputError

# kind -> (its config class, what it is).  By name, as runtime/cli.py names commands: fleet configs are the
# simulator's (sitl/fleet_config.py), which nothing under runtime/ imports
KINDS = {
    "robot": ("runtime.config.robot:RobotConfig", "an mrta robot config (mrta daemon ROBOT.yaml)"),
    "fleet": ("sitl.fleet_config:FleetConfig", "an mrta SITL fleet config (mrta sitl run FLEET.yaml)"),
    "world": ("runtime.config.world:WorldConfig", "an mrta world config (an arena, its obstacles, the datum)"),
}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("schema", help="print the JSON Schema of a robot, fleet or world config",
                       description="Print the JSON Schema (draft 2020-12) of a config kind, made from the same "
                                   "declarations the configs are loaded with: e.g. mrta schema robot > "
                                   "robot.schema.json, then '# yaml-language-server: $schema=robot.schema.json' "
                                   "as a YAML file's first line (docs/config.md).")
    p.add_argument("kind", choices=list(KINDS), help="which config")
    p.set_defaults(func=_main)


def kind_schema(kind: str) -> dict:
    """The JSON Schema of config ``kind`` (a key of :data:`KINDS`)."""
    from runtime.config.schema import schema

    where, title = KINDS[kind]
    module, _, name = where.partition(":")
    try:
        tp = getattr(importlib.import_module(module), name)
    except ImportError as exc:
        raise InputError(f"schema: {kind} configs need {exc.name}, which is not installed") from None
    return schema(tp, title)


def _main(args) -> int:
    print(json.dumps(kind_schema(args.kind), indent=2))
    return 0
