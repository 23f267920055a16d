"""Speed of paper 000's foraging runs: one 3600 s (30,000 tu) run of 10 robots and 3 objects in the fast
foraging world, agents and executors included, beside the same scenario in pybullet's default settings.

Target: the 3600 s run in under 30 s of wall time on one core (120x real time).  Printed in one run:

* the run's wall and CPU time and the real-time factor, with the cost split (physics, sonar, executive,
  agents, harness bookkeeping) that the harness measures;
* the same run again with the time spent inside pybullet's own calls and inside the daemons' allocation stack
  timed (:class:`CallClock`, which costs a wrapper around each call, hence a run of its own; ``--no-calls``
  skips it): what the run would take were everything else free;
* the same run with the compiled kernels (:mod:`runtime.control.compiled`, numba) off, that is the numpy code
  they stand in for (``--numpy-seconds``, default the same length; 0 skips it), and whether its result is the
  same: what the kernels buy, in one run;
* the same scenario, same agents and executives, in a world at pybullet's defaults: the full-fidelity
  Pioneer 3-DX multibody (:mod:`sitl.bodies.pioneer3dx`: chassis mesh, two driven wheels, caster; five
  pybullet ray casts per sonar), pybullet's default time step (1/240 s) and solver iterations (50), every
  contact point solved; run for ``--default-seconds`` of simulated time (it is slow) and compared per
  simulated second, as a ratio.

The method is an option: ``--method standin`` (default until the DR family exists: the test stand-in agent of
tests/foraging_standin.py, each free robot joins the nearest object) or any registered method name that
allocates transport tasks.  Usage: python benchmarks/foraging_speed.py [--seconds 3600] [--numpy-seconds S] [--default-seconds 60]
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import pybullet as p

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runtime.config.world import WorldConfig  # noqa: E402
from runtime.control import compiled  # noqa: E402
from runtime.fleet.node import FleetNode  # noqa: E402
from sitl.sensing import sonar_ring as sonar  # noqa: E402
from sitl.foraging.harness import ForagingConfig, ForagingRun  # noqa: E402
from sitl.world import World  # noqa: E402
from sitl.bodies import pioneer3dx as p3dx  # noqa: E402

DEFAULT_DT = 1 / 240          # pybullet's default fixedTimeStep
DEFAULT_ITERATIONS = 50       # pybullet's default numSolverIterations


class DefaultWorld:
    """The foraging world's interface over :class:`sitl.world.World` with full Pioneer 3-DX bodies at pybullet's
    default settings: (v, w) become wheel speeds (no acceleration ramp: the bodies' wheel motors limit it), the
    sonar is the body's ray casts (with the fast world's minimum range), bumpers the body's contact segments."""

    def __init__(self, starts, cfg: ForagingConfig):
        self.ids = tuple(sorted(starts))
        self.index = {r: k for k, r in enumerate(self.ids)}
        self.world = World(WorldConfig(size=(cfg.size, cfg.size)), seed=cfg.seed, dt=DEFAULT_DT, wheel_radius_sigma=0.0)
        kw = {"physicsClientId": self.world.client_id}
        p.setPhysicsEngineParameter(numSolverIterations=DEFAULT_ITERATIONS, **kw)
        self.bodies = [self.world.add_body(r, starts[r], "pioneer3dx") for r in self.ids]
        for b in self.bodies:
            for link in range(-1, p.getNumJoints(b.body_id, **kw)):
                p.changeDynamics(b.body_id, link, contactProcessingThreshold=1e30, **kw)   # every manifold point
        self.alive = np.ones(len(self.ids), dtype=bool)
        self.poses = np.array([b.pose() for b in self.bodies])
        self.dt = DEFAULT_DT

    def command(self, robot: int, v: float, w: float) -> None:
        half = p3dx.WHEEL_TRACK / 2
        self.bodies[self.index[robot]].set_wheel_speeds(v - w * half, v + w * half)

    def advance(self, seconds: float) -> None:
        self.world.step(max(1, int(round(seconds / self.dt))))
        self.poses = np.array([b.pose() for b in self.bodies])

    def pose(self, robot: int):
        return tuple(float(v) for v in self.poses[self.index[robot]])

    def sonar(self) -> np.ndarray:
        out = np.full((len(self.ids), sonar.N_SONARS), sonar.MAX_RANGE)
        for k in np.flatnonzero(self.alive):
            r = self.bodies[k].sonar_ranges(range(sonar.N_SONARS))
            out[k] = [r[s] if sonar.MIN_RANGE <= r[s] < sonar.MAX_RANGE else sonar.MAX_RANGE for s in range(16)]
        return out

    def bumpers(self) -> np.ndarray:
        return np.array([b.bumps() if a else (False, False) for b, a in zip(self.bodies, self.alive)])

    def remove(self, robot: int) -> None:
        k = self.index[robot]
        self.alive[k] = False
        self.bodies[k].place(1000.0 + 10 * k, 0.0, 0.0)

    def close(self) -> None:
        self.world.close()


