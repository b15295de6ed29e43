"""A stranger on the Dask port: every cluster fbaconf starts or joins is mutual TLS,
listens on loopback only, uses task keys no one can guess, and reads what workers send back as
plain data. Before: any client of the tcp:// scheduler ran code on the workers, could patch
run_case so a decoder exiting 3 everywhere reported PASS, or pre-submit fbaconf's predictable
keys; a local process joined --cluster local:1 mid-run."""

from __future__ import annotations

import ipaddress
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from fbaconf.fuzz.campaign import minimise_report, shard_report
from fbaconf.harness import cluster
from fbaconf.harness.cluster import ClusterError
from fbaconf.harness.cluster.tls import make_certificates

distributed = pytest.importorskip("distributed")
from distributed import Client, Worker  # noqa: E402
from distributed.security import Security  # noqa: E402


def _address(entry: str) -> tuple[str, int]:
    """``host:port`` of /proc/net/tcp{,6} (the host in 32-bit words, each little-endian)."""
    host, port = entry.split(":")
    raw = bytes.fromhex(host)
    return str(ipaddress.ip_address(b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4)))), int(port, 16)


def own_listening() -> list[tuple[str, int]]:
    """The addresses this process listens on (TCP), read from its own descriptors — a
    non-dumpable process may read its own ``/proc``, no other process of its user may: run
    here and, by ``client.run``, in each worker."""
    inodes = set()
    for fd in os.listdir("/proc/self/fd"):
        try:
            link = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if link.startswith("socket:["):
            inodes.add(link[8:-1])
    out = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            f = line.split()
            if f[3] == "0A" and f[9] in inodes:  # LISTEN
                out.append(_address(f[1]))
    return out


def cluster_ports(c) -> dict[str, list[tuple[str, int]]]:
    """What the cluster's processes listen on: this one (the scheduler and the nannies) and
    each worker."""
    return {"harness": own_listening(), **c.run(own_listening)}


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
        # every socket the cluster's processes listen on is on loopback
        ports = cluster_ports(c)
        assert len(ports) == 2 and all(ports.values()), ports
        assert {h for v in ports.values() for h, _p in v} <= {"127.0.0.1", "::1"}, ports
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


def _lab_files(folder: Path) -> dict[str, Path]:
    """A lab's authority and certificate, as the files a lab keeps (made here with fbaconf's
    maker; a lab uses openssl, docs/fuzzing.md)."""
    certs = make_certificates()
    folder.mkdir(mode=0o700)
    paths = {k: folder / f"{k}.pem" for k in ("ca", "cert", "key")}
    for k, p in paths.items():
        p.write_bytes(getattr(certs, k))
        p.chmod(0o600)
    return paths


def test_a_lab_scheduler_with_the_labs_certificates_is_reached_and_no_one_else(tmp_path, monkeypatch):
    """The documented lab set-up: the lab's authority signs its nodes' and its clients'
    certificates; fbaconf is given them by FBACONF_CLUSTER_*."""
    paths = _lab_files(tmp_path / "lab")
    ca, cert, key = (str(paths[k]) for k in ("ca", "cert", "key"))
    sec = Security(
        tls_ca_file=ca,
        tls_client_cert=cert,
        tls_client_key=key,
        tls_scheduler_cert=cert,
        tls_scheduler_key=key,
        tls_worker_cert=cert,
        tls_worker_key=key,
        require_encryption=True,
    )
    with distributed.LocalCluster(
        n_workers=1,
        threads_per_worker=1,
        processes=False,
        protocol="tls://",
        host="127.0.0.1",
        security=sec,
        dashboard_address=None,
    ) as lab:
        for k in ("ca", "cert", "key"):
            monkeypatch.setenv(f"FBACONF_CLUSTER_{k.upper()}", str(paths[k]))
        with cluster.client(lab.scheduler_address.replace("tls://", "tcp://")) as c:
            assert c.submit(lambda: "ran", key=cluster.task_key("probe")).result() == "ran"
        other = _lab_files(tmp_path / "other")
        for k in ("ca", "cert", "key"):
            monkeypatch.setenv(f"FBACONF_CLUSTER_{k.upper()}", str(other[k]))
        with pytest.raises((ClusterError, OSError, TimeoutError)):
            with cluster.client(lab.scheduler_address):
                pass


