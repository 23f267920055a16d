"""The daemon's path to its task: what it drives when the configured planner finds none."""
import logging
import math
from pathlib import Path

from runtime import config as C
from runtime.daemon import Daemon
from runtime.planning.costs import grid_for

BOXES = Path(__file__).resolve().parents[1] / "configs/worlds/boxes_10m.yaml"


class _Link:                      # what the daemon's constructor touches; _plan sends nothing
    module = mav = None


def _daemon(planner: str, rrt_iterations: int = 20000) -> Daemon:
    cfg = C.from_dict(C.RobotConfig, {"robot": {"id": 3}, "gps": {"enabled": False},
                                      "localization": {"initial_pose": [-2.0, 0.0, 0.0]},
                                      "allocation": {"formation": [[2.0, 0.0], [-2.0, 3.5]]},
                                      "planning": {"map": str(BOXES), "planner": planner,
                                                   "rrt_iterations": rrt_iterations}})
    return Daemon(cfg, base=object(), link=_Link())


def test_rrt_miss_drives_the_astar_path_not_a_straight_line_into_the_box(caplog):
    d = _daemon("rrt", rrt_iterations=3)        # trees of a few 0.25 m steps cannot reach 4 m away
    start, goal = (-2.0, 0.0, 0.0), (2.0, 0.0)  # the 1 m box at the origin is in between
    grid = grid_for(d.map, d.cfg.planning.inflate)
    assert not grid.segment_free(start[:2], goal)
    with caplog.at_level(logging.WARNING):
        route = d._plan(start, goal)
    assert route[0] == start[:2] and route[-1] == goal and len(route) > 2
    assert all(grid.segment_free(a, b) for a, b in zip(route, route[1:]))
    assert (d.stats.plan_fallbacks, d.stats.plan_failures) == (1, 0)
    assert d.snapshot()["plan_fallbacks"] == 1
    assert any("rrt found no path to (2.00, 0.00)" in r.getMessage() and "A*" not in r.getMessage()
               and "astar path" in r.getMessage() for r in caplog.records)


def test_no_path_at_all_heads_straight_and_is_counted():
    d = _daemon("astar")
    route = d._plan((-2.0, 0.0, 0.0), (0.0, 0.0))        # the goal is inside the box
    assert route == [(-2.0, 0.0), (0.0, 0.0)]
    assert (d.stats.plan_fallbacks, d.stats.plan_failures) == (0, 1)


def test_a_found_path_is_the_configured_planners():
    d = _daemon("rrt")
    d._plan((-2.0, 0.0, 0.0), (2.0, 0.0))
    assert (d.stats.plan_fallbacks, d.stats.plan_failures) == (0, 0)


def test_rrt_misses_in_bids_are_priced_not_bid_as_cannot():
    """A robot bidding inf for a task it can reach leaves BS and RTMA without a buyer when they resell it
    (found driving 6 robots among 40 % obstacles: one task unallocated, one robot idle)."""
    d = _daemon("rrt", rrt_iterations=3)
    astar = _daemon("astar")
    assert d._cost(0) == astar._cost(0) and d._cost(1) == astar._cost(1)     # the A* lengths
    assert math.isfinite(d._cost(0)) and math.isfinite(d._cost(1))
    assert d.stats.bid_fallbacks == 2 and d.snapshot()["bid_fallbacks"] == 2 and d.snapshot()["idle_offers"] == 0
    fine = _daemon("rrt")
    assert 4.0 < fine._cost(0) < 6.0 and fine.stats.bid_fallbacks == 0
