"""Namespaces are refused inside the sandbox (item 6): a decoder that nests user and
mount namespaces takes the host user's per-user count — under a lowered limit it took them
all, a root process outside could not ``unshare -U`` and a concurrent case's sandbox could not
start. The seccomp filter (isolation/seccomp.py) refuses ``unshare``/``clone`` with a namespace
flag and ``setns`` (EPERM) and ``clone3`` (ENOSYS, so the C library falls back to ``clone``);
threads and ``fork`` still work. The hostile decoders are written here."""

from __future__ import annotations

import os
import sys
import textwrap
import threading
import time
from pathlib import Path

from fbaconf.conformance.suite import load_suites
from fbaconf.harness import adapters
from fbaconf.harness.results import Outcome
from fbaconf.harness.runner import run_cases
from fbaconf.isolation import sandbox, seccomp
from fbaconf.isolation.sandbox import Limits

from lib.sandbox import needs_seccomp_sandbox

PROBE = """
import ctypes, errno, os, subprocess, threading
libc = ctypes.CDLL(None, use_errno=True)
def call(f, *a):
    r = f(*a)
    return "ok" if r >= 0 else errno.errorcode[ctypes.get_errno()]
FLAGS = {"user": 0x10000000, "mount": 0x20000, "net": 0x40000000, "pid": 0x20000000, "ipc": 0x08000000,
         "uts": 0x04000000, "cgroup": 0x02000000, "time": 0x80}
for name, flag in FLAGS.items():
    print("unshare", name, call(libc.unshare, flag))
    # clone(2) itself with the flag (x86-64 and AArch64 number it 56 and 220; SIGCHLD = 17)
    nr = {"x86_64": 56, "aarch64": 220}[os.uname().machine]
    pid = libc.syscall(nr, flag | 17, 0, 0, 0, 0)
    if pid == 0:
        os._exit(0)
    print("clone", name, "ok" if pid > 0 else errno.errorcode[ctypes.get_errno()])
    if pid > 0:
        os.waitpid(pid, 0)
fd = os.open("/proc/self/ns/net", os.O_RDONLY)
print("setns net", call(libc.setns, fd, 0))
print("clone3", call(libc.syscall, 435, 0, 0))
print("unshare files", call(libc.unshare, 0x400))  # no namespace: allowed
t = threading.Thread(target=lambda: print("thread ok"))
t.start(); t.join()
print("child", subprocess.run(["/bin/echo", "ok"], capture_output=True, text=True).stdout.strip())
r = subprocess.run(["unshare", "-U", "-m", "true"], capture_output=True, text=True)
print("unshare-command", r.returncode)
"""


def _run_script(tmp_path: Path, name: str, body: str, limits=None):
    case = tmp_path / name
    (case / "in").mkdir(parents=True)
    script = case / "in" / f"{name}.py"
    script.write_text(textwrap.dedent(body))
    return sandbox.run([os.path.realpath(sys.executable), str(script)], case, limits or Limits(timeout_s=30))


def test_every_way_to_a_new_namespace_is_refused_and_threads_and_children_still_work(tmp_path):
    needs_seccomp_sandbox()
    res = _run_script(tmp_path, "probe", PROBE)
    assert res.returncode == 0, res.stderr_tail
    got = dict(line.rsplit(" ", 1) for line in res.stdout_tail.strip().splitlines())
    for name in ("user", "mount", "net", "pid", "ipc", "uts", "cgroup", "time"):
        assert got[f"unshare {name}"] == "EPERM" and got[f"clone {name}"] == "EPERM", (name, got)
    assert got["setns net"] == "EPERM" and got["clone3"] == "ENOSYS"
    assert got["unshare files"] == "ok" and got["thread"] == "ok" and got["child"] == "ok"
    assert got["unshare-command"] != "0"


FLOOD = """
import ctypes, os, sys, time
libc = ctypes.CDLL(None, use_errno=True)
N = int(sys.argv[1]) if len(sys.argv) > 1 else 200
made, kids = 0, []
for i in range(N):  # each child nests a user and a mount namespace and holds them
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        ok = libc.unshare(0x10000000 | 0x20000) == 0
        os.write(w, b"1" if ok else b"0")
        time.sleep(4 if ok else 0)
        os._exit(0)
    made += os.read(r, 1) == b"1"
    os.close(r); os.close(w)
    kids.append(pid)
open("holding", "w").write(str(made))
time.sleep(3)
print("namespaces", made)
for k in kids:
    os.waitpid(k, 0)
"""


def _flood(tmp_path: Path, name: str, n: int, out: dict) -> None:
    out["res"] = _run_script(
        tmp_path,
        name,
        FLOOD.replace("int(sys.argv[1]) if len(sys.argv) > 1 else 200", str(n)),
        Limits(timeout_s=60, processes=256),
    )


def test_a_namespace_flood_takes_nothing_and_a_concurrent_case_runs(tmp_path):
    """The flooder forks 200 children, each nesting a user and a mount namespace and holding it;
    while it holds, a case of the reference decoder runs in its own sandbox and passes."""
    needs_seccomp_sandbox()
    got: dict = {}
    t = threading.Thread(target=_flood, args=(tmp_path, "flood", 200, got))
    t.start()
    holding = tmp_path / "flood" / "holding"
    for _ in range(600):
        if holding.exists() or not t.is_alive():
            break
        time.sleep(0.05)
    (s,) = load_suites(names=["simple-l1-core"])
    (r,) = run_cases(
        adapters.resolve("reference"),
        [c for c in s.cases if c.id == "dct-q4"],
        claim="simple@1",
        out_dir=tmp_path / "run",
        jobs=1,
        progress=False,
    )
    assert holding.exists(), "the flooder never got to hold"  # the case ran during the hold
    t.join()
    assert r.outcome == Outcome.PASS, r.message
    res = got["res"]
    assert res.returncode == 0, res.stderr_tail
    assert res.stdout_tail.split() == ["namespaces", "0"]


def test_without_the_filter_the_same_flood_would_take_namespaces(tmp_path, monkeypatch):
    """The control: the flood above is real — without the seccomp filter the same decoder (20
    children here) holds a namespace per child — so the filter is what stops it."""
    needs_seccomp_sandbox()
    monkeypatch.setattr(seccomp, "supported", lambda: False)
    got: dict = {}
    _flood(tmp_path, "flood", 20, got)
    res = got["res"]
    assert res.returncode == 0, res.stderr_tail
    assert res.stdout_tail.split() == ["namespaces", "20"]
