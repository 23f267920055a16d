"""Experiment output: one CSV, one markdown table, one PNG per experiment, in one directory."""
from __future__ import annotations

import csv
import math
import os
from pathlib import Path
from typing import Iterable, Sequence


def write_csv(path: str | Path, rows: Sequence[dict]) -> Path:
    """Write ``rows`` (columns in order of first appearance) through a temporary file renamed over ``path``,
    so that a run killed mid-write leaves the previous file whole (long runs rewrite theirs as they go)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fields: list[str] = []
    for row in rows:
        fields.extend(k for k in row if k not in fields)
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields)
        writer.writeheader()
        writer.writerows(rows)
    os.replace(tmp, path)
    return path


def _fmt(v) -> str:
    if isinstance(v, float):
        if math.isnan(v):
            return "-"
        return f"{v:.4g}" if abs(v) < 1e5 else f"{v:.3e}"
    return str(v)


def markdown_table(rows: Sequence[dict], columns: Iterable[str] | None = None) -> str:
    cols = list(columns) if columns is not None else list(rows[0]) if rows else []
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for row in rows:
        lines.append("| " + " | ".join(_fmt(row.get(c, "")) for c in cols) + " |")
    return "\n".join(lines)


def write_markdown(path: str | Path, title: str, sections: Sequence[tuple[str, str]]) -> Path:
    """``sections``: (heading, body) pairs; body is markdown (a table, notes)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    parts = [f"# {title}", ""]
    for heading, body in sections:
        parts += [f"## {heading}", "", body.rstrip(), ""]
    path.write_text("\n".join(parts))
    return path


def figure():
    """A matplotlib figure on the Agg backend (no display needed)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt.subplots(figsize=(7, 4.5), dpi=110)
