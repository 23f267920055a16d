"""The sweep executor: one seam through which every sweep (``mrta experiment *``, the benchmarks that fan out runs)
hands its runs to whatever runs them.

* ``--jobs N`` (no ``--cluster``): N local processes (``concurrent.futures.ProcessPoolExecutor``); 1: in this
  process, in order.
* ``--cluster local``: a Dask ``LocalCluster`` of ``--jobs`` single-thread worker processes, listening on
  127.0.0.1 only (CI, laptops).
* ``--cluster tcp://HOST:PORT``: the Dask scheduler there (``dask scheduler`` / ``dask worker``; docs/experiments.md).
* ``--cluster ray://HOST:PORT``: a Ray cluster through Ray Client (``ray start --head``), the ``[ray]`` extra.

Each is a ``concurrent.futures.Executor``; :func:`run_each` submits every task and yields ``(index, result)`` as
each finishes, so the callers' progress lines and resume files are the same whatever runs the tasks.  A task is a
module-level function and plain picklable arguments; it must read nothing from the submitting machine's working
tree: a file a run needs travels with the task as a :class:`Carried` (its bytes), or resolves inside the
installed package.  Dask and Ray need the ``[cluster]`` / ``[ray]`` extras; without them ``--cluster`` says so in
one line (exit 2)."""
from __future__ import annotations

import argparse
import atexit
import hashlib
import os
import shutil
import tempfile
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from runtime.errors import InputError
from runtime.log import get_logger

log = get_logger("experiments.executor")

NEEDS_DASK = "pip install 'mrta-runtime[cluster]' (dask, distributed)"
NEEDS_RAY = "pip install 'mrta-runtime[ray]'"
CONNECT_TIMEOUT = 30.0          # s to reach a scheduler / Ray head before giving up with one line


# ---------------------------------------------------------------------- arguments

def add_arguments(parser: argparse.ArgumentParser, jobs: int | None = None, what: str = "runs") -> None:
    """``--jobs`` and ``--cluster`` (``jobs``: the default for --jobs; None: every core)."""
    default = jobs if jobs is not None else os.cpu_count() or 1
    parser.add_argument("--jobs", type=int, default=default,
                        help=f"{what} in this many local processes, or workers of --cluster local "
                             f"(default {default})")
    parser.add_argument("--cluster", default=None, metavar="ADDRESS",
                        help="run on a cluster: local (a Dask LocalCluster on 127.0.0.1), tcp://HOST:PORT (a Dask "
                             "scheduler) or ray://HOST:PORT (Ray); see docs/experiments.md")


def check_arguments(args) -> None:
    """One line (InputError) for a bad ``--jobs`` or ``--cluster``."""
    if args.jobs < 1:
        raise InputError(f"--jobs {args.jobs}: expected at least 1")
    cluster = getattr(args, "cluster", None)
    if cluster is not None and kind(cluster) is None:
        raise InputError(f"--cluster {cluster!r}: expected local, tcp://HOST:PORT or ray://HOST:PORT")


def kind(cluster: str | None) -> str | None:
    """'pool' (no cluster), 'local', 'dask', 'ray', or None for an address of no known form."""
    if cluster is None:
        return "pool"
    if cluster == "local":
        return "local"
    scheme, sep, rest = cluster.partition("://")
    if not sep or not rest:
        return None
    return {"tcp": "dask", "tls": "dask", "ray": "ray"}.get(scheme)


def command_flags(args) -> str:
    """How the sweep ran, for the command lines the reports print: ``--jobs N`` (local processes or LocalCluster
    workers) or ``--cluster ADDRESS`` (a remote cluster: its workers decide)."""
    cluster = getattr(args, "cluster", None)
    if kind(cluster) in ("dask", "ray"):
        return f"--cluster {cluster}"
    return f"--jobs {args.jobs}" + (f" --cluster {cluster}" if cluster else "")


# ---------------------------------------------------------------------- executors

@contextmanager
def open_executor(jobs: int = 1, cluster: str | None = None) -> Iterator[Executor | None]:
    """The executor ``--jobs`` / ``--cluster`` name (None: run in this process, in order); closed on exit."""
    k = kind(cluster)
    if k is None:
        raise InputError(f"--cluster {cluster!r}: expected local, tcp://HOST:PORT or ray://HOST:PORT")
    if k == "pool":
        if jobs <= 1:
            yield None
            return
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            yield pool
        return
    if k == "ray":
        with _ray(cluster) as ex:
            yield ex
        return
    with _dask(cluster if k == "dask" else None, jobs) as ex:
        yield ex


