"""The executor contract: every member the executive uses, each with a default (as ArduPilot Rover's ``Mode``
declares every hook), so the executive asks an executor nothing with ``hasattr``.

An executor carries out one commitment: built as ``Executor(commitment, ctx)`` (``ctx``: the executive's
:class:`~runtime.execution.executive.ExecContext`), it votes in the arbiter (``behaviours``; a path follower in
``follow`` leads the robot), or sets constraints over the robot's c-space window (``constraints()``), and reports
progress from ``update``.  What an allocation family wants it to do beyond the commitment comes as data: each cycle
the executive sets ``guide`` to what the family wrote for this task (the task kind module defines its shape, e.g.
:class:`runtime.tasks.surveillance.Guidance`); the executor never calls the agent.
"""
from __future__ import annotations

from runtime.tasks import Commitment, Progress


class Executor:
    behaviours: tuple | list = ()     # arbiter behaviours it votes with
    follow = None                     # its path follower (FollowPath), if it drives a path: the robot's lead
    goal = None                       # where it is going, for the avoidance's "what lies ahead" (None: the path's end)
    window = None                     # a c-space window (runtime.control.cspace.Window) if it sets constraints
    guide = None                      # this cycle's data from the allocation family for this task, if any

    def __init__(self, commitment: Commitment, ctx):
        self.commitment = commitment
        self.task = commitment.task
        self.ctx = ctx

    @staticmethod
    def finishes_after(task) -> float | None:
        """Seconds after arrival at which it reports the task done (None: never; the agent ends it)."""
        return None

    def recommit(self, commitment: Commitment, now: float) -> bool:
        """The same task with new partners or parameters: True if it carried on with them, False to be restarted."""
        return False

    def retune(self) -> None:
        """After the executive applied changed tunables to ``follow``'s follower: its own adjustments."""

    def begin(self, pose, now: float) -> None:
        """Before the sensors are read this cycle."""

    def bump_ended(self, pose, now: float) -> None:
        """A bumper escape ended: re-plan from here if it drives a path."""

    def update(self, pose, now: float) -> list[Progress]:
        """This cycle's work; what it reports."""
        return []

    def constraints(self) -> list:
        """This cycle's c-space constraints (none unless it has a ``window``)."""
        return []

    def cancel(self, now: float) -> None:
        """The commitment ended."""
