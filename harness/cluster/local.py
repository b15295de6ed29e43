"""The run's own cluster (``--cluster local[:N]``): a Dask scheduler and N single-threaded
worker processes on this machine that only this run can talk to (docs/fuzzing.md, "Who may
talk to the cluster").

* Mutual TLS with the run's authority (:func:`.tls.make_certificates`), its key in
  memory only. Dask's ``Security`` takes PEM text but writes it to a temporary file for each
  TLS context; :class:`RunSecurity` hands OpenSSL a memfd instead and refuses to be pickled.
* The harness is non-dumpable while the cluster lives (:func:`.tls.nondumpable`), and
  the workers are *forked* from it (Dask's ``fork`` method): non-dumpable, holding the key,
  from their first instruction. A spawned worker starts as a fresh, dumpable program, whose
  pipes — the pickled worker arguments, the queues whose pickles the nanny in the harness
  reads — any process of the user can open through ``/proc`` in that instant.
* No HTTP: no route is served (Dask's dashboard and ``/info`` pages show logs, call stacks and
  task keys to whoever reaches the port) and the HTTP servers stop listening as they start.
"""

from __future__ import annotations

import ssl
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, NoReturn

import dask
from distributed import Nanny, Scheduler, SpecCluster, Worker
from distributed.security import Security

from .tls import RunCertificates, memory_file, nondumpable

_IN_MEMORY = "<in memory: fbaconf run>"  # what Dask's repr of the Security shows for the certificate

# Dask's configuration while the cluster lives: forked workers, no HTTP route anywhere.
CONFIG = {
    "distributed.worker.multiprocessing-method": "fork",
    "distributed.scheduler.http.routes": [],
    "distributed.worker.http.routes": [],
}


class RunSecurity(Security):
    """Mutual TLS for every role (scheduler, worker, nanny, client) from the run's certificates
    in memory. Never pickled: the workers are forked, and have it."""

    def __init__(self, certs: RunCertificates) -> None:
        super().__init__(
            require_encryption=True,
            tls_ca_file=certs.ca.decode("ascii"),
            tls_client_cert=_IN_MEMORY,
            tls_client_key=None,
            tls_scheduler_cert=_IN_MEMORY,
            tls_scheduler_key=None,
            tls_worker_cert=_IN_MEMORY,
            tls_worker_key=None,
        )
        self._chain = certs.cert + certs.key

    def _get_tls_context(self, tls: dict[str, Any], purpose: ssl.Purpose) -> ssl.SSLContext | None:
        context: ssl.SSLContext | None
        if tls.get("cert") != _IN_MEMORY:
            context = super()._get_tls_context(tls, purpose)
            return context
        with memory_file(self._chain) as path:  # Dask's own checks and settings, the chain from memory
            context = super()._get_tls_context({**tls, "cert": path, "key": None}, purpose)
            return context

    def __reduce__(self) -> NoReturn:
        raise TypeError("the run's TLS key is not pickled: its workers are forked from the harness")

    def __copy__(self) -> RunSecurity:
        return self

    def __deepcopy__(self, memo: dict[int, object]) -> RunSecurity:
        return self


class RunScheduler(Scheduler):
    def start_http_server(self, *args: Any, **kwargs: Any) -> None:
        super().start_http_server(*args, **kwargs)
        self.http_server.stop()  # no HTTP endpoint (module doc)


class RunWorker(Worker):
    def start_http_server(self, *args: Any, **kwargs: Any) -> None:
        super().start_http_server(*args, **kwargs)
        self.http_server.stop()  # no HTTP endpoint (module doc)


@contextmanager
def local_cluster(
    n: int, make_certificates: Callable[[], RunCertificates]
) -> Iterator[tuple[SpecCluster, RunSecurity]]:
    """The run's cluster of ``n`` forked single-threaded workers, and its security; the
    certificates are made once this process is closed to the user's other processes."""
    with nondumpable(), dask.config.set(CONFIG):
        sec = RunSecurity(make_certificates())
        common = dict(
            host="127.0.0.1", protocol="tls://", security=sec, dashboard=False, dashboard_address="127.0.0.1:0"
        )
        worker = {
            "cls": Nanny,
            "options": dict(common, nthreads=1, worker_class=RunWorker, silence_logs=40, memory_limit=1 / n),
        }  # a share of the memory, as LocalCluster
        cluster = SpecCluster(
            scheduler={"cls": RunScheduler, "options": dict(common, port=0)},
            workers={i: worker for i in range(n)},
            worker=worker,
            security=sec,
            silence_logs=40,
        )
        try:
            yield cluster, sec
        finally:
            cluster.close()
