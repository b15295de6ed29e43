"""Hostile decoders: one decoder per attack, each row asserting the attack is
contained — and that an honest decoder still passes under the same sandbox.

The sandbox rows need bubblewrap (``.ci/run`` installs it). Without it they fail in CI
(``CI`` set) and skip elsewhere, naming the reason: a developer machine without bwrap
runs decoders unisolated, which is exactly what these rows would catch.
"""

from __future__ import annotations

import hashlib
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

import fbaconf
from fbaconf.certification import certify
from fbaconf.conformance.suite import Suite, SuiteError, golden_root
from fbaconf.fuzz.promote import promote
from fbaconf.harness import adapters
from fbaconf.harness.results import Outcome, ResultLog
from fbaconf.harness.runner import run_cases

from lib.cases import cases
from lib.hangs import HANG_S
from lib.manifests import decoder
from lib.sandbox import needs_cgroups, needs_sandbox

ROOT = Path(fbaconf.__file__).resolve().parents[1]
VALID = ["simple-l1-core/arith-q8-visemes-expressions", "simple-l1-core/dct-q4"]


def run(tmp_path: Path, m: Path, ids=VALID, **kw):
    return run_cases(
        adapters.resolve(m), cases(ids), claim="simple@1", out_dir=tmp_path / "run", jobs=1, progress=False, **kw
    )


