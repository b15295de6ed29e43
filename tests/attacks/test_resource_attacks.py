"""Resource accounting against honest and hostile decoders: memory judged from the
kernel's OOM events (never from page cache reaching the limit), the output limit enforced
while the decoder writes, trees of any depth counted and removed, no inotify instances taken
from the host's user, ``memory_kind = "rss"`` sampling the decoder's tree (not the launcher), a
reused case folder emptied without following a link a decoder put in it.
"""

from __future__ import annotations

import contextlib
import os
import resource
import shutil
import sys
import textwrap
import threading
import time
from pathlib import Path

import fbaconf
from fbaconf import safefs
from fbaconf.conformance.suite import load_suites
from fbaconf.harness import adapters
from fbaconf.harness.results import Outcome
from fbaconf.harness.runner import run_cases
from fbaconf.isolation import cgroups, endings, sandbox
from fbaconf.isolation.report import report
from fbaconf.isolation.sandbox import Limits

from lib.manifests import decoder
from lib.sandbox import needs_memory_cgroup, needs_sandbox

ROOT = Path(fbaconf.__file__).resolve().parents[1]
VALID = "simple-l1-core/dct-q4"


def run_one(tmp_path: Path, m: Path):
    suite, cid = VALID.split("/")
    (s,) = load_suites(names=[suite])
    (r,) = run_cases(
        adapters.resolve(m),
        [c for c in s.cases if c.id == cid],
        claim="simple@1",
        out_dir=tmp_path / "run",
        jobs=1,
        progress=False,
    )
    return r


def test_an_honest_decoder_with_400_mb_of_scratch_files_passes(tmp_path):
    """Before: page cache reaching the 256 MB cgroup limit counted as OOM (memory.failcnt), so
    this decoder (38 MB resident, exit 0) read "Crash: exceeded 256 MB"."""
    needs_sandbox()
    needs_memory_cgroup()
    body = """
        chunk = bytes(range(256)) * 4096  # 1 MB
        for k in range(4):  # 4 x 100 MB written, read back and removed: 400 MB through the page cache
            p = os.path.join(os.environ["TMPDIR"], "scratch%d" % k)
            with open(p, "wb") as f:
                for _ in range(100):
                    f.write(chunk)
            with open(p, "rb") as f:
                while f.read(1 << 20):
                    pass
            os.unlink(p)
        honest()
        """
    lim = "timeout_s = 60\nmemory_mb = 256\noutput_mb = 256\n"
    r = run_one(tmp_path, decoder(tmp_path, "scratch", body, limits=lim))
    assert r.outcome == Outcome.PASS, r.message


def test_a_disk_flood_is_stopped_at_the_output_limit_while_it_writes(tmp_path):
    """1.2 GB in files each under the per-file limit: before, all of it landed on disk and the
    total was checked after the run; now the decoder is killed once the folder passes 256 MB."""
    work = tmp_path / "case"
    flood = work / "in" / "flood.py"  # in the case folder: what a sandboxed decoder sees
    flood.parent.mkdir(parents=True)
    flood.write_text(
        textwrap.dedent("""\
        import os
        chunk = b"\\1" * (1 << 20)
        for k in range(12):  # 12 x 100 MB
            with open("flood%d" % k, "wb") as f:
                for _ in range(100):
                    f.write(chunk)
        print("wrote it all")
        """)
    )
    lim = Limits(timeout_s=60, memory_mb=512, output_mb=256)
    res = sandbox.run([os.path.realpath(sys.executable), str(flood)], work, lim)
    ending = endings.classify(res, lim)
    assert ending.kind == "output-limit", ending.message
    assert "wrote it all" not in res.stdout_tail
    assert 256 << 20 < res.output_bytes < 400 << 20, res.output_bytes  # stopped at the limit (+ one interval)


def test_a_6000_level_tree_with_338_mb_below_a_3000_level_chain_is_counted_and_removed(tmp_path):
    """Before: one descriptor per level — a tree deeper than the descriptor limit (50,000 levels
    against 20,000) stayed in the run folder, and 338 MB below a chain longer than PATH_MAX were
    neither counted nor removed. Here the harness's descriptor limit is lowered to 1,024 so 6,000
    levels are as deep (and 3,000 levels of "d/" are 6,000 bytes, over PATH_MAX's 4,096)."""
    body = """
        fd = os.open(".", os.O_RDONLY)
        for i in range(6000):
            os.mkdir("d", dir_fd=fd)
            nfd = os.open("d", os.O_RDONLY, dir_fd=fd)
            os.close(fd)
            fd = nfd
            if i == 3000:
                for k in range(2):  # 2 x 169 MB (sparse: each under the per-file limit)
                    f = os.open("hidden%d" % k, os.O_WRONLY | os.O_CREAT, 0o644, dir_fd=fd)
                    os.ftruncate(f, 169 << 20)
                    os.close(f)
        honest()
        """
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(1024, soft), hard))
    try:
        r = run_one(tmp_path, decoder(tmp_path, "deep", body, limits="timeout_s = 120\noutput_mb = 256\n"))
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))
    assert r.outcome != Outcome.PASS and "output limit" in r.message, r.message
    assert not (tmp_path / "run" / "work").exists()  # the whole run folder's work tree is gone


