"""A SITL run's recording: ``run.mcap`` beside ``trace.json``, and the live Foxglove view (``--live``).

:class:`FleetRecording` is the lock-step host's recorder: every daemon's core feeds it
(:class:`runtime.recording.feed.CoreFeed`, one per robot, topics ``/robot_N/...``), and the host adds what only
the simulation knows: each body's true pose (``/robot_N/truth`` and the ``/tf`` frame each robot is drawn in), the
world as scene entities with the task places coloured by state (``/world``), and the operator's view of the run
(``/allocation`` events of robot 0, ``operator``: awarded, arrived, done, released, lost).  The run's picture is
redrawn from the file by :func:`trace_from_mcap` (``python -m sitl.run_plot RUN_DIR/run.mcap``): the tracks from
the true poses, the events from the operator's, the world and the final task marks from the file's ``trace``
metadata.  Times are the simulated clock.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from runtime import config as C
from runtime.log import get_logger
from sitl.run_trace import RobotTrack, RunTrace, TaskMark, TraceEvent

log = get_logger("sitl")
OPERATOR = 0          # the robot id of the operator's events
_STATE = {"awarded": "held", "arrived": "held", "done": "done", "released": "open", "failed": "open",
          "withdrawn": "withdrawn"}


class FleetRecording:
    """Records the lock-step fleet ``f`` (a launcher Fleet) into ``path`` and, with ``live`` ``(host, port)``,
    serves it over the Foxglove WebSocket protocol."""

    def __init__(self, f, path: str | Path | None, live: tuple[str, int] | None = None, mavlink: bool = True):
        from runtime.recording.feed import LogTap
        from runtime.recording.recorder import Recorder

        self.f = f
        self.path = None if path is None else Path(path)
        self.rec = Recorder(self.path, wall=False, live=live, mavlink=mavlink, name=f"mrta sitl {f.fleet.source}")
        self.rec.metadata("run", {"fleet": str(f.fleet.source), "world": str(f.fleet.world),
                                  "robots": {str(rid): {"base": r.base_type, "radius": r.radius}
                                             for rid, r in f.robots.items()}})
        self.tap = LogTap(self.rec).attach()
        self._events = 0
        self._tasks: dict | None = None
        self._world = None

    def attach(self, daemons: dict) -> None:
        """A feed on each daemon's core (its cycles and messages) and a tap on its link (raw MAVLink frames)."""
        from runtime.recording.feed import CoreFeed, link_tap

        for rid, d in daemons.items():
            d.feed = CoreFeed(self.rec, d.core, stats=d.snapshot)
            if self.rec.mavlink and hasattr(d.link, "tap"):
                d.link.tap = link_tap(self.rec, rid)

    def step(self, t: float, op) -> None:
        """After a control cycle: the bodies' true poses, the operator's new events, the world when tasks
        changed."""
        rec, f = self.rec, self.f
        for rid in f.robots:
            if rid in f.withdrawn:
                continue
            pose = f.true_pose(rid)
            rec.pose(rid, t, pose, truth=True)
            rec.transform(rid, t, pose)
        events = op.trace.events
        for ev in events[self._events:]:
            rec.event(t, OPERATOR, "operator", ev.what, ev.task, ev.robots, {"detail": ev.detail}, t=ev.t)
        changed = len(events) != self._events
        self._events = len(events)
        if changed or self._tasks is None or len(op.trace.tasks) != len(self._tasks):
            self._scene(t, op.trace)
        rec.check()

    def _scene(self, t: float, trace: RunTrace) -> None:
        state = {tid: "open" for tid in trace.tasks}
        for ev in trace.events:
            if ev.task in state and ev.what in _STATE:
                state[ev.task] = _STATE[ev.what]
        tasks = [(tid, m.x, m.y, m.name, state[tid]) for tid, m in trace.tasks.items()]
        if tasks != self._tasks:
            self._tasks = tasks
            self.rec.scene(t, trace.world, tasks)

    def close(self, trace: RunTrace | None = None) -> None:
        """The final trace facts (world, robots, task marks) as the file's ``trace`` metadata, then close."""
        try:
            if trace is not None:
                self.rec.metadata("trace", {
                    "title": trace.title, "world": C.to_dict(trace.world), "world_source": trace.world.source,
                    "robots": [{"id": r.id, "base": r.base, "radius": r.radius, "lost_at": r.lost_at}
                               for r in trace.robots.values()],
                    "tasks": [dataclasses.asdict(tk) for tk in trace.tasks.values()]})
        finally:
            self.tap.detach()
            self.rec.close()


def trace_from_mcap(path: str | Path) -> RunTrace:
    """The run's trace as ``trace.json`` has it, from a SITL run's MCAP: an InputError naming the file if it is
    not one."""
    from runtime.errors import InputError
    from runtime.recording.read import read_messages

    source = str(path)
    recording = read_messages(path, topics=None)
    meta = recording.metadata.get("trace")
    if meta is None:
        raise InputError(f"{source}: expected a SITL run's recording (a 'trace' metadata record), found none"
                         + (" (the file ends early)" if recording.truncated else ""))
    try:
        world = C.from_dict(C.WorldConfig, json.loads(meta["world"]), f"{source}: trace.world")
        world = dataclasses.replace(world, source=meta.get("world_source", ""))
        tr = RunTrace(world=world, title=meta.get("title", ""))
        for r in json.loads(meta["robots"]):
            tr.robots[r["id"]] = RobotTrack(r["id"], base=r["base"], radius=r["radius"], lost_at=r["lost_at"])
        for tk in json.loads(meta["tasks"]):
            tr.tasks[tk["id"]] = TaskMark(**tk)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{source}: trace metadata: expected the run's world, robots and tasks ({exc})") from None
    for m in recording.messages:
        if m.kind == "truth" and m.is_pose:
            rid = m.robot
            if rid in tr.robots:
                x, y, yaw = m.pose
                tr.robots[rid].add(m.ns / 1e9, x, y, yaw)
        elif m.topic == "/allocation" and isinstance(m.data, dict) and m.data.get("event") == "operator":
            d = m.data
            try:
                tr.events.append(TraceEvent(float(d["t"]), d["task"], tuple(int(r) for r in d["robots"]),
                                            str(d["message"]), str(d["fields"].get("detail", ""))))
            except (KeyError, TypeError, ValueError, AttributeError) as exc:
                raise InputError(f"{source}: /allocation at {m.ns} ns: expected an operator event "
                                 f"(t, task, robots, message, fields; {exc!r})") from None
    return tr
