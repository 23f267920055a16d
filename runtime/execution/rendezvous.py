"""Meet at a point: drive there like a goto, report ``arrived``, then keep station until the allocation
agent ends the commitment (the task is done when every member of the coalition has arrived, which only
the agent knows)."""
from __future__ import annotations

from runtime.execution.goto import GotoExecutor


class RendezvousExecutor(GotoExecutor):
    @staticmethod
    def finishes_after(task) -> float | None:
        return None
