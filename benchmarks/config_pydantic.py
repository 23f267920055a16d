"""The config walker (runtime/config/build.py) against pydantic v2 on every shipped config: load time, values, errors.

pydantic is not a dependency; this measures what a port would give (docs/config.md, "Why not pydantic").  The
pydantic side is the walker's own declarations turned into pydantic models field for field (``Field(ge=, le=)``
for ``rng``, strict scalars, ``extra="forbid"``, a callable discriminator for the tagged unions, frozen), which is
what a hand port writes, so the models validate the same values; both sides start from the same YAML data (the
bounded loader stays either way).

    PYTHONPATH=. python benchmarks/config_pydantic.py [--repeat N]     # needs pydantic>=2 importable

It prints, per config: the bounded YAML loader's median time to read it (the same for both), the walker's and
pydantic's median time to build it from its data, whether both built the
same values, then the one-time costs (importing pydantic and building the models, in a fresh process each) and a
few wrong configs' messages side by side.
"""
from __future__ import annotations

import argparse
import dataclasses
import statistics
import subprocess
import sys
import time
import typing
from pathlib import Path
from typing import Annotated, Any, Literal, Optional, Union

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runtime.config import build as B  # noqa: E402

_models: dict[type, Any] = {}


def model(tp: type):
    """The pydantic model of config dataclass ``tp`` (and, recursively, of its fields' dataclasses)."""
    if tp in _models:
        return _models[tp]
    import pydantic as P

    hints = typing.get_type_hints(tp, include_extras=True)
    fields = {}
    for f in dataclasses.fields(tp):
        if f.name == "source":
            continue
        default = (f.default if f.default is not dataclasses.MISSING else
                   P.Field(default_factory=f.default_factory) if f.default_factory is not dataclasses.MISSING
                   else ...)
        tagged = f.metadata.get("tagged")
        ann = _union(tagged) if tagged else _type(hints[f.name], dict(f.metadata))
        if tagged and typing.get_origin(hints[f.name]) is tuple:
            ann = tuple[ann, ...]
        if tagged and f.default_factory is not dataclasses.MISSING:
            default = P.Field(default_factory=lambda t=tagged: model(t.choices()[t.default])())
        fields[f.name] = (ann, default)
    cfg = P.ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    _models[tp] = P.create_model(tp.__name__, __config__=cfg, **fields)
    return _models[tp]


def _type(tp: Any, meta: dict) -> Any:
    import pydantic as P

    origin = typing.get_origin(tp)
    if origin in (Union, getattr(__import__("types"), "UnionType")):
        inner = [a for a in typing.get_args(tp) if a is not type(None)]
        return Optional[_type(inner[0], meta)]
    if origin is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple[_type(args[0], meta), ...]
        metas = meta.get("items") or (meta,) * len(args)
        return tuple[tuple(_type(a, m) for a, m in zip(args, metas))]
    if dataclasses.is_dataclass(tp):
        return model(tp)
    if tp in (int, float):
        lo, hi = meta.get("lo"), meta.get("hi")
        bounds = {"gt" if meta.get("lo_open") else "ge": lo} if lo is not None else {}
        if hi is not None:
            bounds["le"] = hi
        return Annotated[tp, P.Strict(), P.Field(**bounds)]
    if tp in (bool, str):
        check = meta.get("check")
        if check:
            return Annotated[tp, P.Strict(), P.AfterValidator(lambda v, c=check[0]: (c(v), v)[1])]
        return Annotated[tp, P.Strict()]
    if origin is Literal:
        return tp
    raise TypeError(tp)


def _union(tagged: B.Tagged) -> Any:
    import pydantic as P

    members = tuple(Annotated[model(cls), P.Tag(name)] for name, cls in tagged.choices().items())
    pick = (lambda v, t=tagged: v.get(t.tag, t.default) if isinstance(v, dict) else getattr(v, t.tag, None))
    return Annotated[Union[members], P.Discriminator(pick)]


# the walker's phrases for pydantic's error types: what keeping tests/test_config.py's messages would take
PHRASES = {"greater_than_equal": "a number in [{ge}, {le}]", "less_than_equal": "a number in [{ge}, {le}]",
           "greater_than": "a number in ({gt}, {le}]", "int_type": "an integer", "float_type": "a number",
           "bool_type": "true/false", "string_type": "a string", "missing": "a value (required)",
           "extra_forbidden": "no such key", "tuple_type": "a list", "literal_error": "one of {expected}",
           "union_tag_invalid": "one of {expected_tags}", "model_type": "a mapping", "finite_number": "a number",
           "too_short": "a list of {min_length}", "too_long": "a list of {max_length}"}