def test_a_decoder_takes_no_inotify_instance_from_the_hosts_user(tmp_path):
    """Before: a sandboxed decoder held all 128 of root's inotify instances on the host."""
    needs_sandbox()
    probe = tmp_path / "case" / "in" / "inotify.py"
    probe.parent.mkdir(parents=True)
    probe.write_text(
        textwrap.dedent("""\
        import ctypes, os
        libc = ctypes.CDLL(None, use_errno=True)
        got = [libc.inotify_init1(0) for _ in range(200)] + [libc.fanotify_init(0, 0)]
        print("instances", sum(1 for fd in got if fd >= 0), os.strerror(ctypes.get_errno()))
        """)
    )
    lim = Limits(timeout_s=20)
    res = sandbox.run([os.path.realpath(sys.executable), str(probe)], tmp_path / "case", lim)
    assert res.returncode == 0, res.stderr_tail
    assert res.stdout_tail.split()[:2] == ["instances", "0"], res.stdout_tail


def test_rss_is_sampled_over_the_decoders_tree_not_the_launcher(tmp_path, monkeypatch):
    """memory_kind = "rss" without cgroups (the sampled limit alone): a child of the decoder
    holding 300 MB resident passes a 150 MB limit — before, the launcher's resident set was
    sampled and the child ran free."""
    monkeypatch.setattr(cgroups, "_CG_BASES", [])  # no cgroup limit: the sampling alone
    hog = tmp_path / "case" / "in" / "hog.py"
    hog.parent.mkdir(parents=True)
    hog.write_text(
        textwrap.dedent("""\
        import subprocess, sys, time
        child = "x = bytearray(300 << 20)\\nfor i in range(0, len(x), 4096): x[i] = 1\\nimport time; time.sleep(10)"
        subprocess.run([sys.executable, "-c", child])
        print("the child ran free")
        """)
    )
    lim = Limits(timeout_s=30, memory_mb=150, memory_kind="rss")
    res = sandbox.run([os.path.realpath(sys.executable), str(hog)], tmp_path / "case", lim)
    ending = endings.classify(res, lim)
    assert ending.kind == "memory" and "resident-set" in ending.message, ending.message
    # the tree died while the child held its memory: the parent, which prints once the child
    # ends, never printed (a kill of the child alone, or none, would let it)
    assert "ran free" not in res.stdout_tail
    # the message names what was sampled (over 150 MB), not the launcher's own small peak
    assert res.rss_sampled_mb > 150 and f"sampled at {res.rss_sampled_mb:.0f} MB" in ending.message, ending.message


def test_isolation_report_names_what_is_missing(monkeypatch):
    rep = report()
    if sandbox.isolation() == "bwrap" and {"memory", "pids"} <= cgroups.controllers():
        assert rep.complete and rep.line().startswith("isolated")
    monkeypatch.setattr(cgroups, "_CG_BASES", [])
    monkeypatch.setattr(sandbox, "_ISOLATION", "none")
    rep = report()
    assert not rep.complete and rep.line().startswith("not isolated: ")
    assert [m.split(":")[0] for m in rep.missing] == [
        "bubblewrap (bwrap)",
        "writable cgroups with the memory controller",
        "writable cgroups with the pids controller",
    ]


PY_OOM = 'Traceback (most recent call last):\n  File "d.py", line 9, in <module>\n    b = bytearray(n)\nMemoryError\n'
CXX_OOM = "terminate called after throwing an instance of 'std::bad_alloc'\n  what():  std::bad_alloc\n"


