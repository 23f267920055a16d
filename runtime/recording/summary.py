"""``mrta log summary FILE.mcap``: what a recording says happened, without Foxglove.

Per robot: the time it covers, the distance its estimate moved, the messages it sent (by type), what its link and
fleet node dropped (its last status snapshot); per task: who held it when (from the robots' ``committed`` and
``released`` events), with which partners (coalitions), its progress and its states in the robots' tables.  A
recording whose writer was killed is read up to its last whole chunk, and the summary says so.
"""
from __future__ import annotations

import argparse
import math
import sys
from collections import Counter, defaultdict



def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("log", help="recordings (MCAP): mrta log summary FILE.mcap")
    s = p.add_subparsers(dest="log_cmd", metavar="SUBCOMMAND", required=True)
    r = s.add_parser("summary", help="per robot and per task, what a recording says happened")
    r.add_argument("file", help="an MCAP recording (RUN_DIR/run.mcap, mrta daemon --record FILE.mcap)")
    r.set_defaults(func=_main)


def summarize(path) -> dict:
    """The summary of the recording at ``path`` as data (what :func:`_main` prints)."""
    from runtime.recording.read import read_messages

    rec = read_messages(path)
    robots: dict[int, dict] = defaultdict(lambda: {"poses": 0, "first": None, "last": None, "moved": 0.0,
                                                   "sent": Counter(), "received": Counter(), "stats": None,
                                                   "lost_peers": []})
    tasks: dict[int, dict] = defaultdict(lambda: {"held": [], "progress": [], "states": [], "coalitions": set()})
    open_holds: dict[tuple[int, int], tuple[float, tuple]] = {}
    last_pose: dict[int, tuple] = {}
    end = 0.0
    skipped = 0
    for m in rec.messages:
        try:
            end = _one(m, end, robots, tasks, open_holds, last_pose)
        except (KeyError, TypeError, ValueError, AttributeError):      # a message not of the shape written
            skipped += 1
    for (rid, task), (t0, _) in open_holds.items():
        tasks[task]["held"].append((rid, t0, None))
    return {"source": rec.source, "truncated": rec.truncated, "end": end, "channels": rec.channels,
            "metadata": rec.metadata, "messages": len(rec.messages), "skipped": skipped + rec.dropped,
            "robots": {k: robots[k] for k in sorted(robots) if k != 0},
            "tasks": {k: tasks[k] for k in sorted(tasks)}}


def _one(m, end: float, robots, tasks, open_holds, last_pose) -> float:
    """One message into the summary's tallies; returns the latest time seen."""
    t = m.ns / 1e9
    end = max(end, t)
    rid = m.robot
    if rid is not None and m.kind == "pose" and m.is_pose:
        r = robots[rid]
        r["poses"] += 1
        r["first"] = t if r["first"] is None else r["first"]
        r["last"] = t
        x, y, _ = m.pose
        if rid in last_pose:
            r["moved"] += math.hypot(x - last_pose[rid][0], y - last_pose[rid][1])
        last_pose[rid] = (x, y)
    elif rid is not None and m.kind == "stats" and isinstance(m.data, dict):
        robots[rid]["stats"] = m.data
    elif m.topic == "/allocation" and isinstance(m.data, dict):
        d = m.data
        rid, ev, task = d.get("robot", 0), d.get("event"), d.get("task")
        robots_of = d.get("robots", ())
        if not isinstance(rid, int) or not (task is None or isinstance(task, int)) or \
                not all(isinstance(r, int) for r in robots_of):
            raise TypeError("robot, task and robots must be integers")
        when = float(d.get("t", t))
        if ev in ("sent", "received"):
            robots[rid][ev][d.get("message", "?")] += 1
        elif ev == "committed" and task is not None:
            if (rid, task) not in open_holds:
                open_holds[(rid, task)] = (when, tuple(d.get("robots", ())))
            if len(d.get("robots", ())) > 1:
                tasks[task]["coalitions"].add(tuple(sorted(d["robots"])))
        elif ev == "released" and task is not None and (rid, task) in open_holds:
            t0, _ = open_holds.pop((rid, task))
            tasks[task]["held"].append((rid, t0, when))
        elif ev == "progress" and task is not None:
            tasks[task]["progress"].append((when, rid, d.get("message", "")))
        elif ev == "task" and task is not None:
            states = tasks[task]["states"]
            entry = (d.get("message", ""), tuple(d.get("robots", ())))
            if not states or states[-1][1:] != entry:
                states.append((when, *entry))
        elif ev == "peer_lost":
            robots[rid]["lost_peers"] += [(when, p) for p in d.get("robots", ())]
    return end


def _task_name(tid: int) -> str:
    return f"{tid} ({tid >> 16}.{tid & 0xFFFF})"


def print_summary(s: dict, out=None) -> None:
    out = sys.stdout if out is None else out
    p = lambda *a: print(*a, file=out)       # noqa: E731
    p(f"{s['source']}: {s['messages']} messages on {len(s['channels'])} channels, up to t = {s['end']:.2f} s"
      + (f"; {s['skipped']} not understood" if s["skipped"] else "")
      + (f"; the file ends early ({s['truncated']}): read up to its last whole chunk" if s["truncated"] else ""))
    for rid, r in s["robots"].items():
        span = "no poses" if r["first"] is None else \
            f"{r['poses']} poses from {r['first']:.2f} to {r['last']:.2f} s, moved {r['moved']:.2f} m"
        p(f"robot {rid}: {span}")
        if r["sent"]:
            p("  sent: " + ", ".join(f"{k} {v}" for k, v in sorted(r["sent"].items())))
        if r["received"]:
            p("  received: " + ", ".join(f"{k} {v}" for k, v in sorted(r["received"].items())))
        st = r["stats"]
        if st:
            from runtime.comms.link import DROP_REASONS
            link = st.get("link") or {}
            drops = {k: v for k, v in {**st.get("fleet_dropped", {}), **st.get("agent_dropped", {})}.items() if v}
            p(f"  link: sent {link.get('sent', '?')}, received {link.get('received', '?')}, dropped "
              f"{sum(v for k, v in link.items() if k in DROP_REASONS)}; allocation dropped "
              + (", ".join(f"{k} {v}" for k, v in sorted(drops.items())) or "nothing"))
        for when, peer in r["lost_peers"]:
            p(f"  lost peer {peer} at {when:.2f} s")
    for tid, t in s["tasks"].items():
        p(f"task {_task_name(tid)}:")
        for rid, t0, t1 in sorted(t["held"], key=lambda h: (h[1], h[0])):
            p(f"  held by robot {rid} from {t0:.2f} to " + ("the end" if t1 is None else f"{t1:.2f} s"))
        for c in sorted(t["coalitions"]):
            p(f"  coalition {list(c)}")
        for when, rid, what in t["progress"]:
            p(f"  {what} (robot {rid}) at {when:.2f} s")
        for when, state, by in t["states"]:
            p(f"  {state} at {when:.2f} s" + (f" by {list(by)}" if by else ""))


def _main(args) -> int:
    print_summary(summarize(args.file))
    return 0
