"""The import graph holds the design's layers (docs/architecture.md#layers): no import cycles, the runtime never
imports the simulator, the robot core's ground services read ports, not the daemon.

Every import counts, wherever it stands in a module (top level, inside a function, under TYPE_CHECKING): a lazy
import is still a dependency.  The graph is built from the source with ``ast``; nothing is imported.
"""
from __future__ import annotations

import ast
import functools
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("runtime", "sitl")


def modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for p in (ROOT / pkg).rglob("*.py"):
            parts = list(p.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = p
    return out


def _resolve(name: str, mods: dict) -> str | None:
    while name and name not in mods:
        name = name.rpartition(".")[0]
    return name or None


def graph() -> dict[str, set[str]]:
    """module -> the project modules it imports (``from pkg import mod`` counts as importing ``pkg.mod``); parsed once
    per session (about 2 s, most of it the generated dialect), read by every test here."""
    return {m: set(ts) for m, ts in _graph().items()}


@functools.lru_cache(maxsize=None)
def _graph() -> dict[str, set[str]]:
    mods = modules()
    edges: dict[str, set[str]] = {m: set() for m in mods}
    for m, path in mods.items():
        package = m if path.name == "__init__.py" else m.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text())):
            targets = []
            if isinstance(node, ast.Import):
                targets = [_resolve(a.name, mods) for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[:len(package.split(".")) - (node.level - 1)]
                    base = ".".join(up + ([base] if base else []))
                for a in node.names:
                    t = _resolve(f"{base}.{a.name}", mods)
                    targets.append(t if t and t != base.rpartition(".")[0] else _resolve(base, mods))
            edges[m].update(t for t in targets if t and t != m)
    return edges


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out = []
    counter = 0
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(edges[w]))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    x = stack.pop()
                    on.discard(x)
                    comp.append(x)
                    if x == v:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


def imports_from(edges, src_prefix: str, dst_prefix: str) -> list[str]:
    return sorted(f"{m} -> {t}" for m, ts in edges.items() if _under(m, src_prefix)
                  for t in ts if _under(t, dst_prefix))


def _under(module: str, prefix: str) -> bool:
    return module == prefix or module.startswith(prefix + ".")


def test_the_graph_sees_lazy_and_type_checking_imports(tmp_path):
    """The checker itself: an import inside a function and one under TYPE_CHECKING are edges."""
    edges = graph()
    assert "runtime.comms.codec" in edges["runtime.comms.link"]          # top level
    assert any(_under(t, "runtime.drivers") for t in edges["runtime.daemon"])   # inside Daemon.__init__
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_the_runtime_never_imports_the_simulator():
    assert imports_from(graph(), "runtime", "sitl") == []


def test_ground_services_read_the_core_through_ports():
    edges = graph()
    assert imports_from(edges, "runtime.comms", "runtime.daemon") == []
    assert imports_from(edges, "runtime.robot", "runtime.daemon") == []


def test_no_module_imports_one_that_imports_it_back():
    assert cycles(graph()) == []


FAMILIES = ("formation", "coalition", "dr", "comutar")


def test_allocation_families_import_the_ground_floor_not_the_fleet_or_each_other():
    edges = graph()
    wrong = []
    for m, targets in edges.items():
        parts = m.split(".")
        if parts[:2] != ["runtime", "allocation"] or len(parts) < 3 or parts[2] not in FAMILIES:
            continue
        for t in targets:
            tp = t.split(".")
            other_family = tp[:2] == ["runtime", "allocation"] and len(tp) > 2 and tp[2] in FAMILIES and tp[2] != parts[2]
            if other_family or _under(t, "runtime.fleet"):
                wrong.append(f"{m} -> {t}")
    assert wrong == []


def test_the_broadcast_address_is_defined_once():
    import re
    where = [str(p.relative_to(ROOT)) for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")
             if re.search(r"^BROADCAST\s*=", p.read_text(), re.M)]
    assert where == ["runtime/messages.py"]


def test_execution_imports_no_allocation_family():
    """Executors take data from the families (each task kind's Guidance), never their agents."""
    assert imports_from(graph(), "runtime.execution", "runtime.allocation") == []


def test_the_executive_asks_its_executors_nothing_with_hasattr():
    """Every member it uses is declared, with a default, on runtime.execution.executor.Executor."""
    tree = ast.parse((ROOT / "runtime" / "execution" / "executive.py").read_text())
    asks = [ast.unparse(n) for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)
            and n.func.id in ("hasattr", "getattr")]
    assert all(a.startswith("getattr(sensors, 'ranges'") for a in asks), asks     # the base's sensors, not executors


def test_every_executor_derives_from_the_contract():
    from runtime import tasks
    from runtime.execution import executor_class
    from runtime.execution.executor import Executor
    assert all(issubclass(executor_class(kind), Executor) for kind in tasks.KINDS)
