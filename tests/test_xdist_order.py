"""tests/xdist_order.py: the suite's order under work stealing is a permutation of the collection, in blocks of the
sizes xdist hands out, each block starting with its heavy files, whole and largest first."""
from __future__ import annotations

from hypothesis import assume, given, strategies as st

from tests import xdist_order


class Item:
    def __init__(self, nodeid: str):
        self.nodeid = nodeid


@given(st.lists(st.integers(1, 30), min_size=1, max_size=25), st.integers(1, 4),
       st.lists(st.floats(0, 200), min_size=25, max_size=25))
def test_blocks_are_a_permutation_with_heavy_files_whole_and_first(counts, workers, secs):
    items = [Item(f"tests/test_{f}.py::t{i}") for f, n in enumerate(counts) for i in range(n)]
    seconds = {f"tests/test_{f}.py": secs[f] for f in range(len(counts)) if secs[f] > 1}
    out = xdist_order.order(items, workers, seconds)
    assert sorted(t.nodeid for t in out) == sorted(t.nodeid for t in items)
    sizes = xdist_order.block_sizes(len(items), workers)
    assert sum(sizes) == len(items) and max(sizes) - min(sizes) <= 1
    file_of = lambda t: t.nodeid.split("::")[0]
    for f in {file_of(t) for t in items}:      # a file's tests keep their order
        mine = [t.nodeid for t in out if file_of(t) == f]
        assert mine == sorted(mine, key=lambda n: int(n.rsplit("::t", 1)[1]))
    heavy = {f for f, s in seconds.items() if s >= xdist_order.HEAVY}
    assume(sum(counts[int(f[11:-3])] for f in heavy) <= min(sizes))   # as in the suite: heavy files fit any block
    k = 0
    for size in sizes:
        block = [file_of(t) for t in out[k:k + size]]
        k += size
        firsts = [f for i, f in enumerate(block) if i == 0 or block[i - 1] != f]
        heavy_here = [f for f in firsts if f in heavy]
        assert firsts[:len(heavy_here)] == heavy_here                 # heavy files open the block, whole ...
        assert [seconds[f] for f in heavy_here] == sorted((seconds[f] for f in heavy_here), reverse=True)
    block_of = {}
    for i, t in enumerate(out):                 # ... and each heavy file lies in one block
        if file_of(t) in heavy:
            b = next(j for j in range(workers) if i < sum(sizes[:j + 1]))
            assert block_of.setdefault(file_of(t), b) == b


def test_the_table_is_read_from_a_durations_report(tmp_path):
    report = ("12.50s call     tests/test_a.py::test_x\n0.40s setup    tests/test_a.py::test_x\n"
              "3.00s call     tests/test_b.py::test_y[1-2]\n(1000 durations < 0.3s hidden.)\n")
    assert xdist_order.from_durations(report) == {"tests/test_a.py": 12.9, "tests/test_b.py": 3.0}
    (tmp_path / "d.json").write_text("not json")
    assert xdist_order.load_table(tmp_path / "d.json") == {}
