"""Cases as tasks on a Dask cluster: ``--cluster local[:N]`` or ``--cluster tcp://HOST:PORT``.

The embedded thread pool (``-j N``) stays the default; a cluster is for campaigns that
outgrow one machine. ``local[:N]`` starts a ``LocalCluster`` of N single-threaded worker
processes on this machine (default: the CPU count); ``tcp://HOST:PORT`` connects to a
running Dask scheduler whose workers have fbaconf installed and see the same paths (a shared
filesystem: suites, goldens, the decoder and the run folder).

Each case is one task (``run_case`` in a worker); results stream back to this process,
which writes them to the same resumable ``results.jsonl`` as the pool does. A worker lost
mid-run loses nothing: Dask reruns the tasks it held on another worker. Why Dask: it is the
well-kept Python engine for exactly this (task futures, ``as_completed``, lost-worker
recovery, a local cluster and a remote scheduler behind one API), so fbaconf writes none of it.
"""
from __future__ import annotations

import os
import re
from contextlib import contextmanager
from typing import Callable, Iterator

from fbaconf.errors import FbaconfInputError


class ClusterError(FbaconfInputError):
    rule = "cluster"


def parse(spec: str) -> tuple[str, str | int]:
    """``local`` / ``local:N`` -> ("local", N); ``tcp://host:port`` -> ("tcp", address)."""
    m = re.fullmatch(r"local(?::(\d+))?", spec or "")
    if m:
        n = int(m.group(1)) if m.group(1) else (os.cpu_count() or 1)
        if not 1 <= n <= 1024:
            raise ClusterError(f"--cluster {spec}: the worker count must be 1..1024")
        return "local", n
    if re.fullmatch(r"tcp://[\w.\-\[\]:]+:\d+", spec or ""):
        return "tcp", spec
    raise ClusterError(f"--cluster {spec!r}: give local, local:N or tcp://HOST:PORT")


@contextmanager
def client(spec: str) -> Iterator:
    """A connected ``distributed.Client`` for ``spec`` (closed, and a local cluster shut down, after)."""
    kind, arg = parse(spec)
    try:
        from distributed import Client, LocalCluster  # noqa: PLC0415 (Dask: optional (the cluster extra))
    except ImportError:
        raise ClusterError("--cluster needs Dask: pip install 'dask[distributed]'") from None
    if kind == "local":
        cluster = LocalCluster(n_workers=int(arg), threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=40)
        c = Client(cluster)
        try:
            yield c
        finally:
            c.close()
            cluster.close()
    else:
        try:
            c = Client(str(arg), timeout=30)
        except OSError as e:
            raise ClusterError(f"cannot reach the Dask scheduler at {arg}: {e}") from None
        try:
            yield c
        finally:
            c.close()


def run_on_cluster(c, run_case: Callable, ctx, cases, on_result: Callable, stopping: Callable[[], bool]) -> None:
    """Submit ``run_case(ctx, case)`` for every case as a task and hand each result to
    ``on_result`` as it arrives. Tasks of a lost worker are rerun by Dask; a task that raises
    is retried twice."""
    from distributed import as_completed  # noqa: PLC0415 (Dask: optional (the cluster extra))
    futures = [c.submit(run_case, ctx, case, key=f"fbaconf-case-{i}-{case.full_id}", pure=False, retries=2)
               for i, case in enumerate(cases)]
    ac = as_completed(futures, with_results=True)
    for _fut, result in ac:
        if stopping():
            c.cancel(futures)
            return
        on_result(result)