def digest(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def test_honest_decoder_passes_in_the_sandbox(tmp_path):
    needs_sandbox()
    rs = run(tmp_path, decoder(tmp_path, "honest", "honest()\n"))
    assert [r.outcome for r in rs] == [Outcome.PASS, Outcome.PASS], [r.message for r in rs]


def test_copy_the_golden_fails_every_valid_case(tmp_path):
    needs_sandbox()
    gold = golden_root()
    body = f"""
        import shutil
        from pathlib import Path
        case = Path(IN).stem
        for g in Path({str(gold)!r}).glob("*/" + case + "/*.npz"):
            shutil.copyfile(g, OUT)
            break
        """
    assert any(gold.glob("*/*/*.npz")), "the goldens exist outside the sandbox"
    rs = run(tmp_path, decoder(tmp_path, "copier", body))
    assert all(r.outcome == Outcome.FAIL for r in rs), [(r.outcome, r.message) for r in rs]


def test_cannot_change_the_harness_the_venv_or_its_manifest(tmp_path):
    needs_sandbox()
    targets = [ROOT / "harness" / "runner.py", ROOT / "conformance" / "data" / "suites.toml"]
    site = Path(next(p for p in sys.path if p.endswith("site-packages")))
    m_path = tmp_path / "patcher.toml"
    body = f"""
        for t in {[str(t) for t in targets]!r}:
            try:
                open(t, "a").write("# patched")
            except OSError:
                pass
        for t in [{str(site / "evil.pth")!r}, {str(m_path)!r}]:
            try:
                open(t, "w").write("import os")
            except OSError:
                pass
        honest()
        """
    before = {t: digest(t) for t in targets}
    m = decoder(tmp_path, "patcher", body)
    mtext = m.read_text()
    rs = run(tmp_path, m, ids=VALID[:1])
    assert {t: digest(t) for t in targets} == before
    assert not (site / "evil.pth").exists()
    assert m.read_text() == mtext
    assert rs[0].outcome == Outcome.PASS


def test_cannot_forge_the_results_of_the_run(tmp_path):
    needs_sandbox()
    body = """
        from pathlib import Path
        run = Path(OUT).parents[4]
        for p in [run / "results.jsonl", Path(OUT).parents[3] / "results.jsonl"]:
            try:
                p.write_text('{"case_id": "x", "outcome": "Pass"}\\n')
            except OSError:
                pass
        sys.exit(3)
        """
    rs = run(tmp_path, decoder(tmp_path, "forger", body), ids=VALID[:1])
    assert rs[0].outcome == Outcome.FAIL
    logged = ResultLog(tmp_path / "run" / "results.jsonl").read()
    assert [r.outcome for r in logged.values()] == [Outcome.FAIL]


def _procs_with(marker: str) -> list[int]:
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if marker in (d / "cmdline").read_bytes().decode(errors="replace"):
                    out.append(int(d.name))
            except OSError:
                pass
    return out


def test_an_escaped_grandchild_is_gone_when_the_case_ends(tmp_path):
    needs_sandbox()
    body = """
        subprocess.Popen(["setsid", "sleep", "313.5"], start_new_session=True)
        if os.fork() == 0:
            os.setsid()
            if os.fork() == 0:
                os.execvp("sleep", ["sleep", "313.5"])
            os._exit(0)
        honest()
        """
    rs = run(tmp_path, decoder(tmp_path, "escaper", body), ids=VALID[:1])
    time.sleep(0.2)
    assert _procs_with("313.5") == []
    assert rs[0].outcome == Outcome.PASS


def test_a_fork_bomb_is_capped_and_cleaned_up(tmp_path):
    needs_sandbox()
    needs_cgroups()
    body = """
        n = 0
        for i in range(300):
            try:
                if os.fork() == 0:
                    time.sleep(60)
                    os._exit(0)
                n += 1
            except OSError:
                break
        print("forked", n, file=sys.stderr)
        sys.exit(0 if n < 300 else 9)
        """
    rs = run(tmp_path, decoder(tmp_path, "bomb", body, limits="timeout_s = 20\nprocesses = 32\n"), ids=VALID[:1])
    # the run ends with the bomb's own exit: its sleeping children are not waited for
    assert rs[0].outcome != Outcome.TIMEOUT, rs[0].message
    assert "forked" in rs[0].stderr_tail and int(rs[0].stderr_tail.split("forked")[1].split()[0]) < 32
    time.sleep(0.2)
    assert _procs_with("bomb.py") == []


def test_memory_limit_holds_for_the_whole_tree(tmp_path):
    needs_sandbox()
    needs_cgroups()
    body = """
        kids = []
        for i in range(3):
            pid = os.fork()
            if pid == 0:
                blob = b"x" * (150 * 2**20)
                time.sleep(3)
                os._exit(0)
            kids.append(pid)
        ok = all(os.waitpid(p, 0)[1] == 0 for p in kids)
        honest()
        sys.exit(0 if ok else 1)
        """
    rs = run(tmp_path, decoder(tmp_path, "hog", body, limits="timeout_s = 30\nmemory_mb = 300\n"), ids=VALID[:1])
    assert rs[0].outcome == Outcome.CRASH and "memory limit" in rs[0].message, rs[0].message


def test_no_network(tmp_path):
    needs_sandbox()
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    srv.settimeout(0.5)
    port = srv.getsockname()[1]
    body = f"""
        import socket
        try:
            socket.create_connection(("127.0.0.1", {port}), timeout=2).sendall(b"leak")
        except OSError as e:
            print("no network:", e, file=sys.stderr)
        honest()
        """
    rs = run(tmp_path, decoder(tmp_path, "caller", body), ids=VALID[:1])
    with pytest.raises(OSError):
        srv.accept()
    srv.close()
    assert "no network" in rs[0].stderr_tail


def test_writes_outside_its_folder_do_not_land(tmp_path):
    needs_sandbox()
    victim = tmp_path / "victim.txt"
    body = f"""
        for t in [{str(victim)!r}, "/tmp/fbaconf-escape-marker", "/etc/fbaconf-escape-marker"]:
            try:
                open(t, "w").write("escaped")
            except OSError:
                pass
        honest()
        """
    rs = run(tmp_path, decoder(tmp_path, "writer", body), ids=VALID[:1])
    assert not victim.exists()
    assert not Path("/tmp/fbaconf-escape-marker").exists() and not Path("/etc/fbaconf-escape-marker").exists()
    assert rs[0].outcome == Outcome.PASS


def test_a_deep_tree_in_the_work_folder_does_not_stop_the_run(tmp_path):
    body = """
        fd = os.open(".", os.O_RDONLY)
        for i in range(3000):
            os.mkdir("d", dir_fd=fd)
            nfd = os.open("d", os.O_RDONLY, dir_fd=fd)
            os.close(fd)
            fd = nfd
        sys.exit(3)
        """
    rs = run(tmp_path, decoder(tmp_path, "deep", body), ids=VALID)
    assert [r.outcome for r in rs] == [Outcome.FAIL, Outcome.FAIL]
    assert not (tmp_path / "run" / "work").exists()


@pytest.mark.parametrize("kind", ["fifo", "zero", "passwd"])
def test_outputs_that_are_not_regular_files_are_not_read(tmp_path, kind):
    make = {
        "fifo": "os.mkfifo(OUT)",
        "zero": "os.symlink('/dev/zero', OUT)",
        "passwd": "os.symlink('/etc/passwd', OUT)",
    }[kind]
    rs = run(tmp_path, decoder(tmp_path, kind, make + "\n", faps_format="fap"), ids=VALID[:1])
    assert rs[0].outcome == Outcome.FAIL and "regular file" in rs[0].message, rs[0].message


@pytest.mark.parametrize(
    "limits",
    [
        "timeout_s = 1e300",
        "timeout_s = inf",
        "timeout_s = -1",
        "memory_mb = 1.5",
        "processes = 0",
        "output_mb = 99999999999",
    ],
)
def test_limits_that_would_disable_checks_are_refused(tmp_path, limits):
    m = decoder(tmp_path, "lim", "honest()\n", limits=limits + "\n")
    with pytest.raises(adapters.ManifestError):
        adapters.resolve(m)


@pytest.mark.parametrize("name", ["../../x", "/abs/path", ".hidden", "a/b", ""])
def test_manifest_names_cannot_leave_the_run_folder(tmp_path, name):
    m = decoder(tmp_path, "named", "honest()\n")
    m.write_text(m.read_text().replace('name = "named"', f'name = "{name}"'))
    with pytest.raises(adapters.ManifestError):
        adapters.resolve(m)


def fbaconf_cli(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "fbaconf", *args], capture_output=True, text=True, cwd=cwd, timeout=600
    )