@pytest.mark.parametrize(
    "bad",
    [
        b"\x80\x04pickle".decode("latin-1"),  # not JSON
        "[" * 100_000 + "]" * 100_000,  # nested past any bound
        json.dumps([1, 2, 3]),  # not a table
        '{"result": ' + "[" * 40 + "]" * 40 + "}",  # deeper than MAX_DEPTH
    ],
)
def test_what_a_worker_sends_back_is_plain_data_or_refused(bad):
    with pytest.raises(ClusterError):
        cluster.from_data(bad, "case result")
    with pytest.raises(ClusterError):
        cluster.from_data(object(), "case result")  # anything but the JSON text a task sends


def test_shard_and_minimisation_reports_are_checked_field_by_field():
    good = {
        "seed": 1,
        "execs": 3,
        "fuzz_seconds": 1.5,
        "features": ["a"],
        "universe": ["a", "b"],
        "corpus": ["AAE="],
        "findings": [
            {
                "key": "crash:x",
                "cls": "crash",
                "signature": "x",
                "message": "m",
                "detail": {},
                "data": "AAE=",
                "kind": "stream",
                "origin": "o",
                "index": 2,
                "corpus_size": 4,
                "hits": 1,
                "seed": 1,
                "found_at_s": 0.5,
            }
        ],
    }
    r = shard_report(json.dumps(good))
    assert r["corpus"] == [b"\x00\x01"] and r["findings"][0]["data"] == b"\x00\x01"
    for change in ({"execs": "3"}, {"corpus": ["not base64!"]}, {"features": [1]}, {"findings": [{"key": 1}]}):
        with pytest.raises(ClusterError):
            shard_report(json.dumps({**good, **change}))
    m = {
        "minimal": "AA==",
        "tests": 1,
        "seconds": 0.1,
        "reproduced": True,
        "flaky": False,
        "message": None,
        "detail": None,
    }
    assert minimise_report(json.dumps(m))["minimal"] == b"\x00"
    for change in ({"minimal": 5}, {"flaky": 1}, {"tests": True}, {"reproduced": "yes"}):
        with pytest.raises(ClusterError):
            minimise_report(json.dumps({**m, **change}))


# ------------------------------------------------------------------ a process of the lab's user

