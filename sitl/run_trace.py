"""What a SITL run did, kept for a picture: the world, each robot's thinned track, the tasks, the events.

Plain dataclasses and JSON, no plotting imports: the launcher fills a :class:`RunTrace` while it steps
the world, writes ``trace.json`` into the run directory, and :mod:`sitl.run_plot` draws it (again, later,
from the file).  Times are sim seconds; positions are metres in the world frame.
"""
from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from runtime import config as C
from runtime.errors import InputError
from runtime.jsonfile import read_json

FORMAT = "mrta-run-trace"
VERSION = 1
EVENT_KINDS = ("awarded", "arrived", "done", "failed", "withdrawn", "released", "lost", "disarmed", "armed")

# A track keeps a sample when the robot moved, turned or time passed this much since the last kept one.
KEEP_MOVE = 0.02                    # m
KEEP_TURN = math.radians(5.0)       # rad
KEEP_DT = 0.5                       # s
DIGITS = 4                          # samples are rounded to 0.1 mm / 0.1 ms / 1e-4 rad (JSON stays short)

Sample = tuple[float, float, float, float]      # t, x, y, yaw


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@dataclass
class RobotTrack:
    """One robot's drive, thinned as it is recorded.

    ``samples[-1]`` is always the newest sample given to :meth:`add`, so the final pose is exact; the
    samples before it are the kept ones.  ``skipped`` counts samples that were not finite.
    """
    id: int
    base: str = "create_oi"
    radius: float = 0.17
    samples: list[Sample] = field(default_factory=list)
    lost_at: float | None = None
    skipped: int = field(default=0, compare=False)
    _kept: int = field(default=-1, compare=False, repr=False)    # samples[:_kept] are committed

    def __post_init__(self) -> None:
        if self._kept < 0:
            self._kept = len(self.samples)

    def add(self, t: float, x: float, y: float, yaw: float) -> None:
        """Record a pose; it stays only if it differs enough from the last kept one (or is the newest)."""
        if not all(math.isfinite(v) for v in (t, x, y, yaw)):
            self.skipped += 1
            return
        s = (round(float(t), DIGITS), round(float(x), DIGITS), round(float(y), DIGITS), round(_wrap(float(yaw)), DIGITS))
        del self.samples[self._kept:]              # the provisional newest sample, if any
        self.samples.append(s)
        if self._kept == 0 or self._differs(self.samples[self._kept - 1], s):
            self._kept = len(self.samples)

    @staticmethod
    def _differs(a: Sample, b: Sample) -> bool:
        return (math.hypot(b[1] - a[1], b[2] - a[2]) >= KEEP_MOVE
                or abs(_wrap(b[3] - a[3])) >= KEEP_TURN
                or b[0] - a[0] >= KEEP_DT)

    def pose_at(self, t: float) -> Sample | None:
        """The last sample at or before ``t`` (the first one if ``t`` precedes the track); None if empty."""
        if not self.samples:
            return None
        lo, hi = 0, len(self.samples)
        while lo < hi:
            mid = (lo + hi) // 2
            if self.samples[mid][0] <= t:
                lo = mid + 1
            else:
                hi = mid
        return self.samples[max(lo - 1, 0)]


@dataclass
class TaskMark:
    id: int
    kind: str                           # "goto", "rendezvous", ...
    x: float
    y: float
    label: str = ""                     # "T3", "WP 2"; empty: "T<id>"
    need: int = 1                       # robots the task needs
    arrived_at: float | None = None     # when the task was handed in

    @property
    def name(self) -> str:
        return self.label or f"T{self.id}"


@dataclass
class TraceEvent:
    t: float
    task: int | None
    robots: tuple[int, ...]
    what: str                           # one of EVENT_KINDS
    detail: str = ""