def test_certify_leaves_a_users_folder_intact(tmp_path):
    mine = tmp_path / "mine"
    (mine / ".git").mkdir(parents=True)
    (mine / "notes.txt").write_text("keep me")
    r = fbaconf_cli("certify", "--decoder", "reference-inprocess", "--claim", "simple@1", "-o", str(mine), "--no-speed")
    assert r.returncode == 2 and "not empty" in r.stderr
    assert (mine / "notes.txt").read_text() == "keep me" and (mine / ".git").is_dir()


def test_a_re_signed_package_fails_verification(signed_package):
    out, pub = signed_package
    v = certify.verify(out, pub)
    assert (v.problems, v.state) == ([], "signed, signature checked")
    # The attacker edits the report and the certificate, recomputes every digest — but has no key.
    report = out / "report.json"
    data = json.loads(report.read_text())
    data["exit_code"] = 0
    report.write_text(json.dumps(data))
    lines = []
    for ln in (out / certify.SUMS).read_text().splitlines():
        rel = ln.split("  ", 1)[1]
        lines.append(f"{digest(out / rel)}  {rel}")
    (out / certify.SUMS).write_text("\n".join(lines) + "\n")
    assert certify.verify(out).problems == []  # digests alone cannot tell
    v = certify.verify(out, pub)
    assert v.state == "signature INVALID" and any(p.startswith("SIGNATURE:") for p in v.problems)
    r = fbaconf_cli("certify", "verify", str(out), "--pubkey", str(pub))
    assert r.returncode == 1
    r = fbaconf_cli("certify", "verify", str(out))
    assert r.returncode == 1 and "NOT VERIFIED" in r.stdout and "not checked" in r.stdout.lower()


def test_unsigned_packages_say_so(certified_package):
    out = certified_package
    v = fbaconf_cli("certify", "verify", str(out))
    assert v.returncode == 0 and "unsigned: anyone could have written this" in v.stdout


def test_sums_entries_outside_the_package_are_refused(certified_package):
    out = certified_package
    sums = out / certify.SUMS
    sums.write_text(sums.read_text() + f"{digest(Path('/etc/hostname'))}  ../../../../../../etc/hostname\n")
    assert any("would leave" in p for p in certify.verify_package(out))
    (out / "fifo").unlink(missing_ok=True)
    os.mkfifo(out / "fifo")
    certify.verify_package(out)  # returns (a FIFO is refused unopened, never read: no hang)


