"""Paper 000's physical foraging world: a fast lock-stepped pybullet arena of Pioneer-sized robots
(:mod:`sitl.foraging.world`), its sonar ring (:mod:`sitl.sensing.sonar_ring`), the harness that runs the real
fleet nodes, agents and executors in it (:mod:`sitl.foraging.harness`) and the scenario's objects and
utilities (:mod:`sitl.foraging.scenario`).  See docs/foraging.md.
"""
