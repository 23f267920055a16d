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
LOOK_PERIOD = 0.5     # s of sim time between looks at the world's things when no event changed them (formation
#                       targets reached, holders)
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
        self._tasks: list | None = None
        self._world = None
        self._carried: dict[int, tuple[float, tuple[int, ...]]] = {}   # task -> (wu left, carriers): leaders' word
        self._carried_changed = False
        self._next_look = 0.0
        self._run_view = None
        self.relay = None          # a RelayServer: the daemons' channels (process fleets with --live)

    def attach(self, daemons: dict) -> None:
        """A feed on each daemon's core (its cycles and messages) and a tap on its link (raw MAVLink frames)."""
        from runtime.recording.feed import CoreFeed

        for rid, d in daemons.items():
            d.feed = CoreFeed(self.rec, d.core, stats=d.snapshot, watch=self._watch_message)
            if self.rec.mavlink and hasattr(d.link, "tap"):
                d.link.tap = self.rec.frame_tap(rid)

    def step(self, t: float, op) -> None:
        """After a control cycle: the bodies' true poses, the operator's new events, the world when tasks
        changed."""
        rec, f = self.rec, self.f
        known = op.poses if getattr(op, "posed_at", None) == t else {}      # the trace's poses of this step
        poses = [(rid, known.get(rid) or f.true_pose(rid)) for rid in f.robots if rid not in f.withdrawn]
        for rid, pose in poses:
            rec.pose(rid, t, pose, truth=True)
        rec.transforms(t, poses)
        events = op.trace.events
        for ev in events[self._events:]:
            rec.event(t, OPERATOR, "operator", ev.what, ev.task, ev.robots, {"detail": ev.detail}, t=ev.t)
        changed = len(events) != self._events
        self._events = len(events)
        if changed or self._carried_changed or t >= self._next_look or self._tasks is None \
                or len(op.trace.tasks) != len(self._tasks):
            self._next_look = t + LOOK_PERIOD
            self._carried_changed = False
            self._scene(t, op)
        rec.check()

    def serve_relay(self) -> tuple[str, int]:
        """Listen for the daemons' channels (a process fleet with ``--live``): the address to pass them as
        ``--live-relay``.  :meth:`poll` takes in what they send."""
        from runtime.recording.relay import RelayServer

        self.relay = RelayServer(self.rec, on_message=self._relayed)
        return self.relay.address

    def poll(self) -> None:
        """What the daemons relayed since the last call, onto the live view."""
        if self.relay is not None:
            self.relay.poll()

    def _relayed(self, robot: int, topic: str, payload: bytes) -> None:
        if b'"left"' in payload and topic.endswith("/allocation"):
            try:
                d = json.loads(payload)
                if d.get("event") == "sent":
                    fields = d.get("fields") or {}
                    self.watch(d.get("task"), fields.get("left"), fields.get("members"))
            except (ValueError, AttributeError):
                pass

    def _watch_message(self, rid: int, msg) -> None:
        left = getattr(msg, "left", None)
        if left is not None:
            self.watch(getattr(msg, "task", None), left, getattr(msg, "members", None))

    def watch(self, task, left, members) -> None:
        """A leader's report of an object (``task``: its ``left`` wu and the ``members`` carrying it; what a ``dr``
        robot's DrLeaderAlive says) updates the object's scene entity."""
        if task is None or left is None or members is None:
            return
        try:
            facts = (float(left), tuple(int(r) for r in members))
        except (TypeError, ValueError):
            return
        if self._carried.get(task) != facts:
            self._carried[task] = facts
            self._carried_changed = True

    def _scene(self, t: float, op) -> None:
        """The world's things as scene entities: each task place coloured by the operator's view of its state,
        with who holds it now, what a leader last said is left of an object and who carries it, and what the
        scenario adds (an object's weight, the robot standing on a formation target)."""
        trace = op.trace
        state = {tid: "open" for tid in trace.tasks}
        for ev in trace.events:
            if ev.task in state and ev.what in _STATE:
                state[ev.task] = _STATE[ev.what]
        holders: dict[int, list[int]] = {}
        for rid in op.live_robots():
            for tid in op.gcs.robots[rid].tasks:
                holders.setdefault(tid, []).append(rid)
        hook = getattr(self.f.scenario, "scene_facts", None)
        extra = hook(self._view(op)) if hook is not None else {}
        tasks = []
        for tid, m in trace.tasks.items():
            if state[tid] == "open" and tid in holders:      # released by one robot, held by another already
                state[tid] = "held"
            facts = {"kind": m.kind, "robots": tuple(holders.get(tid, ())), **extra.get(tid, {})}
            carried = self._carried.get(tid)
            if carried is not None and state[tid] != "done":
                facts["left"], facts["robots"] = carried
            tasks.append((tid, m.x, m.y, m.name, state[tid], facts))
        if tasks != self._tasks:
            self._tasks = tasks
            self.rec.scene(t, trace.world, tasks)

    def _view(self, op):
        if self._run_view is None or self._run_view.op is not op:
            from sitl.operator import RunView
            self._run_view = RunView(op)
        return self._run_view

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
            if self.relay is not None:
                self.relay.close()
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
