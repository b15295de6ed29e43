"""Cases as tasks on a Dask cluster: ``--cluster local[:N]`` or ``--cluster tls://HOST:PORT``.

The embedded thread pool (``-j N``) stays the default; a cluster is for campaigns that
outgrow one machine. ``local[:N]`` starts a cluster of N single-threaded worker processes on
this machine, forked from this one (default: the CPU count; :mod:`.local`);
``tls://HOST:PORT`` (``tcp://`` is read as the same, always over TLS) connects to a running
Dask scheduler whose workers have fbaconf installed and see the same paths (a shared
filesystem: suites, goldens, the decoder and the run folder).

Each case is one task (``run_case`` in a worker); results stream back to this process,
which writes them to the same resumable ``results.jsonl`` as the pool does. A worker lost
mid-run loses nothing: Dask reruns the tasks it held on another worker. Why Dask: it is the
well-kept Python engine for exactly this (task futures, ``as_completed``, lost-worker
recovery, a local cluster and a remote scheduler behind one API), so fbaconf writes none of it.

Security. Anyone who can talk to a Dask scheduler or worker can run code on the
workers, so every cluster is mutual TLS (``distributed.security.Security``): each end proves
itself with a certificate signed by the cluster's own authority.

* ``local``: the cluster authenticates the run, not a user (:mod:`.local`): the
  authority and one certificate are made for the run (:func:`.tls.make_certificates`)
  and the certificate's key lives only in the memory of this process and of the workers it
  forks, all non-dumpable while the cluster lives — no file, argument or environment variable
  holds it. Everything listens on 127.0.0.1 over TLS and nothing speaks HTTP (no dashboard).
  No other process — another user's, or the same user's not started by this run — can join or
  submit.
* ``tls://HOST:PORT``: the lab's certificates are required — ``FBACONF_CLUSTER_CA``,
  ``FBACONF_CLUSTER_CERT`` and ``FBACONF_CLUSTER_KEY`` (PEM files: the lab's authority, and a
  client certificate and key it signed), else Dask's own configuration
  (``distributed.comm.tls.ca-file``, ``distributed.comm.tls.client.cert`` and ``.key``, e.g.
  ``DASK_DISTRIBUTED__COMM__TLS__CA_FILE``); without them the connection is refused before it
  is made. The lab starts its scheduler and workers with the same authority
  (``dask scheduler --tls-ca-file ca.pem --tls-cert node.pem --tls-key node-key.pem``, the
  same for ``dask worker``): docs/fuzzing.md, "Who may talk to the cluster".

Task keys are random (a stranger cannot pre-submit a result under a key fbaconf will ask for).
A task returns its result as JSON text (plain data: dicts, lists, strings, numbers), which
this process parses and validates (:func:`from_data`, :func:`plain`) before it builds a result
from it; the client accepts task results serialized as msgpack only, never pickled. (Dask's own protocol may still carry
pickled control messages between the cluster's authenticated members: the defence against a
stranger is that no stranger is a member.)
"""

from __future__ import annotations

import json
import os
import re
import secrets
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fbaconf.errors import FbaconfInputError

from ..results import CaseResult

if TYPE_CHECKING:
    from distributed import Client
    from distributed.security import Security

    from fbaconf.conformance.suite import Case

    from ..runner import RunContext
from .tls import make_certificates

MAX_DEPTH = 32
MAX_ITEMS = 1 << 20
MAX_TEXT = 16 << 20
RESULT_DESERIALIZERS = ("msgpack",)  # task results: never a pickle


class ClusterError(FbaconfInputError):
    rule = "cluster"


def parse(spec: str) -> tuple[str, str | int]:
    """``local`` / ``local:N`` -> ("local", N); ``tls://host:port`` or ``tcp://host:port`` ->
    ("tls", "tls://host:port")."""
    m = re.fullmatch(r"local(?::(\d+))?", spec or "")
    if m:
        n = int(m.group(1)) if m.group(1) else (os.cpu_count() or 1)
        if not 1 <= n <= 1024:
            raise ClusterError(f"--cluster {spec}: the worker count must be 1..1024")
        return "local", n
    m = re.fullmatch(r"(?:tcp|tls)://([\w.\-\[\]:]+:\d+)", spec or "")
    if m:
        return "tls", f"tls://{m.group(1)}"
    raise ClusterError(f"--cluster {spec!r}: give local, local:N or tls://HOST:PORT")


# ------------------------------------------------------------------ certificates


def lab_security() -> Security:
    """The lab's certificates for a remote scheduler (module doc), or ClusterError."""
    from distributed.security import Security  # noqa: PLC0415 (the cluster extra)

    env = {k: os.environ.get(f"FBACONF_CLUSTER_{k.upper()}") or "" for k in ("ca", "cert", "key")}
    if all(env.values()):
        for k, v in env.items():
            if not Path(v).is_file():
                raise ClusterError(f"FBACONF_CLUSTER_{k.upper()}={v}: no such file")
        return Security(
            tls_ca_file=env["ca"], tls_client_cert=env["cert"], tls_client_key=env["key"], require_encryption=True
        )
    sec = Security(require_encryption=True)  # dask's configuration (distributed.comm.tls.*)
    if getattr(sec, "tls_ca_file", None) and getattr(sec, "tls_client_cert", None):  # set from its config
        return sec
    raise ClusterError(
        "a remote Dask scheduler is reached only over TLS with the lab's certificates: set "
        "FBACONF_CLUSTER_CA, FBACONF_CLUSTER_CERT and FBACONF_CLUSTER_KEY (PEM files: the lab's "
        "certificate authority, a client certificate it signed and its key), or dask's "
        'distributed.comm.tls configuration (docs/fuzzing.md, "Who may talk to the cluster")'
    )