def test_interruption_kills_running_decoders_and_resume_is_exact(tmp_path):
    """SIGINT at -j 2 while decoders sleep: the run stops within seconds with a partial
    report; --resume then runs exactly the cases that had not finished."""
    flag = tmp_path / "fast-now"
    body = f"""
        from pathlib import Path
        if "dct" in Path(IN).name and not Path({str(flag)!r}).exists():
            time.sleep(60)
        honest()
        """
    m = decoder(tmp_path, "sleepy", body, limits="timeout_s = 120\n")
    out = tmp_path / "run"
    args = [
        sys.executable,
        "-m",
        "fbaconf",
        "run",
        "--decoder",
        str(m),
        "--claim",
        "simple@1",
        "-j",
        "2",
        "--suite",
        "simple-l1-core",
        "--case",
        "arith-q8-visemes-expressions",
        "--case",
        "dct-q4",
        "--case",
        "dct-short-high-level",
        "-o",
        str(out),
    ]
    p = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    log = out / "results.jsonl"
    deadline = time.monotonic() + HANG_S
    while time.monotonic() < deadline and not (log.exists() and log.read_text().count("\n") >= 1):
        time.sleep(0.1)
    time.sleep(0.5)
    p.send_signal(__import__("signal").SIGINT)
    p.communicate(timeout=HANG_S)
    # stopped at once: the case under way when the signal came is not finished (not in the log)
    assert p.returncode == 130
    report = json.loads((out / "report.json").read_text())
    assert report["exit_code"] == 130
    done = [json.loads(x)["case_id"] for x in log.read_text().splitlines()]
    assert done == ["simple-l1-core/arith-q8-visemes-expressions"]
    assert _procs_with("sleepy.py") == []
    flag.write_text("")
    r = subprocess.run(args + ["--resume"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    lines = [json.loads(x)["case_id"] for x in log.read_text().splitlines()]
    assert sorted(lines) == sorted(
        ["simple-l1-core/arith-q8-visemes-expressions", "simple-l1-core/dct-q4", "simple-l1-core/dct-short-high-level"]
    )


@pytest.mark.parametrize(
    "manifest",
    [
        "[]",
        '{"format": "fbaconf.suite/1"}',
        '{"format": "fbaconf.suite/1", "name": "../../x", "claim": "simple@1", "cases": []}',
        '{"format": "fbaconf.suite/1", "name": "s", "claim": "simple@1", "cases": [{"id": "/etc"}]}',
        '{"format": "fbaconf.suite/1", "name": "s", "claim": "simple@1", "cases": [{"id": "c", "claim": "simple@1", '
        '"inputs": {"fba": "../../../etc/passwd"}}]}',
        '{"format": "fbaconf.suite/1", "name": "s", "claim": "simple@1", "cases": [3]}',
        '{"format": "fbaconf.suite/1", "name": "s", "claim": 1, "cases": {}}',
    ],
)
def test_malformed_or_escaping_suite_manifests_are_one_clear_error(tmp_path, manifest):
    d = tmp_path / "s"
    d.mkdir()
    (d / "suite.json").write_text(manifest)
    with pytest.raises(SuiteError):
        Suite.load(d)


def test_promote_confines_what_a_finding_names(tmp_path):
    fz = tmp_path / "fz" / "findings"
    for fid, minimal in (("../../escape", "min.fba"), ("ok1", "/etc/passwd"), ("ok2", "../../../../etc/hostname")):
        d = fz / f"f-{abs(hash(fid))}"
        d.mkdir(parents=True)
        (d / "min.fba").write_bytes(b"\x00\x00\x01\xba")
        (d / "finding.json").write_text(
            json.dumps({"id": fid, "class": "crash", "signature": "x", "minimal": {"file": minimal}})
        )
    data = tmp_path / "data"
    refused = []
    assert promote(tmp_path / "fz", data, log=refused.append) == []
    assert len(refused) == 3 and all("skipped" in x for x in refused)
    assert not (tmp_path / "escape.fba").exists() and not any(tmp_path.rglob("passwd"))
    assert not any(tmp_path.rglob("hostname"))


BASE_MANIFEST = 'name = "x"\nclaims = ["simple@1"]\ninputs = ["fba"]\noutputs = ["faps"]\nfaps_format = "fap"\n'
GOOD_COMMANDS = '[commands]\ndecode = ["/bin/true", "{input}", "{faps_out}"]\n'


@pytest.mark.parametrize(
    "text",
    [
        BASE_MANIFEST.replace('"x"', "1") + GOOD_COMMANDS,
        BASE_MANIFEST.replace('["simple@1"]', '"simple@1"') + GOOD_COMMANDS,
        BASE_MANIFEST.replace('["simple@1"]', '["simpel@1"]') + GOOD_COMMANDS,
        BASE_MANIFEST.replace('["fba"]', '["xyz"]') + GOOD_COMMANDS,
        BASE_MANIFEST + "tools = [1]\n" + GOOD_COMMANDS,
        BASE_MANIFEST + "reject_exit_codes = [69]\n" + GOOD_COMMANDS,
        BASE_MANIFEST + "env = [1]\n" + GOOD_COMMANDS,
        BASE_MANIFEST + "python = 1\n" + GOOD_COMMANDS,
        BASE_MANIFEST + 'python = "fbaconf.harness.refadapter:ReferenceAdapter"\n[options]\nnope = 1\n',
        BASE_MANIFEST + "sandbox = 1\n" + GOOD_COMMANDS,
        BASE_MANIFEST + "[commands]\ndecode = [1]\n",
        BASE_MANIFEST + '[commands]\ndecode = ["/bin/true", "{nope}"]\n',
        BASE_MANIFEST + "commands = 1\n",
        BASE_MANIFEST + "limits = 3\n" + GOOD_COMMANDS,
        BASE_MANIFEST + "[limits]\ntimeout = 1\n" + GOOD_COMMANDS,
        BASE_MANIFEST + "tmeout_s = 1\n" + GOOD_COMMANDS,
        "\x00\x01",
        "name = ",
        "",
    ],
)
def test_malformed_manifests_are_one_clear_error(tmp_path, text):
    m = tmp_path / "m.toml"
    m.write_text(text, errors="surrogateescape")
    with pytest.raises(adapters.ManifestError):
        adapters.resolve(m)
