"""Paper 000's task model (eqs. 2-5, 8-10) as pure functions, in SI units, and the paper's units.

The runtime is SI throughout: metres, seconds, weight units (wu).  The paper counts in distance units (du) and
time units (tu); the mapping chosen (digest-000 §8) is 1 du = :data:`DU` m and 1 tu = :data:`TU` s, so the
paper's 3 du/tu is 0.25 m/s (the Pioneer 3-DX's top speed), a load time of 1 tu/wu is 0.12 s/wu and a deadline
of 900 tu is 108 s.  Eq. 5 is unit-consistent with the load time ``tau`` in s/wu:

    workCapacity = L v / (2 (tau L v + d))        wu/s, L in wu, v in m/s, d in m, tau in s/wu

Eq. 5 counts, per trip of L wu, two legs of d/v and tau per wu to load and again to unload; it leaves out the
robot's first approach to the object and rounds no trip up.
"""
from __future__ import annotations

import math
from typing import Callable, Iterable

DU = 0.01             # m per paper distance unit
TU = 0.12             # s per paper time unit


def m_from_du(du: float) -> float:
    return du * DU


def s_from_tu(tu: float) -> float:
    return tu * TU


def speed_from_paper(du_per_tu: float) -> float:
    """du/tu -> m/s (3 du/tu = 0.25 m/s)."""
    return du_per_tu * DU / TU


def capacity_to_paper(wu_per_s: float) -> float:
    """wu/s -> wu/tu (work capacities, interference)."""
    return wu_per_s * TU


def capacity_from_paper(wu_per_tu: float) -> float:
    return wu_per_tu / TU


# ---------------------------------------------------------------------------------------------- equations
def work_capacity(load: float, speed: float, distance: float, load_time: float) -> float:
    """Eq. 5: wu/s one robot moves from an object ``distance`` m from the delivery point, carrying ``load`` wu a
    trip at ``speed`` m/s and taking ``load_time`` s per wu to load and again to unload.  0 for a robot that
    cannot carry or move."""
    if load <= 0 or speed <= 0:
        return 0.0
    return load * speed / (2.0 * (load_time * load * speed + distance))


def ideal_capacity(capacities: Iterable[float]) -> float:
    """Eq. 4: the group's ideal capacity, the sum of its members' work capacities (the leader's among them)."""
    return float(sum(capacities))


def group_capacity(ideal: float, interference: float) -> float:
    """Eq. 3: the ideal capacity less the interference I (wu/s)."""
    return ideal - interference


def expected_time(workload: float, capacity: float) -> float:
    """Eq. 2: s for a group of ``capacity`` wu/s to move ``workload`` wu; infinite when the capacity is not
    positive (digest §8: the v = 0.8 error case, or I above the ideal)."""
    if workload <= 0:
        return 0.0
    return workload / capacity if capacity > 0 else math.inf


def meets_deadline(workload: float, capacity: float, deadline: float, elapsed: float = 0.0) -> bool:
    """Eq. 8, ``DL_g <= DL``, in its mid-task form ``(t - t_start) + WL(t) / groupCapacity <= DL``: ``elapsed``
    s of the deadline are gone, ``workload`` wu remain."""
    return elapsed + expected_time(workload, capacity) <= deadline


def remaining_prediction(measured: float, capacity: float, t: float, t_measured: float) -> float:
    """Eq. 9: the workload left at ``t`` predicted from ``measured`` wu left at ``t_measured`` (never below 0)."""
    return max(0.0, measured - capacity * (t - t_measured))


def utility_soft(finish: float, deadline: float, u_max: float) -> float:
    """Eq. 10: ``u_max`` before the deadline, then ``u_max * 0.07 DL / ((fT - DL) + 0.07 DL)`` (half at
    1.07 DL; continuous at DL).  ``finish`` = fT, s since the task appeared."""
    if finish < deadline:
        return u_max
    if not math.isfinite(finish):
        return 0.0
    k = 0.07 * deadline
    return u_max * k / ((finish - deadline) + k)


def utility_hard(finish: float, deadline: float, u_max: float) -> float:
    """Fig. 1a: ``u_max`` before the deadline, 0 after."""
    return u_max if finish < deadline else 0.0


UTILITIES: dict[str, Callable[[float, float, float], float]] = {"soft": utility_soft, "hard": utility_hard}


def ideal_group_size(workload: float, deadline: float, capacity: float,
                     interference: Callable[[float], float] = lambda n: 0.0, largest: int = 64) -> int | None:
    """The smallest number of robots of ``capacity`` wu/s each (interference ``interference(n)`` wu/s) that moves
    ``workload`` wu within ``deadline`` s (eq. 8); None if even ``largest`` robots cannot."""
    for n in range(1, largest + 1):
        if meets_deadline(workload, group_capacity(n * capacity, interference(n)), deadline):
            return n
    return None