def test_an_allocation_the_kernel_refuses_is_the_memory_limit_like_one_killed_at_it():
    """A decoder asking for gigabytes under a 256 MB limit is killed at the limit when the machine has
    the memory to hand out, and gets MemoryError / std::bad_alloc when it has not: the lab's free
    memory decides which, so both are the memory limit, not a crash of one and a blow-up of the other."""
    lim = Limits(memory_mb=256)
    for res in (
        sandbox.ProcResult(["python3", "d.py"], 1, stderr_tail=PY_OOM),
        sandbox.ProcResult(["./d"], None, signal="SIGABRT", stderr_tail=CXX_OOM),
    ):
        e = endings.classify(res, lim, name="d")
        assert e.kind == endings.EndingKind.MEMORY and "ran out of memory under the 256 MB limit" in e.message
    # a rejection that mentions memory in its own words is a rejection; another exception a crash
    said = sandbox.ProcResult(["./d"], 1, stderr_tail="cannot allocate memory for 10^9 frames: refused\n")
    assert endings.classify(said, lim).kind == endings.EndingKind.REJECT
    other = sandbox.ProcResult(["python3", "d.py"], 1, stderr_tail=PY_OOM.replace("MemoryError", "KeyError: 3"))
    assert endings.classify(other, lim).kind == endings.EndingKind.CRASH


CASE_TREE = {"in": None, "out": {"images": {}, "faces": {}}, "tmp": {}}


def test_a_case_folder_is_emptied_to_its_tree_whatever_was_left_in_it(tmp_path):
    """What a decoder leaves in a reused case folder goes (files, links, a deep tree, a file
    where a folder belongs); the input folder stays as it is; a link's target is never touched."""
    host = tmp_path / "host"
    host.mkdir()
    (host / "precious").write_text("x")
    case = tmp_path / "case"
    (case / "in").mkdir(parents=True)
    (case / "in" / "input.fba").write_bytes(b"input")
    (case / "out" / "images").mkdir(parents=True)
    (case / "out" / "images" / "0001.png").write_bytes(b"png")
    (case / "out" / "faps.fap").write_text("faps")
    (case / "out" / "faces").symlink_to(host)  # a link where a kept folder belongs
    (case / "tmp").write_text("a file where a folder belongs")
    deep = case / "junk"
    for _ in range(200):
        deep = deep / "d"
    deep.mkdir(parents=True)
    (case / "link-to-host").symlink_to(host)
    safefs.empty_tree(case, CASE_TREE)
    assert sorted(p.name for p in case.iterdir()) == ["in", "out", "tmp"]
    assert (case / "in" / "input.fba").read_bytes() == b"input"
    assert sorted(p.name for p in (case / "out").iterdir()) == ["faces", "images"]
    for d in (case / "out" / "images", case / "out" / "faces", case / "tmp"):
        assert d.is_dir() and not d.is_symlink() and not any(d.iterdir())
    assert (host / "precious").read_text() == "x"
    shutil.rmtree(case / "out")
    (case / "out").symlink_to(host)  # a link where a kept folder with kept folders of its own belongs
    safefs.empty_tree(case, CASE_TREE)
    assert not (case / "out").is_symlink() and sorted(p.name for p in (case / "out").iterdir()) == ["faces", "images"]
    assert sorted(p.name for p in host.iterdir()) == ["precious"]


def test_a_folder_swapped_for_a_link_while_the_case_folder_is_emptied_is_not_followed(tmp_path):
    """A pipelined worker empties a case folder while its decoder runs the next input, with write
    access to it: a decoder that keeps swapping ``out`` for a link to a host folder must not get the
    harness to empty that folder (a check of a path then a use of it did, within milliseconds)."""
    host = tmp_path / "host"
    (host / "images").mkdir(parents=True)
    (host / "images" / "precious").write_text("x")
    case = tmp_path / "case"
    (case / "in").mkdir(parents=True)
    (case / "out" / "images").mkdir(parents=True)
    stop = threading.Event()

    def swapper() -> None:
        i = 0
        while not stop.is_set():
            i += 1
            with contextlib.suppress(OSError):
                os.rename(case / "out", tmp_path / f"aside{i}")
            try:
                os.symlink(host, tmp_path / "link")
                os.rename(tmp_path / "link", case / "out")
            except OSError:
                with contextlib.suppress(OSError):
                    os.unlink(tmp_path / "link")
            time.sleep(0.0003)

    t = threading.Thread(target=swapper)
    t.start()
    sweeps, t0 = 0, time.monotonic()
    try:
        while time.monotonic() - t0 < 0.5 and (host / "images" / "precious").exists():
            with contextlib.suppress(OSError):  # a folder that keeps changing may be given up on
                safefs.empty_tree(case, CASE_TREE)
            sweeps += 1
    finally:
        stop.set()
        t.join()
    assert sweeps > 100
    assert (host / "images" / "precious").read_text() == "x"
    safefs.empty_tree(case, CASE_TREE)
    assert not (case / "out").is_symlink() and sorted(p.name for p in (case / "out").iterdir()) == ["faces", "images"]