ATTACKER = r'''
"""A process of the lab's user that the run did not start: it holds a copy of
everything the run wrote to disk and tries every way into the run's cluster — the files, /proc
of the harness and of the workers, the HTTP ports — and, with any key it finds, joins and
patches run_case in the workers so every case passes. Prints what it got, as JSON."""
import json, os, re, socket, ssl, sys

args = json.loads(sys.argv[1])
rep = {"keys": [], "canary": [], "files": 0, "proc": {}, "http": {}, "tls": {}, "joined": False, "patched": 0}
rep["cap_eff"] = open("/proc/self/status").read().split("CapEff:")[1].split()[0]
KEY = re.compile(rb"-----BEGIN [A-Z ]*PRIVATE KEY-----[A-Za-z0-9+/=\s]+-----END [A-Z ]*PRIVATE KEY-----")
CERT = re.compile(rb"-----BEGIN CERTIFICATE-----[A-Za-z0-9+/=\s]+-----END CERTIFICATE-----")
keys, certs = set(), set()

def scan(blob, where):
    for k in KEY.findall(blob):
        keys.add(k)
        (rep["canary"] if b"CANARYCANARY" in k else rep["keys"]).append(where)
    certs.update(CERT.findall(blob))

for top in args["dirs"]:
    for d, _dirs, files in os.walk(top):
        for f in files:
            try:
                with open(os.path.join(d, f), "rb") as fh:
                    scan(fh.read(), os.path.join(d, f))
                rep["files"] += 1
            except OSError:
                pass
for pid in args["pids"]:
    got = rep["proc"][str(pid)] = {}
    for what in ("environ", "maps"):
        try:
            with open(f"/proc/{pid}/{what}", "rb") as fh:
                scan(fh.read(), f"/proc/{pid}/{what}")
            got[what] = "read"
        except OSError as e:
            got[what] = type(e).__name__
    try:
        with open(f"/proc/{pid}/maps") as fh, open(f"/proc/{pid}/mem", "rb", 0) as mem:
            for line in fh:
                span, perms = line.split()[:2]
                lo, hi = (int(x, 16) for x in span.split("-"))
                if perms[0] != "r" or hi - lo > 1 << 30 or "[v" in line:
                    continue
                try:
                    mem.seek(lo)
                    scan(mem.read(hi - lo), f"/proc/{pid}/mem")
                except (OSError, OverflowError, ValueError):
                    pass
        got["mem"] = "read"
    except OSError as e:
        got["mem"] = type(e).__name__
    try:
        fds = os.listdir(f"/proc/{pid}/fd")  # as uid 0 the folder lists; its links are the point
        got["fd"] = 0
        for fd in fds:
            try:
                os.readlink(f"/proc/{pid}/fd/{fd}")
                h = os.open(f"/proc/{pid}/fd/{fd}", os.O_RDONLY | os.O_NONBLOCK)
            except OSError:
                continue
            got["fd"] += 1
            try:
                scan(os.read(h, 1 << 20), f"/proc/{pid}/fd/{fd}")
            except OSError:
                pass
            finally:
                os.close(h)
    except OSError as e:
        got["fd"] = type(e).__name__
for host, port in args["ports"]:  # the dashboard: Dask's /info pages (logs, call stacks, task keys)
    try:
        with socket.create_connection((host, port), timeout=3) as s:
            s.sendall(b"GET /info/main/workers.html HTTP/1.1\r\nHost: localhost\r\n\r\n")
            rep["http"][f"{host}:{port}"] = s.recv(200).decode("latin-1") or "closed"
    except OSError as e:
        rep["http"][f"{host}:{port}"] = type(e).__name__

from distributed import Client
from distributed.security import Security
own = Security.temporary()  # a certificate of its own authority
for host, port in args["ports"]:  # a TLS handshake with a certificate the run's authority did not sign
    ctx = own.get_connection_args("client")["ssl_context"]
    ctx.check_hostname, ctx.verify_mode = False, ssl.CERT_NONE
    try:
        with socket.create_connection((host, port), timeout=3) as raw, ctx.wrap_socket(raw) as s:
            s.sendall(b"\0" * 8)
            rep["tls"][f"{host}:{port}"] = "answered" if s.recv(1) else "closed"
    except (OSError, ssl.SSLError) as e:
        rep["tls"][f"{host}:{port}"] = type(e).__name__


def patch():
    import fbaconf.harness.runner as runner
    from fbaconf.harness.results import Outcome
    real = getattr(runner, "_real_run_case", runner.run_case)

    def run_case(ctx, case):
        r = real(ctx, case)
        r.outcome, r.message = Outcome.PASS, "patched by a process that joined the run's cluster"
        return r
    runner._real_run_case, runner.run_case = real, run_case
    return True


tried = [(c, k) for c in certs for k in keys if b"CANARYCANARY" not in k] or [None]
for pair in tried:
    if pair is None:
        sec = own
    else:
        folder = os.path.join(args["mine"], "stolen")
        os.makedirs(folder, exist_ok=True)
        for name, blob in (("ca", b"\n".join(certs)), ("cert", pair[0]), ("key", pair[1])):
            with open(os.path.join(folder, name + ".pem"), "wb") as fh:
                fh.write(blob + b"\n")
        p = {n: os.path.join(folder, n + ".pem") for n in ("ca", "cert", "key")}
        sec = Security(tls_ca_file=p["ca"], tls_client_cert=p["cert"], tls_client_key=p["key"],
                       require_encryption=True)
    try:
        c = Client(args["scheduler"], security=sec, timeout=4)
    except Exception as e:  # noqa: BLE001
        rep.setdefault("refused", []).append(f"{type(e).__name__}: {e}")
        continue
    rep["joined"] = True
    rep["patched"] = sum(c.run(patch).values())
    c.close()
print(json.dumps(rep))
'''

