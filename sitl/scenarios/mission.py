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
from runtime.config.world import check_inside
from runtime.messages import CLEARED, DONE, OPEN, STATE_NAMES, WITHDRAWN

FINISHED = (DONE, CLEARED)       # a task done counts as done after a clear too (cleared = done, then cleared)


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

    def check(self, fleet, world, file: str) -> None:
        ids = {r.id for r in fleet.robots}
        for i, t in enumerate(self.tasks):
            check_inside(world, (t.x, t.y), file, f"scenario.tasks[{i}]")
            to = t.to if t.to is not None else self.to
            if to is not None and to not in ids:
                raise ConfigError(file, f"scenario.tasks[{i}].to", "the id of a robot of the fleet", to)
        if self.to is not None and self.to not in ids:
            raise ConfigError(file, "scenario.to", "the id of a robot of the fleet", self.to)
        if not self.tasks and not self.wait:
            raise ConfigError(file, "scenario.tasks", "at least one task (or wait: true for an operator)")


class Scenario:
    """Hands each group of tasks (same ``at`` and ``to``) in as one upload at its time; the goal is met when
    every task handed in is done (never, with ``wait``: the fleet keeps serving an operator)."""

    def __init__(self, fleet, world):
        self.cfg: Config = fleet.scenario
        self.fleet = fleet
        self.world = world

    def handovers(self) -> list:
        from runtime.comms.mission import MissionItem
        from sitl.scenarios.base import Handover

        lowest = min(r.id for r in self.fleet.robots)
        groups: dict[tuple[float, int], list] = {}
        for i, t in enumerate(self.cfg.tasks):
            to = t.to if t.to is not None else (self.cfg.to if self.cfg.to is not None else lowest)
            groups.setdefault((t.at, to), []).append((i, t))
        out = []
        for (at, to), entries in sorted(groups.items()):
            items, labels = [], []
            for seq, (i, t) in enumerate(entries):
                kind = T.kind(t.kind)
                command, params = kind.to_item(t.spec())
                items.append(MissionItem(seq, 4, command, *params, t.x, t.y, 0.0))    # MAV_FRAME_LOCAL_ENU
                labels.append(f"T{i}")
            out.append(Handover(at, to, items, labels))
        return out

    def goal(self, run) -> bool:
        """Every task handed in done, at least one (a fleet waiting for an operator keeps running: the launcher
        judges it by this when it is stopped)."""
        return self.shortfall(run) is None

    def shortfall(self, run) -> str | None:
        """What keeps the goal from being met (one line), or None: every task handed in done or withdrawn by a
        clear, and at least one done."""
        due = [h for h in run.handovers if not h.done]
        if due:
            return f"{sum(len(h.items) for h in due)} task(s) not handed in yet (next at {min(h.at for h in due):g} s)"
        ours = {tid for h in run.handovers for tid in h.task_ids}
        open_ = [label for h in run.handovers for label, tid in zip(h.labels, h.task_ids)
                 if tid is None or run.task_state(tid) not in FINISHED + (WITHDRAWN,)]
        open_ += [f"{tid >> 16}.{tid & 0xFFFF}" for tid, rec in sorted(run.table().items())
                  if tid not in ours and rec.state == OPEN]          # handed in by another ground station
        if open_:
            return f"{', '.join(open_)} not done"
        return self.idle(run)

    def idle(self, run) -> str | None:
        """One line when the run had no work to judge it by (nothing handed in, or every task withdrawn by a clear
        before a robot did it), else None."""
        rows = self.summary(run)
        if not rows["tasks"]:
            return "nothing was handed in: no task to judge the run by"
        if rows["done"] == 0 and rows["withdrawn"] == len(rows["tasks"]):
            return (f"nothing was done: the {rows['withdrawn']} task(s) handed in were all withdrawn by a clear "
                    f"before a robot did them")
        return None

    def unreachable(self, run) -> str | None:
        return None                       # a lost robot's tasks go to the others: only a refusal ends it early

    def summary(self, run) -> dict:
        """Every task: the scenario's, then any an operator handed in from another ground station."""
        rows, ours = [], set()
        for h in run.handovers:
            for label, it, tid in zip(h.labels, h.items, h.task_ids or [None] * len(h.items)):
                state = run.task_state(tid) if tid is not None else None
                ours.add(tid)
                rows.append({"label": label, "task": tid, "x": it.x, "y": it.y, "at": h.at, "to": h.to,
                             "state": STATE_NAMES.get(state, "not handed in" if not h.done else "refused"),
                             "by": run.done_by.get(tid, ()), "done_at": run.done_at.get(tid)})
        for tid, rec in sorted(run.table().items()):
            if tid not in ours:
                rows.append({"label": "op", "task": tid, "x": rec.x, "y": rec.y, "at": run.first_seen(tid),
                             "to": tid >> 16, "state": STATE_NAMES.get(rec.state), "by": run.done_by.get(tid, ()),
                             "done_at": run.done_at.get(tid)})
        done = sum(r["state"] in ("done", "cleared") for r in rows)
        withdrawn = sum(r["state"] == "withdrawn" for r in rows)
        return {"tasks": rows, "valid": done > 0 and done + withdrawn == len(rows), "done": done,
                "withdrawn": withdrawn, "driven": dict(run.driven)}

    @staticmethod
    def print_summary(res: dict, out) -> None:
        print("\ntask  fleet id  position (m)      handed in  state      done by  done at (s)", file=out)
        at = lambda r: "-" if r["at"] is None else f"{r['at']:7.1f} s"      # noqa: E731
        for r in res["tasks"]:
            tid = "-" if r["task"] is None else f"{r['task'] >> 16}.{r['task'] & 0xFFFF}"
            by = "+".join(f"R{b}" for b in r["by"]) or "-"
            done_at = "-" if r["done_at"] is None else f"{r['done_at']:.1f}"
            print(f"{r['label']:>4}  {tid:>8}  ({r['x']:5.2f}, {r['y']:5.2f})  {at(r):>9}  {r['state']:9}  "
                  f"{by:>7}  {done_at:>11}", file=out)
        if res["driven"]:
            print("driven (m): " + ", ".join(f"R{rid} {d:.1f}" for rid, d in sorted(res["driven"].items())), file=out)
        withdrawn = res.get("withdrawn", 0)
        cleared = sum(r["state"] == "cleared" for r in res["tasks"])
        print(f"tasks done: {res['done']}/{len(res['tasks']) - withdrawn}"
              + (f" ({cleared} of them cleared after)" if cleared else "")
              + (f", {withdrawn} withdrawn by a clear before done" if withdrawn else "")
              + f"   sim time {res['sim_time']:.1f} s", file=out)
