"""A fleet node skips its tick only when the tick would do nothing (FleetNode.idle): checked on a DR foraging run,
where every tick judged idle is run anyway and must send nothing and change no state of the node or its agent."""
from __future__ import annotations

import pytest

from runtime.fleet import node as fleet_node
from runtime.fleet.node import FleetNode
from sitl.foraging.harness import ForagingConfig, ForagingRun


def test_every_skipped_tick_of_a_dr_foraging_run_would_have_done_nothing(monkeypatch):
    judged = []
    checked = FleetNode._checked_tick

    def counting(self, now):
        judged.append(self.robot_id)
        return checked(self, now)

    monkeypatch.setattr(FleetNode, "check_idle", True)
    monkeypatch.setattr(FleetNode, "_checked_tick", counting)
    fr = ForagingRun(ForagingConfig(robots=10, method="dr", time_limit=40.0, seed=2))
    try:
        result = fr.run()
    finally:
        fr.close()
    ticks = 10 * 400
    assert len(judged) > ticks // 4, f"only {len(judged)} of about {ticks} ticks were judged idle"
    assert len(set(judged)) > 5          # members across the fleet, not one robot
    assert result.moved > 0              # loads taken and reported: the outboxes were busy too


class _Liar:
    """An agent that says it is quiet and sends a message every tick."""
    commitments = ()
    allocating = False

    def quiet(self, now):
        return True

    def on_tick(self, now):
        return ["hello"]

    def pop_events(self):
        return []


def test_a_tick_judged_idle_that_does_something_is_caught(monkeypatch):
    monkeypatch.setattr(FleetNode, "check_idle", True)
    node = FleetNode(1, _Liar())
    node.begin((0.0, 0.0))
    assert node.tick(0.0)                  # the first tick runs (inputs since)
    assert node.idle(0.5)
    with pytest.raises(AssertionError, match="judged idle did something"):
        node.tick(0.5)


def test_a_state_change_in_an_idle_tick_is_caught(monkeypatch):
    class Changer(_Liar):
        n = 0

        def on_tick(self, now):
            self.n += 1
            return []

    monkeypatch.setattr(FleetNode, "check_idle", True)
    node = FleetNode(1, Changer())
    node.begin((0.0, 0.0))
    node.tick(0.0)
    with pytest.raises(AssertionError):
        node.tick(0.5)
    assert fleet_node._plain({"a": [1, {2}]}, set()) == (("'a'", ("list", 1, ("set", 2))),)
