"""Typed configuration: robots, fleets and worlds in YAML (see :mod:`runtime.config.build`)."""
from runtime.config.build import (ConfigError, Tagged, deep_merge, from_dict, load, parse_hostport, rng,  # noqa: F401
                                  short_repr, to_dict, union_field)
from runtime.config.robot import (CommsConfig, ControlConfig, GpsConfig, LocalizationConfig, Peer,  # noqa: F401
                                  PlanningConfig, RobotConfig, RobotIdentity, load_robot)
from runtime.config.validate import validate as validate_robot  # noqa: F401
from runtime.config.world import Box, Datum, WorldConfig, load_world  # noqa: F401
