"""The order the suite's files run in under pytest-xdist's work stealing (`make test`: ``-n 3 --dist worksteal``).

Work stealing hands each worker an equal count of tests, in collection order, as one contiguous block; an idle
worker then takes the back half of the longest queue.  In plain file order most of the long SITL files
(``test_sitl_*``) sit in the last block, so one worker starts them late while the others run out of work, and the
run ends on one long test with a core idle.  Here every worker's block is built to start with its share of the
heavy files (spread largest first, by the seconds in ``durations.json``) and to end with light ones, which are what
stealing moves.  Files stay whole where possible (their module fixtures are set up once); only light files are
split at a block's edge.  The order is the same in every worker (xdist checks that the collections agree).

``durations.json`` holds seconds per test file, from a run with ``--durations=0``:
``python tests/xdist_order.py DURATIONS_OUTPUT > tests/durations.json``.  A file it does not name counts
``DEFAULT`` seconds a test; a stale table only makes the order worse, never a test wrong."""
from __future__ import annotations

import json
import re
import sys
from collections import defaultdict
from pathlib import Path

TABLE = Path(__file__).with_name("durations.json")
DEFAULT = 0.15     # s per test of a file the table does not name (the median test of the suite is shorter)
HEAVY = 5.0        # s: a file at least this long is placed as a whole, largest first


def block_sizes(n: int, workers: int) -> list[int]:
    """The counts xdist's work stealing sends each worker first (``len(pending) // nodes_remaining``)."""
    sizes, left = [], n
    for i in range(workers):
        sizes.append(left // (workers - i))
        left -= sizes[-1]
    return sizes


def order(items: list, workers: int, seconds: dict[str, float], key=lambda item: item.nodeid.split("::")[0]) -> list:
    """``items`` reordered into ``workers`` blocks of xdist's sizes, each starting with its heavy files."""
    files: dict[str, list] = {}
    for item in items:
        files.setdefault(key(item), []).append(item)
    weight = {f: seconds.get(f, DEFAULT * len(tests)) for f, tests in files.items()}
    sizes = block_sizes(len(items), workers)
    blocks: list[list] = [[] for _ in range(workers)]
    load, count = [0.0] * workers, [0] * workers
    heavy = sorted((f for f in files if weight[f] >= HEAVY), key=lambda f: (-weight[f], f))
    for f in heavy:
        fits = [i for i in range(workers) if count[i] + len(files[f]) <= sizes[i]] or list(range(workers))
        i = min(fits, key=lambda i: (load[i], i))
        blocks[i].extend(files[f])
        load[i] += weight[f]
        count[i] += len(files[f])
    light = [t for f in files if weight[f] < HEAVY for t in files[f]]
    for i in range(workers):              # fill each block to its size, in collection order
        take = max(0, sizes[i] - count[i])
        blocks[i].extend(light[:take])
        light = light[take:]
    blocks[-1].extend(light)               # only when heavy files overfilled the blocks
    return [t for block in blocks for t in block]


def load_table(path: Path = TABLE) -> dict[str, float]:
    try:
        table = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return {str(k): float(v) for k, v in table.items() if isinstance(v, (int, float))} if isinstance(table, dict) else {}


LINE = re.compile(r"^\s*([0-9.]+)s (?:call|setup|teardown)\s+(\S+?)::")


def from_durations(text: str) -> dict[str, float]:
    """Seconds per file from pytest's ``--durations=0`` report (phases under ``--durations-min`` count nothing)."""
    per_file: dict[str, float] = defaultdict(float)
    for line in text.splitlines():
        m = LINE.match(line)
        if m:
            per_file[m.group(2)] += float(m.group(1))
    return {f: round(s, 1) for f, s in sorted(per_file.items())}


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python tests/xdist_order.py PYTEST_DURATIONS_OUTPUT > tests/durations.json")
    print(json.dumps(from_durations(Path(sys.argv[1]).read_text()), indent=0, sort_keys=True))
