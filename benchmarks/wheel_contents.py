"""What the wheel holds: the packages runtime and sitl and nothing else top-level (no tests), with the shipped MAVLink
bindings and the example configs inside (docs/deploy.md).

    python benchmarks/wheel_contents.py [WHEEL]

Without WHEEL it builds one from this checkout (pip wheel . --no-deps, into a temp dir) and also checks that every
module in it is the checkout's.  Prints the top-level
entries with their file counts, then each problem; exit 1 when there is one.
"""
from __future__ import annotations

import subprocess
import sys
import tempfile
import zipfile
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TOP = {"runtime", "sitl"}
MUST = ("runtime/comms/_dialect/mrta.py", "runtime/comms/_dialect/KEY", "runtime/comms/mrta.xml",
        "runtime/examples/fleets/create2_4.yaml", "runtime/examples/robots/create2.yaml",
        "runtime/examples/worlds/arena_10m.yaml", "runtime/examples/missions/square_6.plan",
        "runtime/deploy/mrta-daemon@.service", "runtime/deploy/99-mrta-serial.rules")


def build(out: Path) -> Path:
    """``pip wheel`` this checkout into ``out``; the wheel's path."""
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "-q", "-w", str(out)],
                   check=True, capture_output=True, text=True)
    return next(out.glob("mrta_runtime-*.whl"))


def tops(names: list[str]) -> Counter:
    """File count per top-level entry (``*.dist-info`` as one)."""
    return Counter("*.dist-info" if n.split("/")[0].endswith(".dist-info") else n.split("/")[0] for n in names)


def stale(wheel: Path) -> list[str]:
    """Modules of ``wheel`` that differ from this checkout's: setuptools copies into ``build/lib`` only what is
    newer than the copy there, so a ``build/`` left by an earlier ``pip wheel`` can ship old code (seen here: a
    wheel whose robot core predated the daemon it shipped with)."""
    z = zipfile.ZipFile(wheel)
    why = "(a stale build/ directory? rm -rf build and build again)"
    mods = [n for n in z.namelist() if n.endswith(".py") and n.split("/")[0] in TOP]
    return ([f"{n} is not in the checkout {why}" for n in mods if not (ROOT / n).is_file()]
            + [f"{n} differs from the checkout's {why}" for n in mods
               if (ROOT / n).is_file() and z.read(n) != (ROOT / n).read_bytes()])


def problems(names: list[str]) -> list[str]:
    """What is wrong with a wheel holding ``names``."""
    out = [f"top-level {t!r}: expected only {sorted(TOP)} and the dist-info" for t in tops(names)
           if t not in TOP | {"*.dist-info"}]
    out += [f"missing {m}" for m in MUST if m not in names]
    shipped = {n.removeprefix("runtime/examples/") for n in names if n.startswith("runtime/examples/")}
    configs = {str(p.relative_to(ROOT / "configs")) for p in (ROOT / "configs").glob("*/*") if p.is_file()}
    out += [f"configs/{c} is not in runtime/examples/" for c in sorted(configs - shipped)]
    return out


def main(argv: list[str]) -> int:
    with tempfile.TemporaryDirectory() as tmp:
        wheel = Path(argv[0]) if argv else build(Path(tmp))
        names = zipfile.ZipFile(wheel).namelist()
        print(f"{wheel.name}: {len(names)} files")
        for top, n in sorted(tops(names).items()):
            print(f"  {top:<24} {n:4d}")
        found = problems(names) + ([] if argv else stale(wheel))
        for p in found:
            print(f"problem: {p}")
        return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
