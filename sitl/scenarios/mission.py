"""Mission: tasks handed in over time, each at its ``at`` second of sim time, to a robot over the MAVLink
mission protocol, as an operator would; the goal is met when every task handed in is done.  With
``wait: true`` the fleet keeps running for an operator (``mrta mission upload``, a ground station) until
the timeout or Ctrl-C."""
from __future__ import annotations

import dataclasses
import functools
import typing
from dataclasses import dataclass
from typing import Any, Literal, Optional

from runtime import tasks as T
from runtime.config.build import ConfigError, Tagged, rng


@functools.lru_cache(maxsize=None)
def _entry_class(kind: str) -> type:
    """``{kind, at, to}`` plus the kind's spec fields: one task of the timetable."""
    spec = T.kind(kind).Spec
    hints = typing.get_type_hints(spec)
    fields = [("kind", Literal[kind], dataclasses.field(default=kind)),
              ("at", float, dataclasses.field(default=0.0, metadata=rng(0.0, None))),
              ("to", Optional[int], dataclasses.field(default=None))]
    for f in dataclasses.fields(spec):
        default = (dataclasses.field(default=f.default, metadata=f.metadata) if f.default is not dataclasses.MISSING
                   else dataclasses.field(metadata=f.metadata))
        fields.append((f.name, hints[f.name], default))
    # fields without defaults must come first
    fields.sort(key=lambda f: f[2].default is not dataclasses.MISSING)

    def spec_of(self):
        return spec(**{f.name: getattr(self, f.name) for f in dataclasses.fields(spec)})

    return dataclasses.make_dataclass(f"{spec.__name__}Entry", fields, frozen=True, namespace={"spec": spec_of})


def _entries() -> dict[str, type]:
    return {name: _entry_class(name) for name in T.KINDS}


@dataclass(frozen=True)
class Config:
    type: Literal["mission"] = "mission"
    tasks: tuple[Any, ...] = dataclasses.field(default=(), metadata={"tagged": Tagged("kind", _entries, "goto")})
    to: Optional[int] = None            # robot the operator uploads to (null: the lowest id); a task may say
    wait: bool = False                  # keep running for an operator once the listed tasks are done

    def check(self, fleet, file: str) -> None:
        ids = {r.id for r in fleet.robots}
        for i, t in enumerate(self.tasks):
            to = t.to if t.to is not None else self.to
            if to is not None and to not in ids:
                raise ConfigError(file, f"scenario.tasks[{i}].to", "the id of a robot of the fleet", to)
        if self.to is not None and self.to not in ids:
            raise ConfigError(file, "scenario.to", "the id of a robot of the fleet", self.to)
        if not self.tasks and not self.wait:
            raise ConfigError(file, "scenario.tasks", "at least one task (or wait: true for an operator)")
