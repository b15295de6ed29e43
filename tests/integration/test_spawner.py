"""The fuzzer's fast paths: one sandbox per worker with a fork server, and the
persistent decoder protocol. Each must judge an input exactly as a fresh sandbox would, keep
inputs apart (files, processes, stderr), and survive a decoder that dies or hangs."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from fbaconf.fuzz.inputs import Entry
from fbaconf.fuzz.targets import DecoderTarget, FuzzSetupError
from fbaconf.harness import adapters
from fbaconf.isolation import endings, forkclient, forkserver_build, sandbox
from fbaconf.isolation.forkclient import ForkServer
from fbaconf.isolation.persistent import SPARES
from fbaconf.isolation.sandbox import Limits, default_view

from lib.manifests import python_decoder

STREAM = b"\x00\x00\x01\xba" + bytes(40)


def _manifest(tmp_path: Path, body: str, *, serve: str | None = None, limits: str = "timeout_s = 5") -> Path:
    return python_decoder(tmp_path, "t", body, serve_body=serve, limits=limits)


def _target(tmp_path: Path, m: Path, **kw) -> DecoderTarget:
    return DecoderTarget(adapters.resolve(m), tmp_path / "work", oracle=False, **kw)


@pytest.fixture(params=["c", "python"])
def server(request, monkeypatch):
    """Each fork-server test runs through both servers: forkserver.c, compiled here, and
    forkserver.py (the fallback without a C compiler). They speak one protocol and must judge alike."""
    if request.param == "c":
        if forkserver_build.forkserver_binary() is None:
            pytest.skip("no C compiler: the fork server in C cannot be built")
    else:
        monkeypatch.setattr(forkserver_build, "forkserver_binary", lambda: None)
    return request.param


def test_without_a_working_compiler_the_python_server_runs(tmp_path, monkeypatch):
    """A compiler that fails (or none) is no error: the harness falls back to forkserver.py."""
    monkeypatch.setattr(forkserver_build, "_built", {})
    monkeypatch.setenv("CC", "false")
    assert forkserver_build.forkserver_binary() is None
    root = tmp_path / "w"
    (root / "case" / "in").mkdir(parents=True)
    with ForkServer(root, default_view(["/bin/sh"], root / "case"), Limits(timeout_s=2.0)) as fs:
        assert fs.native is None
        r = fs.run(["/bin/sh", "-c", "echo python server; exit 4"], root / "case")
        assert (r.returncode, r.stdout_tail.strip()) == (4, "python server")


def _check_server(fs: ForkServer, server: str) -> None:
    assert (fs.native is not None) == (server == "c")


def _alive(marker: str) -> bool:
    out = subprocess.run(["ps", "-eo", "args"], capture_output=True, text=True).stdout
    return any(marker in line and "ps -eo" not in line for line in out.splitlines())


def test_inputs_do_not_see_each_others_files(tmp_path, server):
    """Every file an input's decoder leaves in its folder (outputs, tmp, the folder itself) is
    gone before the next input: the second run exits 7 if it finds any."""
    body = """work = os.getcwd()
left = sorted(n for d in (work, os.path.join(work, 'out'), os.path.join(work, 'out', 'images'), os.environ['TMPDIR'])
              for n in os.listdir(d) if n not in ('in', 'out', 'tmp', 'images', 'faces'))
if left:
    sys.stderr.write('leftovers: %r\\n' % left); sys.exit(7)
for d in (work, os.path.join(work, 'out', 'images'), os.environ['TMPDIR']):
    open(os.path.join(d, 'junk'), 'w').write('x')
os.mkdir(os.path.join(work, 'out', 'sub'))
sys.exit(69)
"""
    t = _target(tmp_path, _manifest(tmp_path, body))
    try:
        for _ in range(2 * t.depth + 1):  # every case folder used, one of them twice
            assert t.execute(Entry(STREAM)).verdict is None  # 69 each time, never 7
        _check_server(t._workers[0].server, server)
    finally:
        t.close()


def test_a_process_left_behind_dies_with_its_input(tmp_path, server):
    if sandbox.isolation() != "bwrap":
        pytest.skip(
            "bubblewrap (bwrap) is not installed: without its PID namespace a process that leaves its "
            "session outlives its input"
        )
    marker = f"sleep {900 + uuid.uuid4().int % 99}.{uuid.uuid4().int % 997}"
    body = f"""import subprocess