def method_of(name: str):
    if name == "standin":
        from tests.foraging_standin import STANDIN, StandInOptions
        return STANDIN, StandInOptions()
    if name == "dr":                  # NM_I, soft, as Table 5 runs it: the shipped model, the delivery area
        from sitl.experiments import dr_common as D
        return name, D.options(D.Cell("NM_I", utility="soft"), D.shipped_model(), D.Setup())
    return name, None


ENGINE_CALLS = ("stepSimulation", "setJointMotorControlArray", "getJointStates")
NODE_CALLS = ("on_message", "on_peer_lost", "on_progress", "begin", "tick")


class CallClock:
    """Times the calls ``names`` of ``owner`` (a module or a class) while in use, none of the Python around them,
    by wrapping the owner's attributes (calls made through them are seen; none of these call each other)."""

    def __init__(self, owner, names) -> None:
        self.owner, self.names = owner, names
        self.seconds, self.calls = 0.0, 0
        self._saved: dict = {}

    def __enter__(self) -> "CallClock":
        clock = time.perf_counter
        for name in self.names:
            def timed(*args, _call=getattr(self.owner, name), **kw):
                t = clock()
                try:
                    return _call(*args, **kw)
                finally:
                    self.seconds += clock() - t
                    self.calls += 1
            self._saved[name] = getattr(self.owner, name)
            setattr(self.owner, name, timed)
        return self

    def __exit__(self, *exc) -> None:
        for name, call in self._saved.items():
            setattr(self.owner, name, call)


def measure(cfg: ForagingConfig, world=None, calls: bool = False) -> tuple[dict, float, float, object]:
    """(timing split, wall s, CPU s, result) of one run.  With ``calls`` the timing split also holds ``engine``,
    the part of ``physics`` spent inside pybullet's own calls (its step, the motor targets and joint states the
    worlds set and read), and ``node``, the part of ``agents`` spent inside the daemon's own allocation stack (each
    robot's :class:`FleetNode` and its agent: messages, ticks, lost peers, progress).  Timing those calls costs (a
    Python wrapper around each), so the real-time factor comes from a run without, and these from a second run."""
    fr = ForagingRun(cfg, world)
    try:
        with CallClock(p, ENGINE_CALLS if calls else ()) as engine, \
                CallClock(FleetNode, NODE_CALLS if calls else ()) as node:
            w0, c0 = time.perf_counter(), time.process_time()
            res = fr.run()
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    finally:
        fr.close()
    return {**res.timing, "engine": engine.seconds, "node": node.seconds}, wall, cpu, res


def same_result(a, b) -> bool:
    return (len(a.finished), a.moved, a.messages.sent) == (len(b.finished), b.moved, b.messages.sent)


