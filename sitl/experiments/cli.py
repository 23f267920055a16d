"""`mrta experiment NAME`: one module per paper table/figure.

Each experiment module exposes ``add_arguments(parser)`` and ``run(args) -> int`` and writes
CSV + PNG + a markdown table (with the paper's numbers beside ours) under ``--out``.
"""
from __future__ import annotations

import argparse
import functools
import importlib
import logging

EXPERIMENTS = {
    "wdp-tables": ("sitl.experiments.wdp_tables", "paper 001 Tables 3-6: IDA* and BFS nodes/seconds"),
    "formation-ideal": ("sitl.experiments.formation_ideal", "paper 002 Fig. 6 and 7: error vs Hungarian, 2-20 robots"),
    "formation-twobox": ("sitl.experiments.formation_twobox", "paper 002 Fig. 9: the two-box distribution"),
    "formation-world": ("sitl.experiments.formation_world", "paper 002 Tables I-II: A*/RRT in the pybullet world"),
    "dr-calibration": ("sitl.experiments.dr_calibration", "paper 000 Fig. 2: interference calibration, 1-8 robots x 10 distances"),
    "comutar-surveillance": ("sitl.experiments.comutar_surveillance", "paper 003 Figs. 4-7: surveillance and sensor sharing"),
    "dr-table3": ("sitl.experiments.dr_table3", "paper 000 Table 3 / Fig. 3: SR under hard deadlines, 5 strategies"),
    "dr-table4": ("sitl.experiments.dr_table4", "paper 000 Table 4 / Figs. 4-6: DR, SR, Greedy, soft and hard utility"),
    "dr-table5": ("sitl.experiments.dr_table5", "paper 000 Table 5: off-line vs on-line SVR, with and without errors"),
}


def _available() -> dict[str, tuple[str, str]]:
    out = {}
    for name, (module, help_) in EXPERIMENTS.items():
        if importlib.util.find_spec(module) is not None:
            out[name] = (module, help_)
    return out


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("experiment", help="reproduce a paper's table or figure")
    exp_sub = parser.add_subparsers(dest="experiment", metavar="NAME", required=True)
    for name, (module_name, help_) in _available().items():
        module = importlib.import_module(module_name)
        p = exp_sub.add_parser(name, help=help_)
        p.add_argument("--out", default=f"out/{name}", help="output directory (default: %(default)s)")
        module.add_arguments(p)
        p.set_defaults(func=_with_progress(module.run))


def _with_progress(run):
    """Experiments are long: their progress lines (INFO on ``mrta.experiments``) show without -v."""
    @functools.wraps(run)
    def wrapped(args):
        logger = logging.getLogger("mrta.experiments")
        if logger.getEffectiveLevel() > logging.INFO:
            logger.setLevel(logging.INFO)
        return run(args)
    return wrapped
