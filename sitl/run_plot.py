"""A picture of a SITL run: the map with the paths driven and the tasks (left), a timeline of who held
which task when (right).

``plot_run(trace, "run/trace.png")`` draws a :class:`sitl.run_trace.RunTrace` with matplotlib on the Agg
backend (no display).  Redraw a saved run without ``mrta``, from its trace or its recording::

    python -m sitl.run_plot RUN_DIR/trace.json [OUT.png]
    python -m sitl.run_plot RUN_DIR/run.mcap [OUT.png]
"""
from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

from runtime.errors import InputError
from sitl.run_trace import RunTrace, TaskMark

TASK_MARKERS = {"goto": ("D", 7), "rendezvous": ("*", 13)}      # kind -> (marker, size); others below
OTHER_MARKER = ("h", 9)
ENDS = ("done", "failed", "withdrawn", "released")               # events that close a task bar
BAR_STYLE = {                                                    # how a bar ended -> face alpha, hatch
    "done": (0.85, None), "failed": (0.35, "xxx"), "withdrawn": (0.25, "///"), "released": (0.15, None),
    "lost": (0.35, "..."), "open": (0.25, None),
}


@dataclass
class Bar:
    """One robot holding one task on the timeline, from ``t0`` (awarded) to ``t1``, ended by ``how``."""
    robot: int
    task: int | None
    t0: float
    t1: float
    how: str                    # "done" | "failed" | "withdrawn" | "released" | "lost" | "open" (held at the end)
    lane: int = 0
    lanes: int = 1


# ---------------------------------------------------------------------- derived facts (no matplotlib)

def robot_colours(ids: list[int]) -> dict[int, tuple]:
    """A distinct colour per robot (tab10 up to 10 robots, tab20 beyond), by sorted id."""
    from matplotlib import colormaps
    cmap = colormaps["tab10" if len(ids) <= 10 else "tab20"]
    return {rid: cmap(k % cmap.N) for k, rid in enumerate(sorted(ids))}


def task_bars(trace: RunTrace) -> list[Bar]:
    """Intervals from "awarded" to the task's end for each robot; overlapping bars get separate lanes."""
    end = trace.end_time()
    lost = {rid: tr.lost_at for rid, tr in trace.robots.items() if tr.lost_at is not None}
    held: dict[tuple[int, int | None], float] = {}
    bars: list[Bar] = []
    for ev in sorted(trace.events, key=lambda e: e.t):
        if ev.what == "awarded":
            for rid in ev.robots:
                held.setdefault((rid, ev.task), ev.t)
        elif ev.what in ENDS or ev.what == "lost":
            keys = [k for k in held
                    if (ev.what == "lost" or k[1] == ev.task) and (not ev.robots or k[0] in ev.robots)]
            for k in keys:
                bars.append(Bar(k[0], k[1], held.pop(k), ev.t, ev.what))
    for (rid, task), t0 in held.items():
        t_lost = lost.get(rid)
        bars.append(Bar(rid, task, t0, t_lost if t_lost is not None and t_lost >= t0 else end,
                        "lost" if t_lost is not None and t_lost >= t0 else "open"))
    _assign_lanes(bars)
    return bars


def _assign_lanes(bars: list[Bar]) -> None:
    by_robot: dict[int, list[Bar]] = {}
    for b in sorted(bars, key=lambda b: (b.t0, b.t1)):
        by_robot.setdefault(b.robot, []).append(b)
    for row in by_robot.values():
        lane_end: list[float] = []
        for b in row:
            free = [i for i, t in enumerate(lane_end) if t <= b.t0]
            b.lane = free[0] if free else len(lane_end)
            if free:
                lane_end[b.lane] = b.t1
            else:
                lane_end.append(b.t1)
        for b in row:
            b.lanes = len(lane_end)


def task_outcome(trace: RunTrace, task: TaskMark) -> tuple[str, tuple[int, ...], float | None]:
    """("done" | "failed" | "arrived" | "open", the robots that did it (or got there), when).  "arrived": a
    task that is never done (station keeping) with a robot on it."""
    mine = sorted((e for e in trace.events if e.task == task.id), key=lambda e: e.t)
    ends = [e for e in mine if e.what in ("done", "failed")]
    if ends:
        last = ends[-1]
        return last.what, last.robots or _arrived(mine), last.t
    arrivals = [e for e in mine if e.what == "arrived"]
    if arrivals:
        return "arrived", _arrived(mine), arrivals[0].t
    return "open", (), None


