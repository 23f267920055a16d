"""Simulated robot bodies for the pybullet world, by kind (see :mod:`sitl.bodies.registry`)."""