def split(timing: dict) -> str:
    parts = {k: v for k, v in timing.items() if k not in ("total", "engine", "node")}
    total = sum(parts.values())
    return ", ".join(f"{k} {v:.1f} s ({100 * v / total:.0f} %)" for k, v in parts.items())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3600.0, help="simulated s of the fast run (default 3600)")
    ap.add_argument("--numpy-seconds", type=float, default=None,
                    help="simulated s of the same run with the compiled kernels off (the numpy code, as before "
                         "numba: default --seconds; 0 skips it)")
    ap.add_argument("--default-seconds", type=float, default=60.0,
                    help="simulated s of the run at pybullet's defaults (default 60; it is slow)")
    ap.add_argument("--no-calls", dest="calls", action="store_false",
                    help="skip the second run that times the calls inside pybullet and the allocation stack")
    ap.add_argument("--robots", type=int, default=10)
    ap.add_argument("--method", default="standin", help="standin (tests/foraging_standin.py) or a registered method")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--no-sonar", action="store_true", help="robots avoid by bumpers only")
    ap.add_argument("--control-period", type=float, default=ForagingConfig.control_period,
                    help="s between control cycles (default %(default)s; the reproductions' figures stand on it)")
    args = ap.parse_args()
    method, options = method_of(args.method)
    cfg = ForagingConfig(robots=args.robots, method=method, options=options, seed=args.seed, time_limit=args.seconds,
                         sonar=not args.no_sonar, control_period=args.control_period)
    print(f"{args.robots} robots, 3 objects of 40 wu, method {args.method}, control period {cfg.control_period} s, "
          f"fast world: physics step {cfg.dt * 1000:g} ms, {cfg.solver_iterations} solver iterations, disc bodies, "
          f"closed-form sonar; compiled kernels {'on (numba)' if compiled.AVAILABLE else 'off (numba not installed)'}")
    timing, wall, cpu, res = measure(cfg)
    print(f"fast world, {args.seconds:g} s simulated: wall {wall:.1f} s, CPU {cpu:.1f} s, real-time factor "
          f"{args.seconds / wall:.0f}x, {args.seconds / cpu:.0f}x in CPU (target: wall < 30 s, 120x); objects done "
          f"{len(res.finished)}, {res.moved:.0f} wu moved, {res.messages.sent} messages sent")
    print(f"  cost split: {split(timing)}")
    rest = sum(v for k, v in timing.items() if k not in ("total", "executive", "engine", "node"))
    print(f"  without the executive the rest (world, agents, harness) takes {rest:.1f} s: "
          f"{args.seconds / max(rest, 1e-9):.0f}x real time at best with these parts as they are")
    if args.calls:
        t_in, w_in, c_in, r_in = measure(cfg, calls=True)
        floor = t_in["engine"] + t_in["node"]
        print(f"  the same run again with its calls timed: CPU {c_in:.1f} s (untimed {cpu:.1f} s), "
              f"{'the same result' if same_result(r_in, res) else 'A DIFFERENT RESULT'}; inside pybullet (its "
              f"step, the motor targets and joint states) {t_in['engine']:.1f} s, inside the daemon's allocation stack "
              f"(FleetNode and agent) {t_in['node']:.1f} s: with the executive, the sonar and every other line free the "
              f"run would still take {floor:.1f} s ({args.seconds / max(floor, 1e-9):.0f}x)")
    numpy_seconds = args.seconds if args.numpy_seconds is None else args.numpy_seconds
    if numpy_seconds > 0 and compiled.AVAILABLE:
        with compiled.numpy_code():                   # every kernel's caller takes its numpy code again
            t_np, w_np, c_np, r_np = measure(ForagingConfig(**{**cfg.__dict__, "time_limit": numpy_seconds}))
        same = "" if numpy_seconds != args.seconds else (
            ", the same result" if same_result(r_np, res) else ", A DIFFERENT RESULT")
        print(f"numpy code (kernels off), {numpy_seconds:g} s simulated: wall {w_np:.1f} s, CPU {c_np:.1f} s, "
              f"{numpy_seconds / w_np:.0f}x real time, {numpy_seconds / c_np:.0f}x in CPU; objects done "
              f"{len(r_np.finished)}, {r_np.moved:.0f} wu moved, {r_np.messages.sent} messages sent{same}; compiled "
              f"is {c_np / numpy_seconds / (cpu / args.seconds):.2f}x faster in CPU per simulated second")
        print(f"  cost split: {split(t_np)}")
    if args.default_seconds > 0:
        short = ForagingConfig(**{**cfg.__dict__, "time_limit": args.default_seconds})
        t_fast, w_fast, c_fast, _ = measure(short)
        t_def, w_def, c_def, _ = measure(short, DefaultWorld)
        print(f"same scenario, {args.default_seconds:g} s simulated: fast world wall {w_fast:.1f} s (CPU {c_fast:.1f}), "
              f"pybullet defaults (full Pioneer bodies, {1 / DEFAULT_DT:.0f} Hz, {DEFAULT_ITERATIONS} iterations, "
              f"ray-cast sonar) wall {w_def:.1f} s (CPU {c_def:.1f}): {w_def / w_fast:.1f}x slower in all")
        world_fast = t_fast["physics"] + t_fast["sonar"]
        world_def = t_def["physics"] + t_def["sonar"]
        print(f"  world only (physics + sonar): fast {world_fast:.2f} s, defaults {world_def:.2f} s: "
              f"{world_def / max(world_fast, 1e-9):.0f}x")
        print(f"  fast split: {split(t_fast)}")
        print(f"  defaults split: {split(t_def)}")
        est = w_def / args.default_seconds * 3600
        print(f"  at the defaults a 3600 s run would take about {est:.0f} s of wall time ({3600 / est:.1f}x real time)")
    if not math.isfinite(wall):
        sys.exit(1)


if __name__ == "__main__":
    main()
