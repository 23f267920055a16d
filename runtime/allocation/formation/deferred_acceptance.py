"""The outcome of BS and RTMA in closed form: task-proposing deferred acceptance.

With the resale rule "sell to the best bid worse than the seller's own", a task that a robot gives up
goes to the next robot down that task's list of bids, and a robot holding two tasks keeps the one it
prefers.  That is Gale-Shapley deferred acceptance with the tasks proposing:

* a task ranks robots by (bid, robot id), lowest first;
* a robot ranks tasks by its keep rule, lowest first: BS by (cost, task), RTMA by
  (bid - mean of all robots' bids for the task, bid, task) (paper 002, section II-B).

Deferred acceptance ends in the same matching whatever the order of proposals, so the agents' result
does not depend on message timing, parallel auctions or retries; this module computes it directly in
O(n^2) and the tests hold the agents to it.

Both sides rank by one matrix (up to a shift per row or per column), so the stable matching is unique and
equals the greedy one, smallest entry first: BS is greedy on the costs, RTMA greedy on the costs minus
each robot's mean minus each task's mean.  RTMA's means act as one-shot estimates of the assignment
problem's dual prices; the epsilon auction (:mod:`runtime.allocation.formation.eps_auction`) finds the exact ones.  (Exact ties between floating-point keys can break the
other way if the agents sum the mean in another order; random real costs have none.)
"""
from __future__ import annotations

import numpy as np


def rtma_bids(costs) -> np.ndarray:
    """Equation (1): each robot's cost minus the mean of its costs to all tasks."""
    c = np.asarray(costs, dtype=float)
    return c - c.mean(axis=1, keepdims=True)


def deferred_acceptance(task_key: np.ndarray, robot_key: np.ndarray) -> list[int]:
    """Task-proposing deferred acceptance on an n x n problem.

    ``task_key[i, j]``: how task j ranks robot i (lower is better, ties by robot index);
    ``robot_key[i, j]``: how robot i ranks task j (lower is better, ties by task index).
    Returns the task index per robot.
    """
    tk = np.asarray(task_key, dtype=float)
    rk = np.asarray(robot_key, dtype=float)
    n = tk.shape[0]
    if tk.shape != (n, n) or rk.shape != (n, n):
        raise ValueError(f"deferred_acceptance: expected two n x n arrays, got {tk.shape} and {rk.shape}")
    # each task's robots in its order of preference (stable sort keeps ties by robot index)
    order = np.argsort(tk, axis=0, kind="stable").T
    # robot_rank[i, j]: position of task j in robot i's order
    robot_rank = np.empty((n, n), dtype=int)
    robot_rank[np.arange(n)[:, None], np.argsort(rk, axis=1, kind="stable")] = np.arange(n)
    held = [-1] * n                   # task per robot
    next_choice = [0] * n             # per task, index into its order
    free = list(range(n - 1, -1, -1))
    while free:
        task = free.pop()
        robot = int(order[task][next_choice[task]])
        next_choice[task] += 1
        current = held[robot]
        if current < 0:
            held[robot] = task
        elif robot_rank[robot, task] < robot_rank[robot, current]:
            held[robot] = task
            free.append(current)
        else:
            free.append(task)
    return held


def bs_outcome(costs) -> list[int]:
    """What BS agents end with on ``costs`` (robot x task)."""
    c = np.asarray(costs, dtype=float)
    return deferred_acceptance(c, c)


def rtma_outcome(costs) -> list[int]:
    """What RTMA agents end with on ``costs`` (robot x task)."""
    b = rtma_bids(costs)
    return deferred_acceptance(b, b - b.mean(axis=0, keepdims=True))