@contextmanager
def _dask(address: str | None, jobs: int) -> Iterator[Executor]:
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise InputError(f"--cluster {address or 'local'}: Dask is not installed: {NEEDS_DASK}") from None
    import dask
    import logging

    for name in ("distributed", "distributed.scheduler", "distributed.nanny", "distributed.worker"):
        logging.getLogger(name).setLevel(logging.WARNING)       # the sweep's own progress lines say what happens
    cluster = None
    # workers keep one run each (pybullet and the runs are single-threaded); no dashboard (bokeh is not a dependency)
    with dask.config.set({"distributed.worker.daemon": False, "distributed.scheduler.work-stealing": True}):
        try:
            if address is None:
                cluster = LocalCluster(n_workers=jobs, threads_per_worker=1, processes=True, host="127.0.0.1",
                                       dashboard_address=None, memory_limit=0, silence_logs=40)
                client = Client(cluster, set_as_default=False)
            else:
                client = Client(address, timeout=CONNECT_TIMEOUT, set_as_default=False)
        except (OSError, TimeoutError) as exc:
            if cluster is not None:
                cluster.close()
            raise InputError(f"--cluster {address or 'local'}: no Dask scheduler answered ({exc})") from None
        log.info("sweep on Dask %s: %d workers", address or "LocalCluster 127.0.0.1",
                 len(client.scheduler_info().get("workers", {})))
        try:
            yield client.get_executor(pure=False)
        finally:
            client.close()
            if cluster is not None:
                cluster.close()


class RayExecutor(Executor):
    """``concurrent.futures.Executor`` over Ray tasks (one CPU each); futures from ``ObjectRef.future()``."""

    def __init__(self, ray):
        self.ray = ray
        self.remote: dict[Callable, Any] = {}

    def submit(self, fn, /, *args, **kwargs) -> Future:
        if fn not in self.remote:
            self.remote[fn] = self.ray.remote(num_cpus=1, max_retries=0)(fn)
        return self.remote[fn].remote(*args, **kwargs).future()


@contextmanager
def _ray(address: str) -> Iterator[Executor]:
    try:
        import ray
    except ImportError:
        raise InputError(f"--cluster {address}: Ray is not installed: {NEEDS_RAY}") from None
    try:
        ray.init(address=address)
    except (ConnectionError, OSError, TimeoutError) as exc:
        raise InputError(f"--cluster {address}: no Ray head answered ({exc})") from None
    try:
        yield RayExecutor(ray)
    finally:
        ray.shutdown()


def run_each(fn: Callable, tasks: Sequence[tuple], jobs: int = 1, cluster: str | None = None,
             order: Sequence[int] | None = None) -> Iterator[tuple[int, Any]]:
    """``(k, fn(*tasks[k]))`` for every task, as each finishes: in this process in ``order`` (default: as given)
    with ``--jobs 1`` and no cluster, else submitted in ``order`` (put the longest first) to :func:`open_executor`.
    A task's exception is raised here; the others still under way are cancelled."""
    order = list(range(len(tasks))) if order is None else list(order)
    if not order:
        return
    workers = min(jobs, len(order)) if cluster is None else jobs
    with open_executor(1 if cluster is None and len(order) <= 1 else workers, cluster) as ex:
        if ex is None:
            for k in order:
                yield k, fn(*tasks[k])
            return
        futures = {ex.submit(fn, *tasks[k]): k for k in order}
        try:
            for fut in as_completed(futures):
                yield futures[fut], fut.result()
        finally:
            for fut in futures:
                fut.cancel()


# ---------------------------------------------------------------------- files that travel with a task

_CARRIED_DIR: Path | None = None


@dataclass(frozen=True)
class Carried:
    """A file a run needs, carried in the task: read where the sweep is submitted, written once per worker process
    (under a private temporary directory, by content hash) where the run asks for its :meth:`path`."""
    name: str
    data: bytes

    @classmethod
    def read(cls, path: str | os.PathLike) -> "Carried":
        path = Path(path)
        try:
            return cls(path.name, path.read_bytes())
        except OSError as exc:
            raise InputError(f"{path}: cannot read ({exc.strerror})") from None

    @property
    def digest(self) -> str:
        return hashlib.sha256(self.data).hexdigest()[:16]

    def path(self) -> Path:
        """The file on this machine: the same bytes under the same name, in this process's temporary directory."""
        global _CARRIED_DIR
        if _CARRIED_DIR is None or not _CARRIED_DIR.is_dir():
            _CARRIED_DIR = Path(tempfile.mkdtemp(prefix="mrta-carried-"))
            atexit.register(shutil.rmtree, _CARRIED_DIR, True)
        path = _CARRIED_DIR / self.digest / self.name
        if not path.is_file():
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix(path.suffix + ".tmp")
            tmp.write_bytes(self.data)
            tmp.replace(path)
        return path