@dataclass
class RunTrace:
    world: C.WorldConfig = field(default_factory=C.WorldConfig)
    robots: dict[int, RobotTrack] = field(default_factory=dict)
    tasks: dict[int, TaskMark] = field(default_factory=dict)
    events: list[TraceEvent] = field(default_factory=list)
    title: str = ""

    def event(self, t: float, what: str, task: int | None = None, robots: tuple[int, ...] | list[int] = (),
              detail: str = "") -> TraceEvent:
        """Append an event (``what`` must be one of :data:`EVENT_KINDS`) and return it."""
        if what not in EVENT_KINDS:
            raise ValueError(f"event kind {what!r}: expected one of {', '.join(EVENT_KINDS)}")
        ev = TraceEvent(float(t), task, tuple(int(r) for r in robots), what, detail)
        self.events.append(ev)
        return ev

    def end_time(self) -> float:
        """The latest time anything in the trace happened (0 for an empty trace)."""
        times = [0.0]
        times += [tr.samples[-1][0] for tr in self.robots.values() if tr.samples]
        times += [tr.lost_at for tr in self.robots.values() if tr.lost_at is not None]
        times += [e.t for e in self.events]
        times += [tk.arrived_at for tk in self.tasks.values() if tk.arrived_at is not None]
        return max(times)

    # ------------------------------------------------------------------ JSON

    def to_dict(self) -> dict:
        return {
            "format": FORMAT, "version": VERSION, "title": self.title,
            "world": C.to_dict(self.world), "world_source": self.world.source,
            "robots": [{"id": r.id, "base": r.base, "radius": r.radius, "lost_at": r.lost_at,
                        "samples": [list(s) for s in r.samples]} for r in self.robots.values()],
            "tasks": [dataclasses.asdict(tk) for tk in self.tasks.values()],
            "events": [{**dataclasses.asdict(e), "robots": list(e.robots)} for e in self.events],
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), separators=(",", ":"))

    def write(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(self.to_json())
        return path

    @classmethod
    def from_dict(cls, data: Any, source: str = "<trace>") -> "RunTrace":
        """Inverse of :meth:`to_dict`; a bad document raises :class:`InputError` naming the key."""
        return _Reader(source).trace(data)

    @classmethod
    def from_json(cls, text: str, source: str = "<trace>") -> "RunTrace":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InputError(f"{source}: expected JSON ({exc.msg} at line {exc.lineno} column {exc.colno})") from None
        except RecursionError:
            raise InputError(f"{source}: expected JSON (nested too deeply)") from None
        return cls.from_dict(data, source)

    @classmethod
    def read(cls, path: str | Path) -> "RunTrace":
        return cls.from_dict(read_json(path, "run trace (trace.json)"), str(path))


class _Reader:
    """Checks a decoded trace document field by field; the first problem is one InputError line."""

    def __init__(self, source: str):
        self.source = source

    def fail(self, key: str, expected: str) -> InputError:
        return InputError(f"{self.source}: {key}: expected {expected}")

    def obj(self, v: Any, key: str) -> dict:
        if not isinstance(v, dict):
            raise self.fail(key, "an object")
        return v

    def items(self, v: Any, key: str) -> list:
        if not isinstance(v, list):
            raise self.fail(key, "a list")
        return v

    def num(self, v: Any, key: str, optional: bool = False) -> float | None:
        if v is None and optional:
            return None
        try:
            ok = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
        except OverflowError:       # an integer too large for a float
            ok = False
        if not ok:
            raise self.fail(key, "a finite number" + (" or null" if optional else ""))
        return float(v)

    def integer(self, v: Any, key: str, optional: bool = False) -> int | None:
        if v is None and optional:
            return None
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.fail(key, "an integer" + (" or null" if optional else ""))
        return v

    def text(self, v: Any, key: str) -> str:
        if not isinstance(v, str):
            raise self.fail(key, "a string")
        return v

    def trace(self, data: Any) -> RunTrace:
        d = self.obj(data, "document")
        if d.get("format") != FORMAT or d.get("version") != VERSION:
            raise self.fail("format", f'"format": "{FORMAT}", "version": {VERSION}')
        world = C.from_dict(C.WorldConfig, self.obj(d.get("world"), "world"), f"{self.source}: world")
        world = dataclasses.replace(world, source=self.text(d.get("world_source", ""), "world_source"))
        tr = RunTrace(world=world, title=self.text(d.get("title", ""), "title"))
        for i, r in enumerate(self.items(d.get("robots", []), "robots")):
            track = self.robot(self.obj(r, f"robots[{i}]"), f"robots[{i}]")
            if track.id in tr.robots:
                raise self.fail(f"robots[{i}].id", f"a robot id not used before (got {track.id} twice)")
            tr.robots[track.id] = track
        for i, t in enumerate(self.items(d.get("tasks", []), "tasks")):
            task = self.task(self.obj(t, f"tasks[{i}]"), f"tasks[{i}]")
            if task.id in tr.tasks:
                raise self.fail(f"tasks[{i}].id", f"a task id not used before (got {task.id} twice)")
            tr.tasks[task.id] = task
        tr.events = [self.event(self.obj(e, f"events[{i}]"), f"events[{i}]")
                     for i, e in enumerate(self.items(d.get("events", []), "events"))]
        return tr

    def robot(self, r: dict, key: str) -> RobotTrack:
        samples = []
        for j, s in enumerate(self.items(r.get("samples", []), f"{key}.samples")):
            if not isinstance(s, list) or len(s) != 4:
                raise self.fail(f"{key}.samples[{j}]", "[t, x, y, yaw]")
            samples.append(tuple(self.num(v, f"{key}.samples[{j}]") for v in s))
        radius = self.num(r.get("radius"), f"{key}.radius")
        if radius <= 0:
            raise self.fail(f"{key}.radius", "a positive number (m)")
        return RobotTrack(id=self.integer(r.get("id"), f"{key}.id"), base=self.text(r.get("base"), f"{key}.base"),
                          radius=radius, samples=samples,
                          lost_at=self.num(r.get("lost_at"), f"{key}.lost_at", optional=True))

    def task(self, t: dict, key: str) -> TaskMark:
        need = self.integer(t.get("need", 1), f"{key}.need")
        if need < 1:
            raise self.fail(f"{key}.need", "an integer >= 1")
        return TaskMark(id=self.integer(t.get("id"), f"{key}.id"), kind=self.text(t.get("kind"), f"{key}.kind"),
                        x=self.num(t.get("x"), f"{key}.x"), y=self.num(t.get("y"), f"{key}.y"),
                        label=self.text(t.get("label", ""), f"{key}.label"), need=need,
                        arrived_at=self.num(t.get("arrived_at"), f"{key}.arrived_at", optional=True))

    def event(self, e: dict, key: str) -> TraceEvent:
        what = e.get("what")
        if what not in EVENT_KINDS:
            raise self.fail(f"{key}.what", "one of " + "|".join(EVENT_KINDS))
        robots = tuple(self.integer(v, f"{key}.robots[{j}]")
                       for j, v in enumerate(self.items(e.get("robots", []), f"{key}.robots")))
        return TraceEvent(t=self.num(e.get("t"), f"{key}.t"), task=self.integer(e.get("task"), f"{key}.task", True),
                          robots=robots, what=what, detail=self.text(e.get("detail", ""), f"{key}.detail"))