def _arrived(events) -> tuple[int, ...]:
    return tuple(dict.fromkeys(r for e in events if e.what == "arrived" for r in e.robots))


def handin_ticks(trace: RunTrace, merge: float) -> list[tuple[float, str]]:
    """(time, labels) of task hand-ins; hand-ins less than ``merge`` s after a tick share it ("T5, RV")."""
    ticks: list[tuple[float, list[str]]] = []
    for t, name in sorted((tk.arrived_at, tk.name) for tk in trace.tasks.values() if tk.arrived_at is not None):
        if ticks and t - ticks[-1][0] < merge:
            ticks[-1][1].append(name)
        else:
            ticks.append((t, [name]))
    return [(t, ", ".join(names)) for t, names in ticks]


def box_corners(center, size, yaw: float) -> list[tuple[float, float]]:
    c, s = math.cos(yaw), math.sin(yaw)
    hx, hy = size[0] / 2, size[1] / 2
    return [(center[0] + c * dx - s * dy, center[1] + s * dx + c * dy)
            for dx, dy in ((-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy))]


def _fmt_t(t: float) -> str:
    return f"{t:.0f} s" if t >= 10 else f"{t:.1f} s"


# ---------------------------------------------------------------------- drawing

def plot_run(trace: RunTrace, path: str | Path) -> Path:
    """Draw ``trace`` to the PNG ``path`` (its directory is created) and return the path."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    colours = robot_colours(list(trace.robots))
    fig, (ax_map, ax_time) = plt.subplots(1, 2, figsize=(16, 8), dpi=110,
                                          gridspec_kw={"width_ratios": [1.0, 1.15]})
    try:
        _draw_map(ax_map, trace, colours)
        _draw_timeline(ax_time, trace, colours)
        fig.suptitle(trace.title or "SITL run", fontsize=12)
        fig.tight_layout()
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fig.savefig(path)
        except OSError as exc:
            raise InputError(f"{path}: expected a writable PNG path ({exc.strerror or exc})") from None
    finally:
        plt.close(fig)
    return path


def _draw_map(ax, trace: RunTrace, colours: dict) -> None:
    from matplotlib.lines import Line2D
    from matplotlib.patches import Circle, Polygon, Rectangle

    w = trace.world
    sx, sy = w.size
    ax.add_patch(Rectangle((-sx / 2, -sy / 2), sx, sy, fill=False, zorder=1,
                           lw=3.0 if w.walls else 1.0, ls="-" if w.walls else "--",
                           ec="0.15" if w.walls else "0.6"))
    for box in w.obstacles:
        ax.add_patch(Polygon(box_corners(box.center, box.size, box.yaw), closed=True, zorder=1,
                             fc="0.78", ec="0.35", hatch="//", lw=1.0))

    placed: list[tuple[float, float]] = []          # final poses already labelled (stack labels that meet)
    for rid in sorted(trace.robots):
        tr, col = trace.robots[rid], colours[rid]
        if not tr.samples:
            continue
        xs = [s[1] for s in tr.samples]
        ys = [s[2] for s in tr.samples]
        ax.plot(xs, ys, "-", color=col, lw=1.6 if len(trace.robots) <= 6 else 1.2, alpha=0.9, zorder=3)
        ax.plot(xs[:1], ys[:1], "s", ms=8, mfc="white", mec=col, mew=2.0, zorder=4)
        if tr.lost_at is not None:              # where it was when lost (the body may have moved on)
            lost = tr.pose_at(tr.lost_at)
            ax.plot([lost[1]], [lost[2]], "X", ms=15, mfc="red", mec="black", mew=1.0, zorder=6)
        _, x, y, yaw = tr.samples[-1]
        ax.add_patch(Circle((x, y), tr.radius, fc=col, ec="black", alpha=0.45, lw=1.0, zorder=4))
        ax.plot([x, x + tr.radius * math.cos(yaw)], [y, y + tr.radius * math.sin(yaw)], "-", color="black",
                lw=1.2, zorder=5)
        near = sum(math.hypot(x - px, y - py) < 0.6 for px, py in placed)
        placed.append((x, y))
        ax.annotate(f"R{rid}", (x, y), xytext=(0, -12 - 10 * near), textcoords="offset points",
                    ha="center", va="top", fontsize=8, fontweight="bold", color=col, zorder=6)

    for task in trace.tasks.values():
        how, doers, when = task_outcome(trace, task)
        marker, ms = TASK_MARKERS.get(task.kind, OTHER_MARKER)
        face = "white" if how == "open" else ("0.3" if how == "failed" else
                                                colours.get(doers[0], "0.5") if len(doers) == 1 else "gold")
        ax.plot([task.x], [task.y], marker, ms=ms, mfc=face, mec="red" if how == "failed" else "black",
                mew=1.3, zorder=7)
        for rid in doers:
            tr = trace.robots.get(rid)
            pose = tr.pose_at(when) if tr is not None and when is not None else None
            if pose is not None:
                ax.plot([task.x, pose[1]], [task.y, pose[2]], ":", color=colours[rid], lw=1.2, zorder=6)
        text = task.name + (f" ({task.need})" if task.need > 1 else "")
        if how != "open":
            text += "\n" + " ".join(filter(None, ("+".join(f"R{r}" for r in doers),
                                                   "failed" if how == "failed" else "",
                                                   _fmt_t(when) if when is not None else "")))
        ax.annotate(text, (task.x, task.y), xytext=(7, 5), textcoords="offset points", zorder=8,
                    fontsize=7 if len(trace.tasks) <= 15 else 6,
                    linespacing=0.95, bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.7})

    margin = 0.05 * max(sx, sy)
    ax.set_xlim(-sx / 2 - margin, sx / 2 + margin)
    ax.set_ylim(-sy / 2 - margin, sy / 2 + margin)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, east)")
    ax.set_ylabel("y (m, north)")
    ax.grid(True, alpha=0.25)
    ax.set_title("paths driven and tasks", fontsize=10)

    handles = [Line2D([], [], ls="", marker="s", ms=7, mfc="white", mec="0.2", mew=1.5, label="start"),
               Line2D([], [], ls="", marker="o", ms=10, mfc="0.6", mec="black", alpha=0.6, label="final pose (radius)"),
               Line2D([], [], ls="", marker="X", ms=10, mfc="red", mec="black", label="robot lost")]
    kinds = sorted({t.kind for t in trace.tasks.values()})
    for kind in kinds:
        marker, ms = TASK_MARKERS.get(kind, OTHER_MARKER)
        handles.append(Line2D([], [], ls="", marker=marker, ms=min(ms, 11), mfc="white", mec="black", label=kind))
    if trace.tasks:
        handles.append(Line2D([], [], ls=":", color="0.3", label="task - robot that did it"))
    handles += [Line2D([], [], color=colours[r], lw=2.5, label=f"R{r}") for r in sorted(trace.robots)]
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=min(6, len(handles)),
              fontsize=7, frameon=False)


def _draw_timeline(ax, trace: RunTrace, colours: dict) -> None:
    from matplotlib.lines import Line2D
    from matplotlib.patches import Rectangle

    ids = sorted(trace.robots) or sorted({r for e in trace.events for r in e.robots})
    row = {rid: len(ids) - 1 - k for k, rid in enumerate(ids)}      # first robot on top
    end = max(trace.end_time(), 1.0)
    names = {tid: tk.name for tid, tk in trace.tasks.items()}
    px_per_s = ax.get_window_extent().width / end * 0.98              # for fitting labels inside bars

    for rid, y in row.items():
        ax.axhspan(y - 0.5, y + 0.5, color="0.96" if y % 2 else "white", zorder=0)
        _shade_disarmed(ax, trace, rid, y, end)
    bar_y: dict[tuple[int, int | None], float] = {}    # (robot, task) -> centre of its bar, for ticks
    for b in task_bars(trace):
        if b.robot not in row:
            continue
        h = 0.7 / b.lanes
        y0 = row[b.robot] - 0.35 + (b.lanes - 1 - b.lane) * h
        bar_y[(b.robot, b.task)] = y0 + h * 0.46
        col = colours.get(b.robot, "0.5")
        alpha, hatch = BAR_STYLE[b.how]
        ax.add_patch(Rectangle((b.t0, y0), max(b.t1 - b.t0, end * 0.002), h * 0.92, fc=col, alpha=alpha,
                               hatch=hatch, ec=col, lw=1.0, ls="--" if b.how == "open" else "-", zorder=2))
        ax.add_patch(Rectangle((b.t0, y0), max(b.t1 - b.t0, end * 0.002), h * 0.92, fill=False, ec=col, lw=1.0,
                               zorder=3))
        label = names.get(b.task, "?" if b.task is None else f"T{b.task}")
        if b.how in ("failed", "withdrawn"):
            label += f" {b.how}"
        inside = (b.t1 - b.t0) * px_per_s > 6.5 * len(label) + 6
        ax.text(b.t0 + (b.t1 - b.t0) / 2 if inside else b.t1, y0 + h * 0.46, (label if inside else " " + label),
                ha="center" if inside else "left", va="center", fontsize=7 if b.lanes < 3 else 6, zorder=4,
                color="black", clip_on=True)

    for ev in trace.events:
        ys = [bar_y.get((r, ev.task), row[r]) for r in ev.robots if r in row]
        if ev.what == "arrived":
            ax.plot([ev.t] * len(ys), ys, "|", ms=14, mew=2.0, color="black", zorder=5)
        elif ev.what == "lost":
            ax.plot([ev.t] * len(ys), ys, "X", ms=12, mfc="red", mec="black", zorder=6)
    for rid, tr in trace.robots.items():
        if tr.lost_at is not None and not any(e.what == "lost" and rid in e.robots for e in trace.events):
            ax.plot([tr.lost_at], [row[rid]], "X", ms=12, mfc="red", mec="black", zorder=6)

    handins = handin_ticks(trace, merge=end * 0.012)
    for t, _ in handins:
        ax.axvline(t, color="0.5", lw=0.6, ls=":", zorder=1)
    top = ax.secondary_xaxis("top")
    top.set_xticks([t for t, _ in handins], labels=[n for _, n in handins], rotation=90, fontsize=7)
    if handins:
        top.set_xlabel("task handed in", fontsize=8)

    ax.set_xlim(0, end * 1.02)
    ax.set_ylim(-0.5, max(len(ids), 1) - 0.5)
    ax.set_yticks(list(row.values()),
                  labels=[f"R{rid}" + (f" {trace.robots[rid].base}" if rid in trace.robots else "") for rid in row])
    for tick, rid in zip(ax.get_yticklabels(), row):
        tick.set_color(colours.get(rid, "black"))
    ax.set_xlabel("sim time (s)")
    ax.grid(True, axis="x", alpha=0.25)
    ax.set_title("who held which task, when (awarded to handed in)", fontsize=10)
    handles = [Rectangle((0, 0), 1, 1, fc="0.5", alpha=BAR_STYLE[k][0], hatch=BAR_STYLE[k][1], ec="0.3",
                         ls="--" if k == "open" else "-", label={"open": "still held at end", "lost": "held when lost"}.get(k, k))
               for k in BAR_STYLE]
    handles += [Line2D([], [], ls="", marker="|", ms=10, mew=2, color="black", label="arrived"),
                Line2D([], [], ls="", marker="X", ms=9, mfc="red", mec="black", label="lost"),
                Rectangle((0, 0), 1, 1, fc="0.85", ec="none", label="disarmed")]
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=5, fontsize=7, frameon=False)


def _shade_disarmed(ax, trace: RunTrace, rid: int, y: float, end: float) -> None:
    """Grey the row where the robot was disarmed (from "disarmed" to the next "armed" or the end)."""
    since = None
    for ev in sorted((e for e in trace.events if rid in e.robots and e.what in ("armed", "disarmed")),
                     key=lambda e: e.t):
        if ev.what == "disarmed" and since is None:
            since = ev.t
        elif ev.what == "armed" and since is not None:
            ax.fill_between([since, ev.t], y - 0.45, y + 0.45, color="0.85", lw=0, zorder=1)
            since = None
    if since is not None:
        ax.fill_between([since, end * 1.02], y - 0.45, y + 0.45, color="0.85", lw=0, zorder=1)


# ---------------------------------------------------------------------- command line

def read_trace(path: str | Path) -> RunTrace:
    """A run's trace from ``trace.json``, or from the run's recording (a file ending in ``.mcap``)."""
    if str(path).endswith(".mcap"):
        from sitl.recording import trace_from_mcap
        return trace_from_mcap(path)
    return RunTrace.read(path)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m sitl.run_plot",
                                description="Redraw a SITL run from its trace.json or its recording (run.mcap).")
    p.add_argument("trace", help="RUN_DIR/trace.json or RUN_DIR/run.mcap written by the launcher")
    p.add_argument("out", nargs="?", help="PNG to write (default: beside the trace, same name, .png)")
    args = p.parse_args(argv)
    try:
        trace = read_trace(args.trace)
        out = plot_run(trace, args.out or Path(args.trace).with_suffix(".png"))
    except InputError as exc:
        print(f"run_plot: {exc}", file=sys.stderr)
        return 2
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
