"""The launcher (isolation/sandbox.py): prlimit applies the limits; with cgroups, a shell holds a
case's launch until the harness has moved it into them, and a server's shell joins them itself."""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fbaconf.isolation import sandbox

needs_prlimit = pytest.mark.skipif(shutil.which("prlimit") is None, reason="util-linux prlimit not installed")


@needs_prlimit
def test_limits_reach_the_program():
    argv, held = sandbox.launch_argv(
        512 * 2**20, 3 * 2**20, 7, [], ["/bin/sh", "-c", "ulimit -v; ulimit -f; ulimit -t; ulimit -c"]
    )
    assert not held
    out = subprocess.run(argv, capture_output=True, text=True, check=True).stdout.split()
    # ulimit -v in KiB, -f in 512-byte blocks (dash), -t in seconds, -c core blocks
    assert out == [str(512 * 1024), str(3 * 2**20 // 512), "7", "0"], out


@needs_prlimit
def test_a_limit_of_zero_is_not_set():
    argv, _ = sandbox.launch_argv(0, 0, 0, [], ["/bin/true"])
    assert not any(a.startswith(("--as", "--fsize", "--cpu")) for a in argv)


@needs_prlimit
def test_held_launch_waits_for_the_cgroup_move(tmp_path: Path):
    """The program must not start before every cgroup has its pid: a fake cgroup folder
    records what the harness wrote, and the program writes a file only after the go."""
    cg = tmp_path / "cg"
    cg.mkdir()
    (cg / "cgroup.procs").write_text("")
    marker = tmp_path / "started"
    argv, held = sandbox.launch_argv(0, 0, 0, [cg], ["/bin/sh", "-c", f"echo $$ > {marker}"])
    assert held and argv[0] == "/bin/sh"
    proc = subprocess.Popen(argv, stdin=subprocess.PIPE, start_new_session=True)
    time.sleep(0.3)
    assert not marker.exists(), "the program ran before the harness let it go"
    assert sandbox.release(proc, [cg]) is None
    assert proc.wait(5) == 0
    assert (cg / "cgroup.procs").read_text() == str(proc.pid)
    assert marker.read_text().strip() == str(proc.pid)  # exec chain: the same process


@needs_prlimit
def test_a_cgroup_that_cannot_be_joined_stops_the_launch(tmp_path: Path):
    marker = tmp_path / "started"
    gone = tmp_path / "no-such-cgroup"
    argv, held = sandbox.launch_argv(0, 0, 0, [gone], ["/bin/sh", "-c", f"touch {marker}"])
    proc = subprocess.Popen(argv, stdin=subprocess.PIPE, start_new_session=True)
    why = sandbox.release(proc, [gone])
    assert why is not None and why.startswith("fbaconf-limit: cannot join cgroup") and str(gone) in why
    assert proc.poll() is not None and not marker.exists()


def test_without_prlimit_the_python_launcher_joins_and_limits(monkeypatch, tmp_path: Path):
    monkeypatch.setattr(sandbox.shutil, "which", lambda name: None)
    argv, held = sandbox.launch_argv(1 << 30, 0, 5, [tmp_path], ["/bin/true"])
    assert not held and argv[3] == str(sandbox.LIMIT_LAUNCHER)
    assert argv[4:10] == [str(1 << 30), "0", "5", "--cgroup", str(tmp_path), "--"]


@needs_prlimit
def test_a_lower_hard_limit_caps_the_value():
    """Under a hard CPU limit of 20 s (not root's to raise), asking for 50 gives 20, not an error."""
    code = (
        "import subprocess; from fbaconf.isolation import sandbox; "
        "a, _ = sandbox.launch_argv(0, 0, 50, [], ['/bin/sh', '-c', 'ulimit -t; ulimit -H -t']); "
        "print(subprocess.run(a, capture_output=True, text=True, check=True).stdout)"
    )
    out = subprocess.run(
        ["prlimit", "--cpu=20:20", "--", sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.split()
    assert out == ["20", "20"], out


@needs_prlimit
def test_a_server_launch_joins_its_cgroups_itself_and_keeps_its_stdin(tmp_path: Path):
    """A long-lived server (fork server, persistent decoder) gets its input on stdin, so no
    shell can hold it for the harness's go: the launcher moves itself into every cgroup, sets the
    limits and execs the program, whose stdin is still the harness's pipe."""
    cgs = [tmp_path / "cg1", tmp_path / "cg2"]
    for cg in cgs:
        cg.mkdir()
        (cg / "cgroup.procs").write_text("")
    program = ["/bin/sh", "-c", "read -r line; echo $$ $(ulimit -v) $line"]
    argv, held = sandbox.launch_argv(512 * 2**20, 0, 0, cgs, program, join=True)
    assert not held
    proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, start_new_session=True)
    out, _ = proc.communicate("request\n", timeout=10)
    pid, limit, line = out.split()
    assert proc.returncode == 0 and line == "request" and limit == str(512 * 1024)
    assert pid == str(proc.pid)  # exec chain: the process that joined is the program
    assert [(cg / "cgroup.procs").read_text().strip() for cg in cgs] == [pid, pid]


@needs_prlimit
def test_a_server_launch_that_cannot_join_a_cgroup_stops_before_the_program(tmp_path: Path):
    marker = tmp_path / "started"
    gone = tmp_path / "no-such-cgroup"
    argv, _ = sandbox.launch_argv(0, 0, 0, [gone], ["/bin/sh", "-c", f"touch {marker}"], join=True)
    r = subprocess.run(argv, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=10)
    assert r.returncode == 127 and r.stderr.strip() == f"fbaconf-limit: cannot join cgroup {gone}"
    assert not marker.exists()