DECOY = """import time
key = '''-----BEGIN PRIVATE KEY-----
CANARYCANARYCANARYCANARYCANARYCANARY
-----END PRIVATE KEY-----'''
print('ready', flush=True)
time.sleep(300)
"""


SCENARIO = r'''
"""The run, with the attacker started once its cluster is up and before a case is sent: prints
what the attacker got, what it was told, and the run's outcomes."""
import json, os, subprocess, sys, tempfile
from contextlib import contextmanager
from pathlib import Path

from fbaconf.conformance.suite import load_suites
from fbaconf.harness import adapters, cluster
from fbaconf.harness.runner import run_cases
from test_cluster_attacks import DECOY, cluster_ports

tmp, hand_over = Path(sys.argv[1]), sys.argv[2] == "hand-over"
temp = tmp / "tmp"
decoy = subprocess.Popen([sys.executable, "-c", DECOY], stdout=subprocess.PIPE)  # dumpable: the attacker's control
assert decoy.stdout.readline() == b"ready\n"
got, real_client = [], cluster.client


@contextmanager
def attacked(spec):
    with real_client(spec) as c:
        ports = sorted({tuple(p) for v in cluster_ports(c).values() for p in v})
        args = {"dirs": [str(tmp / "run"), str(temp)], "scheduler": c.scheduler.address, "ports": ports,
                "pids": [os.getpid(), *c.run(os.getpid).values(), decoy.pid], "mine": str(tmp / "mine")}
        if hand_over:  # the control: the attacker given what the run keeps secret
            (temp / "handed.pem").write_bytes(c.security.tls_ca_file.encode() + c.security._chain)
        p = subprocess.run([sys.executable, str(tmp / "attacker.py"), json.dumps(args)], capture_output=True,
                           timeout=300)
        assert p.returncode == 0, p.stderr.decode()[-3000:]
        got.append((json.loads(p.stdout), args))
        yield c


cluster.client = attacked
(s,) = load_suites(names=["simple-l1-core"])
try:
    results = run_cases(adapters.resolve(tmp / "fail.toml"), s.cases[:6], claim="simple@1", out_dir=tmp / "run",
                        progress=False, cluster="local:2")
finally:
    decoy.kill()
((rep, args),) = got
print(json.dumps({"rep": rep, "args": args, "outcomes": [r.outcome.value for r in results]}))
'''

# Run as root, the harness and the attacker would hold root's capabilities, with which the kernel
# lets one read the other's /proc whatever its dumpable flag: both run without any capability
# (uid 0 kept), as two processes of one ordinary user would — what keeps the attacker out is
# then the harness's and the workers' being non-dumpable (bubblewrap still starts: it needs no
# capability, only user namespaces).
NO_CAPABILITIES = (
    "import ctypes, os, sys\n"
    "for cap in range(64):\n"
    "    ctypes.CDLL(None).prctl(24, cap, 0, 0, 0)  # PR_CAPBSET_DROP (root only)\n"
    "os.execv(sys.executable, [sys.executable] + sys.argv[1:])\n"
)


