"""Paper 003's allowed configuration space as one behaviour of the DAMN arbiter.

The executors of CoMutaR's task kinds (:mod:`runtime.execution.surveillance`, :mod:`runtime.execution.avoidance`)
each turn their commitment into constraint functions over the robot's next-frame window
(:mod:`runtime.control.cspace`: Alg. 2 survey, Alg. 3 sensor reader, Alg. 4 obstacle avoider).
:class:`CspaceVote` gathers every one of them each cycle, intersects and maximises
(:func:`~runtime.control.cspace.choose`), and casts the result as votes and vetoes over the
arbiter's arcs (:func:`~runtime.control.cspace.to_arc_ballot`): arcs outside the intersection are
vetoed, so whatever else votes (bumpers, the robot's own range avoidance) the command stays inside it.  An
empty intersection vetoes every arc but stop: the robot stops, and the conflict is counted and logged with the
constraints that caused it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from runtime.control import cspace as C
from runtime.control.arbiter import ArcSet, Ballot
from runtime.execution.executor import Executor


@dataclass
class CspaceVote:
    window: C.Window
    log: object = None
    name: str = "cspace"
    weight: float = 2.0
    constraints: list = field(default_factory=list)     # this cycle's, from every executor
    conflicts: int = 0                                  # cycles with an empty intersection
    blame: tuple[str, ...] = ()                         # the constraints of the last conflict
    choice: object = None

    def set(self, constraints: list) -> None:
        self.constraints = list(constraints)

    def ballot(self, arcs: ArcSet, now: float) -> Ballot:
        choice = self.choice = C.choose(self.window, self.constraints, 1)
        if choice.conflict[0]:
            blame = tuple(choice.blame[0])
            if blame != self.blame and self.log is not None:
                self.log.warning("c-space conflict: %s allow nothing together: stopping", " + ".join(blame))
            self.conflicts += 1
            self.blame = blame
        else:
            self.blame = ()
        votes, veto = C.to_arc_ballot(self.window, choice, arcs)
        return Ballot(np.asarray(votes, float), np.asarray(veto, bool))


def stop_only(win: C.Window, name: str) -> C.Constraint:
    """A constraint that allows standing still and nothing else (turning on the spot included)."""
    allowed = np.zeros((1, win.size), dtype=bool)
    allowed[0, win.stop] = True
    return C.Constraint(allowed, None, name)


class CspaceExecutor(Executor):
    """What CoMutaR's executors share: no arbiter behaviours of their own (their constraints go to the
    executive's :class:`CspaceVote`), the c-space window of the family's guide, and this cycle's constraints (set by
    ``update``)."""

    def __init__(self, commitment, ctx):
        super().__init__(commitment, ctx)
        self._cons: list = []

    @property
    def window(self) -> C.Window | None:
        return None if self.guide is None else self.guide.window

    def recommit(self, commitment, now: float) -> bool:
        self.commitment = commitment
        return True

    def constraints(self) -> list:
        return self._cons

    def cancel(self, now: float) -> None:
        self._cons = []
