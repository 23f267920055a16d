"""SITL scenarios by ``scenario.type``: the only list of them.

A scenario module has ``Config`` (the fleet config's ``scenario:`` section, with a ``check(fleet, world, file)``
that raises ConfigError) and ``Scenario`` (built from the fleet; says what the operator hands the fleet
and when, when the run's goal is met, and prints the summary; ``build(world)``, if it has one, adds its bodies to
the pybullet world).  A scenario that reacts to the run has
``on_poll(run, now)``, called after each operator poll; it returns what the launcher must do: hand-overs to add
(:class:`~sitl.scenarios.base.Handover`) and ``("kill", robot)`` (that robot's daemon dies).  A new scenario is
one module plus one line.
"""
from __future__ import annotations

import importlib

SCENARIOS: dict[str, str] = {
    "formation": "sitl.scenarios.formation",     # paper 002: robots take up formation positions
    "mission": "sitl.scenarios.mission",         # tasks handed in over time, by an operator or a timetable
    "foraging": "sitl.scenarios.foraging",       # paper 000: objects carried to a delivery point, replaced
    "surveillance": "sitl.scenarios.surveillance",   # paper 003: a region surveyed with a borrowed sensor
}


def module(name: str):
    return importlib.import_module(SCENARIOS[name])


def config_classes() -> dict[str, type]:
    return {name: module(name).Config for name in SCENARIOS}
