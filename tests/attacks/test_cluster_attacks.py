"""A stranger on the Dask port (issue 29): every cluster fbaconf starts or joins is mutual TLS,
listens on loopback only, uses task keys no one can guess, and reads what workers send back as
plain data. Before: any client of the tcp:// scheduler ran code on the workers, could patch
run_case so a decoder exiting 3 everywhere reported PASS, or pre-submit fbaconf's predictable
keys; a local process joined --cluster local:1 mid-run."""
from __future__ import annotations

import json
import os
import socket
from pathlib import Path

import pytest

from fbaconf.fuzz.campaign import minimise_report, shard_report
from fbaconf.harness import cluster
from fbaconf.harness.cluster import ClusterError

distributed = pytest.importorskip("distributed")
from distributed import Client, Worker  # noqa: E402
from distributed.security import Security  # noqa: E402


def _listening(pids: set[int]) -> set[str]:
    """The addresses the processes ``pids`` listen on (TCP, IPv4 and IPv6)."""
    inodes = set()
    for pid in pids:
        try:
            for fd in os.listdir(f"/proc/{pid}/fd"):
                link = os.readlink(f"/proc/{pid}/fd/{fd}")
                if link.startswith("socket:["):
                    inodes.add(link[8:-1])
        except OSError:
            continue
    out = set()
    for table, v6 in (("/proc/net/tcp", False), ("/proc/net/tcp6", True)):
        for line in Path(table).read_text().splitlines()[1:]:
            f = line.split()
            if f[3] == "0A" and f[9] in inodes:  # LISTEN
                host = f[1].split(":")[0]
                if v6:
                    out.add("::" if set(host) == {"0"} else "::1" if host.endswith("1") and set(host[:-1]) <= {"0"}
                            else host)
                else:
                    out.add(socket.inet_ntoa(bytes.fromhex(host)[::-1]))
    return out


def _refused(fn) -> bool:
    try:
        c = fn()
    except Exception:  # noqa: BLE001 - any failure to connect is the point
        return True
    c.close()
    return False


def test_a_stranger_can_neither_connect_nor_join_a_local_cluster(tmp_path):
    with cluster.client("local:1") as c:
        addr = c.scheduler.address
        assert addr.startswith("tls://127.0.0.1:"), addr
        workers = c.scheduler_info()["workers"]
        assert len(workers) == 1 and all(w.startswith("tls://127.0.0.1:") for w in workers)
        # every socket the cluster's processes listen on is on loopback (TLS: the HTTP servers too)
        pids = {os.getpid(), *c.run(os.getpid).values(), *c.run(os.getppid).values()}  # + the nannies
        assert _listening(pids) <= {"127.0.0.1", "::1"}, _listening(pids)
        plain = addr.replace("tls://", "tcp://")
        assert _refused(lambda: Client(plain, timeout=3))  # no TLS
        assert _refused(lambda: Client(addr, timeout=3, security=Security.temporary()))  # another authority
        # a worker joining mid-run, without the run's certificate: refused; the run keeps its one worker
        for sec in (None, Security.temporary()):
            w = Worker(plain if sec is None else addr, security=sec, nthreads=1, host="127.0.0.1", death_timeout=4)
            with pytest.raises(Exception):  # noqa: B017 - whatever the handshake raises
                c.sync(w.start)
            c.sync(w.close)
        assert len(c.scheduler_info()["workers"]) == 1
        assert c.submit(lambda x: x + 1, 41, key=cluster.task_key("probe")).result() == 42


def test_task_keys_are_unpredictable():
    keys = {cluster.task_key("case") for _ in range(1000)}
    assert len(keys) == 1000 and all(len(k) == len("fbaconf-case-") + 32 for k in keys)


def test_a_remote_scheduler_is_refused_without_the_labs_certificates(monkeypatch):
    for k in ("CA", "CERT", "KEY"):
        monkeypatch.delenv(f"FBACONF_CLUSTER_{k}", raising=False)
    with pytest.raises(ClusterError, match="FBACONF_CLUSTER_CA"):
        with cluster.client("tcp://127.0.0.1:9"):
            pass


def test_a_lab_scheduler_with_the_labs_certificates_is_reached_and_no_one_else(tmp_path, monkeypatch):
    """The documented lab set-up: the lab's authority signs its nodes' and its clients'
    certificates; fbaconf is given them by FBACONF_CLUSTER_*."""
    paths = cluster.make_certificates(tmp_path / "lab")
    assert oct((tmp_path / "lab").stat().st_mode & 0o777) == "0o700"
    assert oct(paths["key"].stat().st_mode & 0o777) == "0o600"
    sec = cluster.security_for(paths)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tls://",
                                  host="127.0.0.1", security=sec, dashboard_address=None) as lab:
        for k in ("ca", "cert", "key"):
            monkeypatch.setenv(f"FBACONF_CLUSTER_{k.upper()}", str(paths[k]))
        with cluster.client(lab.scheduler_address.replace("tls://", "tcp://")) as c:
            assert c.submit(lambda: "ran", key=cluster.task_key("probe")).result() == "ran"
        other = cluster.make_certificates(tmp_path / "other")
        for k in ("ca", "cert", "key"):
            monkeypatch.setenv(f"FBACONF_CLUSTER_{k.upper()}", str(other[k]))
        with pytest.raises((ClusterError, OSError, TimeoutError)):
            with cluster.client(lab.scheduler_address):
                pass


@pytest.mark.parametrize("bad", [
    b"\x80\x04pickle".decode("latin-1"),  # not JSON
    "[" * 100_000 + "]" * 100_000,  # nested past any bound
    json.dumps([1, 2, 3]),  # not a table
    '{"result": ' + "[" * 40 + "]" * 40 + "}",  # deeper than MAX_DEPTH
])
def test_what_a_worker_sends_back_is_plain_data_or_refused(bad):
    with pytest.raises(ClusterError):
        cluster.from_data(bad, "case result")
    with pytest.raises(ClusterError):
        cluster.from_data(object(), "case result")  # anything but the JSON text a task sends


def test_shard_and_minimisation_reports_are_checked_field_by_field():
    good = {"seed": 1, "execs": 3, "fuzz_seconds": 1.5, "features": ["a"], "universe": ["a", "b"],
            "corpus": ["AAE="], "findings": [{"key": "crash:x", "cls": "crash", "signature": "x", "message": "m",
                                              "detail": {}, "data": "AAE=", "kind": "stream", "origin": "o",
                                              "index": 2, "corpus_size": 4, "hits": 1, "seed": 1,
                                              "found_at_s": 0.5}]}
    r = shard_report(json.dumps(good))
    assert r["corpus"] == [b"\x00\x01"] and r["findings"][0]["data"] == b"\x00\x01"
    for change in ({"execs": "3"}, {"corpus": ["not base64!"]}, {"features": [1]}, {"findings": [{"key": 1}]}):
        with pytest.raises(ClusterError):
            shard_report(json.dumps({**good, **change}))
    assert minimise_report(json.dumps({"minimal": "AA==", "tests": 1, "seconds": 0.1, "message": None,
                                       "detail": None}))["minimal"] == b"\x00"
    with pytest.raises(ClusterError):
        minimise_report(json.dumps({"minimal": 5, "tests": 1, "seconds": 0.1, "message": None, "detail": None}))