def pydantic_message(exc, file: str) -> str:
    """The first error of a pydantic ValidationError in the walker's one-line form (file: dotted key: expected)."""
    err = exc.errors()[0]
    key = ""
    for part in err["loc"]:
        key += f"[{part}]" if isinstance(part, int) else (f".{part}" if key else str(part))
    ctx = {"ge": "", "le": "", "gt": "", **(err.get("ctx") or {})}
    phrase = PHRASES.get(err["type"], err["type"]).format(**ctx)
    return f"{file}: {key}: expected {phrase}, got {B.short_repr(err['input'])}"


def timed(fn, repeat: int) -> float:
    runs = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        runs.append(time.perf_counter() - t)
    return statistics.median(runs)


def fresh(code: str) -> float:
    """Median of 5 fresh processes' time (ms) for ``code``'s printed figure."""
    out = [float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                                cwd=ROOT).stdout) for _ in range(5)]
    return statistics.median(out)


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=50)
    args = ap.parse_args(argv)
    from runtime.config import RobotConfig, WorldConfig
    from sitl.fleet_config import FleetConfig

    kinds = {"robots": RobotConfig, "worlds": WorldConfig, "fleets": FleetConfig}
    print(f"{'config':38} {'read ms':>8} {'walker ms':>10} {'pydantic ms':>12}  same values")
    totals = [0.0, 0.0, 0.0]
    for kind, tp in kinds.items():
        m = model(tp)
        for path in sorted((ROOT / "configs" / kind).glob("*.yaml")):
            data = B._read_yaml(path)
            r = timed(lambda: B._read_yaml(path), args.repeat)
            w = timed(lambda: B._build(tp, data, str(path), ""), args.repeat)
            p = timed(lambda: m.model_validate(data), args.repeat)
            same = B.to_dict(B._build(tp, data, str(path), "")) == _plain(m.model_validate(data).model_dump())
            totals[0] += w
            totals[1] += p
            totals[2] += r
            print(f"{kind + '/' + path.name:38} {r * 1e3:8.3f} {w * 1e3:10.3f} {p * 1e3:12.3f}  {same}")
    print(f"{'all ' + str(sum(1 for k in kinds for _ in (ROOT / 'configs' / k).glob('*.yaml'))) + ' configs':38} "
          f"{totals[2] * 1e3:8.3f} {totals[0] * 1e3:10.3f} {totals[1] * 1e3:12.3f}")
    registries = ("from runtime.drivers.registry import config_classes as a; "
                  "from runtime.allocation.registry import options_classes as b; "
                  "from sitl.scenarios import config_classes as c; a(); b(); c(); ")
    imp = fresh("import time; t = time.perf_counter(); import pydantic, pydantic_core; "
                "from pydantic import BaseModel, Field, create_model; print((time.perf_counter() - t) * 1e3)")
    build = fresh("import sys, time; sys.path.insert(0, 'benchmarks'); import config_pydantic as m, pydantic; "
                  "from runtime.config import RobotConfig, WorldConfig; from sitl.fleet_config import FleetConfig; "
                  + registries + "t = time.perf_counter(); [m.model(x) for x in (RobotConfig, WorldConfig, "
                  "FleetConfig)]; print((time.perf_counter() - t) * 1e3)")
    first = fresh("import time; from runtime.config import RobotConfig, build; " + registries +
                  "d = build._read_yaml('configs/robots/create2.yaml'); t = time.perf_counter(); "
                  "build._build(RobotConfig, d, 'x', ''); print((time.perf_counter() - t) * 1e3)")
    print(f"one-time, in a fresh process (median of 5; the registries' modules imported before either is timed): "
          f"import pydantic {imp:.0f} ms, build the robot, world and fleet models {build:.0f} ms; the walker's "
          f"first build of configs/robots/create2.yaml {first:.1f} ms")
    bad = {"robot.id 300": {"robot": {"id": 300}}, "robot.idd": {"robot": {"idd": 1}},
           "control.rate '5'": {"control": {"rate": "5"}}, "base.type roomba": {"base": {"type": "roomba"}},
           "localization.initial_pose [1, 2]": {"localization": {"initial_pose": [1, 2]}},
           "comms.unsigned_gcs ['x']": {"comms": {"unsigned_gcs": ["x"]}}}
    import pydantic as P
    for what, data in bad.items():
        try:
            B._build(RobotConfig, data, "r.yaml", "")
        except B.ConfigError as exc:
            print(f"{what}\n  walker:   {exc}")
        try:
            model(RobotConfig).model_validate(data)
        except P.ValidationError as exc:
            print(f"  pydantic: {pydantic_message(exc, 'r.yaml')}")
    return 0


def _plain(v):
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    return v


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