subprocess.Popen({marker.split()!r}, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
time.sleep(0.2)
sys.exit(69)
"""
    t = _target(tmp_path, _manifest(tmp_path, body))
    try:
        assert t.execute(Entry(STREAM)).verdict is None
        assert not _alive(marker)  # even though it left its session
        _check_server(t._workers[0].server, server)
    finally:
        t.close()


CASES = [  # argv (after the interpreter, or a program), the ending's kind
    (["-c", "import time; time.sleep(10)"], "timeout"),
    (["-c", "x = bytearray(800 << 20)"], "memory"),
    (["/bin/dd", "if=/dev/zero", "of=big", "bs=1M", "count=5"], "output-limit"),  # SIGXFSZ
    (["-c", "open('big', 'wb').write(bytes(5 << 20))"], "crash"),  # Python ignores SIGXFSZ: EFBIG, a traceback
    (["/nonexistent/decoder"], "setup"),
    (["-c", "import os, signal; os.kill(os.getpid(), signal.SIGSEGV)"], "crash"),
    (["-c", "import sys; print('out'); sys.stderr.write('err'); sys.exit(1)"], "reject"),
]


def test_fork_server_judges_like_a_fresh_sandbox(tmp_path, server):
    """The limits a one-shot launch sets hold in each forked decoder (time, address space,
    file size, exec failure, signals), and :mod:`exits` judges the two paths alike."""
    root = tmp_path / "w"
    (root / "case" / "in").mkdir(parents=True)
    lim = Limits(timeout_s=1.0, memory_mb=300, memory_kind="address-space", output_mb=4)
    py = os.path.realpath(sys.executable)
    view = default_view([py], root / "case")
    with ForkServer(root, view, lim) as fs:
        _check_server(fs, server)
        for args, kind in CASES:
            argv = args if args[0].startswith("/") else [py, *args]
            r = fs.run(argv, root / "case")
            one = sandbox.run(argv, root / "case", lim, view=view)
            got = (endings.classify(r, lim, {1}).kind, endings.classify(one, lim, {1}).kind)
            assert got == (kind, kind), (args, r, one)
            if kind != "setup":  # (bubblewrap says exit 1 where the fork server says 127: both set-up)
                assert r.signal == one.signal and r.returncode == one.returncode
        r = fs.run([py, "-c", "import sys; print('out'); sys.stderr.write('err'); sys.exit(3)"], root / "case")
        assert (r.returncode, r.stdout_tail.strip(), r.stderr_tail) == (3, "out", "err")
        assert fs.starts == 1  # one server for all of it


def test_fork_server_environment_path_search_and_resident_memory(tmp_path, server):
    """The decoder gets the harness's minimal environment (HOME and TMPDIR in its folder), a
    bare program name is found on that environment's PATH (a missing one is a set-up failure),
    and a resident-set limit is sampled and enforced — in both servers."""
    root = tmp_path / "w"
    (root / "case" / "in").mkdir(parents=True)
    py = os.path.realpath(sys.executable)
    view = default_view([py], root / "case")
    case = os.path.realpath(root / "case")
    with ForkServer(root, view, Limits(timeout_s=5.0, memory_mb=300, output_mb=4)) as fs:
        _check_server(fs, server)
        r = fs.run(
            [py, "-c", "import os; print(os.environ['HOME'], os.environ['TMPDIR'], os.getcwd(), sorted(os.environ))"],
            root / "case",
        )
        home, tmp, cwd, names = r.stdout_tail.split(" ", 3)
        assert (r.returncode, home, tmp, cwd) == (0, case, os.path.join(case, "tmp"), case)
        assert "FBACONF" not in names and "PYTEST" not in names  # nothing of the harness's own environment
        r = fs.run(["sh", "-c", "echo found"], root / "case")
        assert (r.returncode, r.stdout_tail.strip()) == (0, "found")
        r = fs.run(["no-such-decoder-on-path"], root / "case")
        assert endings.classify(r, fs.limits, {1}).kind == "setup"
        assert "no-such-decoder-on-path" in r.stderr_tail
    rss = Limits(timeout_s=5.0, memory_mb=100, memory_kind="rss", output_mb=4)
    with ForkServer(root, view, rss) as fs:
        _check_server(fs, server)
        grow = "import time\nx = []\nfor _ in range(60):\n    x.append(bytearray(8 << 20)); time.sleep(0.01)\n"
        r = fs.run([py, "-c", grow], root / "case")
        assert endings.classify(r, rss, {1}).kind == "memory", r
        r = fs.run([py, "-c", "x = bytearray(20 << 20)"], root / "case")
        assert (r.returncode, endings.classify(r, rss, {1}).kind) == (0, "decoded")


@pytest.mark.parametrize("how", ["os.kill(os.getppid(), signal.SIGKILL)", "os.kill(-1, signal.SIGKILL)"])
def test_a_decoder_that_kills_its_fork_server_is_its_inputs_finding(tmp_path, server, how):
    """A hostile decoder kills the fork server (its parent, or everything it may signal). That
    is the finding of the input that did it, named as such — not a set-up failure that stops the
    campaign — and the next input runs in a fresh server and is judged as usual."""
    body = f"""data = open(sys.argv[1], 'rb').read()
if b'KILL' in data:
    try:
        {how}
    except OSError:
        pass
sys.exit(69)
"""
    if "-1" in how and sandbox.isolation() != "bwrap":
        pytest.skip("kill(-1) outside a PID namespace would signal every process of this user")
    t = _target(tmp_path, _manifest(tmp_path, body))
    try:
        assert t.execute(Entry(STREAM)).verdict is None
        for _ in range(2):
            v = t.execute(Entry(STREAM + b"KILL")).verdict
            assert (v.cls, v.signature) == ("unexpected-exit", "fork-server-killed"), v
            assert "killed its parent" in v.message
            assert t.execute(Entry(STREAM)).verdict is None  # a fresh server took over
        _check_server(t._workers[0].server, server)
        assert t._workers[0].server.starts == 3
    finally:
        t.close()


def test_a_fork_server_that_cannot_start_is_a_set_up_failure(tmp_path, monkeypatch):
    """The other side of the hello: a server that dies before saying it is a set-up failure."""
    monkeypatch.setattr(forkserver_build, "forkserver_binary", lambda: None)
    broken = tmp_path / "broken_server.py"
    broken.write_text("import sys\nsys.exit(3)\n")
    monkeypatch.setattr(forkclient, "SERVER_SCRIPT", broken)
    t = _target(tmp_path, _manifest(tmp_path, "sys.exit(69)"))
    try:
        with pytest.raises(FuzzSetupError, match="could not start"):
            t.execute(Entry(STREAM))
    finally:
        t.close()


SERVE = """def answer(code):
    print(rid, code, flush=True)
n = 0
while True:
    line = sys.stdin.buffer.readline()
    if not line:
        break
    rid, size, out = line.decode().rstrip('\\n').split(' ', 2)
    data = sys.stdin.buffer.read(int(size))
    n += 1
    sys.stderr.write('input %d of this process\\n' % n)
    if b'SEGV' in data:
        os.kill(os.getpid(), signal.SIGSEGV)
    if b'HANG' in data:
        time.sleep(60)
    if b'ASAN' in data:
        sys.stderr.write('==1==ERROR: AddressSanitizer: heap-buffer-overflow on address 0x1\\n')
    if b'JUNK' in data:
        print('what?', flush=True)
        continue
    if b'QUIT' in data:
        sys.exit(0)
    answer(1 if b'BAD' in data else 69)
"""


def test_persistent_protocol_survives_crashes_and_hangs(tmp_path):
    m = _manifest(tmp_path, "sys.exit(69)", serve=SERVE, limits="timeout_s = 1")
    t = _target(tmp_path, m)
    assert t.persistent
    try:

        def run(payload):
            return t.execute(Entry(STREAM + payload)).verdict

        assert run(b"") is None and run(b"BAD") is None  # not supported; a clean reject
        v = run(b"SEGV")
        assert v.cls == "crash" and "SIGSEGV" in v.signature
        assert run(b"") is None  # a fresh process took over
        v = run(b"ASAN")
        assert v.cls == "crash" and "AddressSanitizer" in v.message  # a report without dying is a crash
        assert run(b"") is None  # ... of that input only: the next one's stderr is its own
        assert run(b"HANG").cls == "hang"
        assert run(b"") is None
        assert run(b"JUNK").cls == "unexpected-exit"  # not an answer line
        assert run(b"QUIT").cls == "unexpected-exit"  # exited without answering
        quit_ = t.start(Entry(STREAM + b"QUIT"))
        time.sleep(0.5)  # it has exited before its ending is read: judged, never sent again
        assert quit_.result().verdict.cls == "unexpected-exit"
        assert run(b"") is None
        dec = t._workers[0].server
        # the first, one after SEGV, HANG, JUNK and each QUIT, and two to confirm SEGV and HANG (each ended
        # a process that had answered an input before: run again as a fresh process's first input)
        assert dec.starts == 8
        # after the first restart two spares were kept starting, and each later restart took one
        assert dec._launches == dec.starts + SPARES == dec.starts + 2
        spares = [s.proc for s in dec._spares]
        assert len(spares) == 2 and all(p.poll() is None for p in spares)  # ready for the next crashes
    finally:
        t.close()
    assert all(p.poll() is not None for p in spares)  # stopped with the worker


def test_serve_takes_no_per_input_placeholders(tmp_path):
    m = _manifest(tmp_path, "sys.exit(69)", serve="pass")
    m.write_text(m.read_text().replace('serve = ["{python}", ', 'serve = ["{python}", "{input}", '))
    with pytest.raises(adapters.ManifestError, match="serve"):
        adapters.load_manifest(m)


def test_queued_inputs_answer_in_order(tmp_path, server):
    """An input sent while another runs starts when it ends; both answers come back to their
    own input even when they arrive together (no lost reply, no phantom hang)."""
    root = tmp_path / "w"
    for i in range(2):
        (root / f"case{i}" / "in").mkdir(parents=True)
    lim = Limits(timeout_s=2.0, memory_mb=300, output_mb=4)
    view = default_view(["/bin/sh"], root / "case0")
    view.writable.append(root / "case1")
    with ForkServer(root, view, lim, slots=2) as fs:
        _check_server(fs, server)
        for i in range(30):
            a = fs.start(["/bin/sh", "-c", f"echo a{i} >&2; exit {i % 3}"], root / "case0", slot=0)
            b = fs.start(["/bin/sh", "-c", f"echo b{i} >&2; exit {(i + 1) % 3}"], root / "case1", slot=1)
            time.sleep(0.05)  # both have ended: their replies wait together in the pipe
            rb, ra = b.result(), a.result()  # judged in any order
            assert (ra.returncode, ra.stderr_tail.strip(), ra.timed_out) == (i % 3, f"a{i}", False)
            assert (rb.returncode, rb.stderr_tail.strip(), rb.timed_out) == ((i + 1) % 3, f"b{i}", False)
        assert fs.starts == 1


def test_persistent_queued_inputs_keep_their_own_stderr(tmp_path):
    m = _manifest(tmp_path, "sys.exit(69)", serve=SERVE, limits="timeout_s = 2")
    t = _target(tmp_path, m)
    try:
        for _ in range(10):
            runs = [t.start(Entry(STREAM + p)) for p in (b"ASAN", b"")]
            first, second = (r.result().verdict for r in runs)
            assert first.cls == "crash" and second is None  # the report stays with its input
    finally:
        t.close()


def test_the_c_server_under_address_and_undefined_behaviour_sanitizers(tmp_path, monkeypatch, capfd):
    """forkserver.c built with ASan + UBSan (aborting on the first report) serves every kind of
    ending without a report on its stderr (the harness's, captured here) and without dying
    (a server is started afresh only after a cgroup memory hit, by design). A resident-set
    limit: ASan cannot map its shadow memory under an address-space limit."""
    cc = forkserver_build.compiler()
    exe = tmp_path / "fbaconf-forkserver"
    if (
        cc is None
        or subprocess.run(
            [
                cc,
                "-O1",
                "-g",
                "-fsanitize=address,undefined",
                "-fno-sanitize-recover=all",
                "-o",
                str(exe),
                str(forkserver_build.SOURCE),
            ],
            capture_output=True,
        ).returncode
        != 0
    ):
        pytest.skip("no compiler with AddressSanitizer and UndefinedBehaviorSanitizer here")
    monkeypatch.setattr(forkserver_build, "forkserver_binary", lambda: exe)
    monkeypatch.setenv("ASAN_OPTIONS", "detect_leaks=0")
    root = tmp_path / "w"
    (root / "case" / "in").mkdir(parents=True)
    lim = Limits(timeout_s=1.0, memory_mb=200, memory_kind="rss", output_mb=4)
    py = os.path.realpath(sys.executable)
    with ForkServer(root, default_view([py], root / "case"), lim) as fs:
        assert fs.native == exe
        expected = [
            (["/bin/sh", "-c", "exit 3"], "unexpected"),
            (["/bin/sh", "-c", "kill -SEGV $$"], "crash"),
            (["/nonexistent/decoder"], "setup"),
            (["/bin/sh", "-c", "sleep 5"], "timeout"),
            ([py, "-c", "x = [bytearray(8 << 20) for _ in range(60)]"], "memory"),
        ]
        for argv, kind in expected * 2:
            assert endings.classify(fs.run(argv, root / "case"), lim, {1}).kind == kind, argv
        for i in range(100):
            r = fs.run(["/bin/sh", "-c", f"echo {i}; exit {i % 5}"], root / "case")
            assert (r.returncode, r.stdout_tail.strip()) == (i % 5, str(i))
        assert fs.starts <= 3  # the first, and at most one after each of the two memory endings
    assert "Sanitizer" not in capfd.readouterr().err
