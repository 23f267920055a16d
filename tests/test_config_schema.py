"""`mrta schema robot|fleet|world` (runtime/config/schema.py): a JSON Schema an editor checks YAML with.  Every shipped
config passes it, and on a config with one value changed the schema and the loader agree (the loader's checks that
need a file, a network parse or two values at once excepted)."""
from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st
from jsonschema import Draft202012Validator

from runtime.cli import main
from runtime.config import ConfigError, RobotConfig, WorldConfig, from_dict, to_dict
from runtime.config.build import _read_yaml
from runtime.config.schema_cli import kind_schema as schema
from sitl.fleet_config import FleetConfig

ROOT = Path(__file__).resolve().parents[1]
KINDS = {"robot": ("robots", RobotConfig), "world": ("worlds", WorldConfig), "fleet": ("fleets", FleetConfig)}
_validators: dict[str, Draft202012Validator] = {}


def validator(kind: str) -> Draft202012Validator:
    if kind not in _validators:
        s = schema(kind)
        Draft202012Validator.check_schema(s)          # a valid draft 2020-12 schema
        _validators[kind] = Draft202012Validator(s)
    return _validators[kind]


def shipped(kind: str) -> list[Path]:
    return sorted((ROOT / "configs" / KINDS[kind][0]).glob("*.yaml"))


@pytest.mark.parametrize("kind", list(KINDS))
def test_mrta_schema_prints_the_schema(kind, capsys):
    assert main(["schema", kind]) == 0
    assert json.loads(capsys.readouterr().out) == schema(kind)


@pytest.mark.parametrize("kind, path", [(k, p) for k in KINDS for p in shipped(k)], ids=lambda v: getattr(v, "name", v))
def test_every_shipped_config_passes_its_schema(kind, path):
    errors = [f"{'.'.join(map(str, e.path))}: {e.message}" for e in validator(kind).iter_errors(_read_yaml(path))]
    assert errors == []


def test_the_schema_names_ranges_defaults_and_each_registered_choice():
    robot = schema("robot")["properties"]
    assert robot["robot"]["title"] == "RobotIdentity" and robot["robot"]["properties"]["id"] == {"type": "integer", "minimum": 1, "maximum": 250, "default": 1}
    assert robot["comms"]["additionalProperties"] is False
    from runtime.allocation.registry import options_classes
    from runtime.drivers.registry import config_classes
    assert [b["properties"]["type"]["const"] for b in robot["base"]["oneOf"]] == list(config_classes())
    assert [b["properties"]["method"]["const"] for b in robot["allocation"]["oneOf"]] == list(options_classes())
    sizes = schema("world")["properties"]["obstacles"]["items"]["properties"]["size"]["prefixItems"]
    assert sizes[0]["exclusiveMinimum"] == 0


def test_a_section_without_its_tag_is_the_default_choice():
    v = validator("robot")
    assert v.is_valid({"base": {"port": "/dev/ttyUSB0"}})                    # create_oi, as the loader takes it
    assert not v.is_valid({"base": {"port": "/dev/ttyUSB0", "subclass": "p3dx-sh"}})   # an arcos key
    assert v.is_valid({"base": {"type": "arcos", "subclass": "p3dx-sh"}})


# --------------------------------------------------------------------------- the schema agrees with the loader

NOT_IN_SCHEMA = ("comms.unsigned_gcs",)   # parsed by the loader (a network in CIDR form); the schema says "a string"


def _leaves(data, path=()):
    if isinstance(data, dict):
        for k, v in data.items():
            yield from _leaves(v, path + (k,))
    elif isinstance(data, list) and data:
        for i, v in enumerate(data):
            yield from _leaves(v, path + (i,))
    else:
        yield path


def _set(data, path, value):
    for p in path[:-1]:
        data = data[p]
    data[path[-1]] = value


VALUES = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6),
                   st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False), st.text(max_size=5),
                   st.lists(st.integers(-5, 5), max_size=4), st.dictionaries(st.text(max_size=3), st.integers(),
                                                                            max_size=2))


@settings(max_examples=150, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_the_schema_and_the_loader_agree_on_a_changed_value(data):
    kind = data.draw(st.sampled_from(["robot", "world", "fleet"]))
    path = data.draw(st.sampled_from(shipped(kind)))
    tp = KINDS[kind][1]
    plain = to_dict(from_dict(tp, _read_yaml(path)))          # every key, defaults included
    leaves = [p for p in _leaves(plain) if not ".".join(map(str, p)).startswith(NOT_IN_SCHEMA)]
    where = data.draw(st.sampled_from(leaves))
    changed = copy.deepcopy(plain)
    if data.draw(st.booleans()):
        _set(changed, where, data.draw(VALUES))
    else:                                                     # a key the section does not know
        parent = where[:-1]
        section = changed
        for p in parent:
            section = section[p]
        if not isinstance(section, dict):
            return
        section[data.draw(st.sampled_from(["speed", "idd", "x"]))] = 1
    try:
        from_dict(tp, changed)
        loader = True
    except ConfigError:
        loader = False
    assert validator(kind).is_valid(changed) == loader, (where, changed)