# ------------------------------------------------------------------ clients


@contextmanager
def client(spec: str) -> Iterator[Client]:
    """A connected ``distributed.Client`` for ``spec`` (closed, and a local cluster shut down,
    after)."""
    kind, arg = parse(spec)
    try:
        from distributed import Client  # noqa: PLC0415 (Dask: optional (the cluster extra))
    except ImportError:
        raise ClusterError("--cluster needs Dask: pip install 'dask[distributed]'") from None
    if kind == "local":
        if not hasattr(os, "memfd_create"):
            raise ClusterError(
                "--cluster local needs Linux: the run's key is kept in memory (memfd, prctl); "
                "use --cluster tls://HOST:PORT or -j N"
            )
        from .local import local_cluster  # noqa: PLC0415 (Dask: optional, the cluster extra)

        with local_cluster(int(arg), make_certificates) as (cluster, run_sec):
            c = Client(cluster, security=run_sec, deserializers=RESULT_DESERIALIZERS)
            try:
                yield c
            finally:
                c.close()
    else:
        sec = lab_security()
        try:
            c = Client(str(arg), timeout=30, security=sec, deserializers=RESULT_DESERIALIZERS)
        except (OSError, TimeoutError) as e:
            raise ClusterError(f"cannot reach the Dask scheduler at {arg} over TLS: {e}") from None
        try:
            yield c
        finally:
            c.close()


def task_key(kind: str) -> str:
    """A task key no one can guess ahead (a stranger cannot pre-submit a result under it)."""
    return f"fbaconf-{kind}-{secrets.token_hex(16)}"


# ------------------------------------------------------------------ results as data


def plain(obj: object, what: str = "result", *, _depth: int = 0, _count: list[int] | None = None) -> Any:
    """``obj`` if it is plain data — dicts with string keys, lists (tuples read as lists),
    strings, bytes, whole and real numbers, booleans, None — within bounds of depth, size and
    text; ClusterError otherwise. What a worker sends back is checked with it before use."""
    count = _count if _count is not None else [0]
    count[0] += 1
    if _depth > MAX_DEPTH or count[0] > MAX_ITEMS:
        raise ClusterError(f"a {what} from the cluster is nested or sized past the bounds")
    if obj is None or isinstance(obj, (bool, int, float)):
        return obj
    if isinstance(obj, (str, bytes)):
        if len(obj) > MAX_TEXT:
            raise ClusterError(f"a {what} from the cluster holds a text of {len(obj)} bytes")
        return obj
    if isinstance(obj, (list, tuple)):
        return [plain(x, what, _depth=_depth + 1, _count=count) for x in obj]
    if isinstance(obj, dict):
        if not all(isinstance(k, str) for k in obj):
            raise ClusterError(f"a {what} from the cluster has a key that is not a string")
        return {k: plain(v, what, _depth=_depth + 1, _count=count) for k, v in obj.items()}
    raise ClusterError(f"a {what} from the cluster is not plain data ({type(obj).__name__})")


def as_data(obj: object) -> str:
    """What a task sends back: JSON text (plain data by construction, msgpack-serialized)."""
    return json.dumps(obj)


def from_data(text: object, what: str) -> dict[str, Any]:
    """A task's JSON text, parsed and checked (:func:`plain`) — ClusterError for anything else."""
    if not isinstance(text, str) or len(text) > MAX_TEXT:
        raise ClusterError(f"a {what} from the cluster is not the JSON text a task sends")
    try:
        got = json.loads(text)
    except (ValueError, RecursionError):
        raise ClusterError(f"a {what} from the cluster is not JSON") from None
    got = plain(got, what)
    if not isinstance(got, dict):
        raise ClusterError(f"a {what} from the cluster is not a table")
    return got


def _case_task(run_case: Callable[[RunContext, Case], CaseResult], ctx: RunContext, case: Case) -> str:
    """In a worker: one case, its result as plain data (an exception as such, never raised:
    an exception object would travel pickled)."""
    try:
        return as_data({"result": run_case(ctx, case).to_json()})
    except Exception as e:  # noqa: BLE001 - reported as data, judged by the coordinator
        return as_data({"error": f"{type(e).__name__}: {str(e)[:2000]}", "case": getattr(case, "full_id", "?")})


def run_on_cluster(
    c: Client,
    run_case: Callable[[RunContext, Case], CaseResult],
    ctx: RunContext,
    cases: list[Case],
    on_result: Callable[[CaseResult], None],
    stopping: Callable[[], bool],
) -> None:
    """Submit ``run_case(ctx, case)`` for every case as a task and hand each result to
    ``on_result`` as it arrives. Tasks of a lost worker are rerun by Dask; a task that raises
    is retried twice."""
    from distributed import as_completed  # noqa: PLC0415 (Dask: optional (the cluster extra))

    futures = [c.submit(_case_task, run_case, ctx, case, key=task_key("case"), pure=False, retries=2) for case in cases]
    ac = as_completed(futures, with_results=True)
    for _fut, got in ac:
        if stopping():
            c.cancel(futures)
            return
        got = from_data(got, "case result")
        if "error" in got:
            raise ClusterError(f"case {got.get('case')} failed in a worker: {got['error']}")
        try:
            on_result(CaseResult.from_json(got["result"]))
        except (KeyError, TypeError, ValueError) as e:
            raise ClusterError(f"a case result from the cluster does not read as one: {e}") from None