def _attacked_run(tmp_path: Path, *, hand_over_the_key: bool):
    """``run_cases`` of a decoder that exits 3 on every case, on ``--cluster local:2``, with the
    attacker run once the cluster is up (SCENARIO). Everything the run writes lands under
    ``tmp_path`` (its folder, and TMPDIR: Dask's scratch space)."""
    (tmp_path / "fail.py").write_text("import sys\nsys.exit(3)\n")
    (tmp_path / "fail.toml").write_text(
        'name = "exit-3"\nclaims = ["simple@1"]\ninputs = ["fba"]\noutputs = ["faps"]\nfaps_format = "npz"\n'
        f'[commands]\ndecode = ["{{python}}", "{tmp_path / "fail.py"}", "{{input}}", "{{faps_out}}"]\n'
    )
    (tmp_path / "attacker.py").write_text(ATTACKER)
    (tmp_path / "scenario.py").write_text(SCENARIO)
    for d in ("tmp", "mine"):
        (tmp_path / d).mkdir()
    env = {
        **os.environ,
        "TMPDIR": str(tmp_path / "tmp"),
        "PYTHONPATH": os.pathsep.join([str(Path(__file__).parent), os.environ.get("PYTHONPATH", "")]),
    }
    p = subprocess.run(
        [
            sys.executable,
            "-c",
            NO_CAPABILITIES,
            str(tmp_path / "scenario.py"),
            str(tmp_path),
            "hand-over" if hand_over_the_key else "attack",
        ],
        capture_output=True,
        env=env,
        timeout=600,
    )
    assert p.returncode == 0, p.stderr.decode()[-4000:]
    doc = json.loads(p.stdout.decode().strip().splitlines()[-1])
    return doc["rep"], doc["args"], doc["outcomes"]


def test_a_process_of_the_labs_user_cannot_join_the_run_or_change_a_verdict(tmp_path):
    """Before: the run's certificate and key were files of the lab's user (0600): a process of
    that user read them, joined --cluster local and patched run_case in the workers — 7 of 10
    cases passed for a decoder that exits 3 on every case; any local user read the dashboard.
    Now the key is in the memory of non-dumpable processes only and nothing speaks HTTP."""
    rep, args, outcomes = _attacked_run(tmp_path, hand_over_the_key=False)
    assert rep["cap_eff"] == "0000000000000000"  # no capability
    assert rep["files"] > 0  # it read what the run wrote (the run folder, Dask's scratch space)
    assert rep["keys"] == []  # no private key: not in a file, not in /proc
    # the control: a dumpable process of the same user is read through /proc, its key found
    decoy = rep["proc"][str(args["pids"][-1])]
    assert {k: v for k, v in decoy.items() if k != "fd"} == {"environ": "read", "maps": "read", "mem": "read"}
    assert decoy["fd"] >= 3, decoy  # its descriptors opened
    assert rep["canary"], "the attacker reads a dumpable process's memory"
    for pid in args["pids"][:-1]:  # the harness and the workers: closed
        got = rep["proc"][str(pid)]
        assert got["environ"] == got["maps"] == got["mem"] == "PermissionError", (pid, rep["proc"])
        assert got["fd"] in (0, "PermissionError"), (pid, rep["proc"])  # no descriptor opened
    assert len(args["ports"]) >= 5  # the scheduler, two nannies, two workers
    assert not any(v.startswith("HTTP/") for v in rep["http"].values()), rep["http"]  # no dashboard, no HTTP
    assert "answered" not in rep["tls"].values(), rep["tls"]  # another authority's certificate: refused
    assert rep["joined"] is False and rep["refused"], rep
    assert outcomes == ["Fail"] * 6, outcomes


def test_the_attacker_given_the_runs_key_joins_and_changes_verdicts(tmp_path):
    """The control of the test above: handed the run's key (what the harness keeps in memory),
    the same attacker joins and every case of the failing decoder passes — so the test above
    fails if the key can be had."""
    rep, _args, outcomes = _attacked_run(tmp_path, hand_over_the_key=True)
    assert rep["joined"] is True and rep["patched"] == 2, rep.get("refused")
    assert outcomes == ["Pass"] * 6, outcomes
