"""What the sandbox shows a decoder (docs/harness.md "What a decoder sees"): one
hostile decoder per way of looking — a sibling file, its folder, ``..``, /proc (its parent's
cwd, every process's command line, environment and descriptors), a copy-anything crawl — and
each must find nothing derived from the goldens or the reference outputs, nothing of the run
or package folder, and no key. Every line of that docs section names its test here.

The sandboxed rows need bubblewrap (as in test_attacks.py: fail in CI, skip elsewhere).
"""

from __future__ import annotations

import json
import sys
import textwrap
from pathlib import Path
from types import SimpleNamespace

import pytest

import fbaconf
from fbaconf.conformance.suite import golden_root, load_suites, suites_root
from fbaconf.harness import adapters
from fbaconf.harness.adapters import ViewError
from fbaconf.harness.results import Outcome
from fbaconf.harness.runner import run_cases
from fbaconf.isolation import sandbox
from fbaconf.isolation.staging import auxiliary_files, staged_inputs

from lib.cases import cases
from lib.manifests import write_manifest
from lib.sandbox import needs_sandbox

ROOT = Path(fbaconf.__file__).resolve().parents[1]
# binary cases with a .fap sibling in their suite folder, one with skips, one with a texture
WITH_SIBLING = ["simple-l1-core/arith-q8-visemes-expressions", "simple-l1-core/skips-14-15", "simple-l1-core/dct-q4"]
TEXTURED = "predictable-l1-stress/grid-limits-l1"


def manifest(
    tmp_path: Path, name: str, decode: list, *, inputs=("fba",), outputs=("faps",), fmt="fap", claim="predictable@2"
) -> Path:
    return write_manifest(
        tmp_path / name / f"{name}.toml",
        decode,
        claims=[claim],
        inputs=inputs,
        outputs=outputs,
        faps_format=fmt,
        limits="timeout_s = 30",
    )


def python_decoder(tmp_path: Path, name: str, body: str, **kw) -> Path:
    """A decoder written in Python (run through {python}: the widest view there is)."""
    script = tmp_path / name / f"{name}.py"
    script.parent.mkdir(exist_ok=True)
    script.write_text("import os, sys, json, shutil\nIN, OUT = sys.argv[1], sys.argv[2]\n" + textwrap.dedent(body))
    return manifest(tmp_path, name, ["{python}", str(script), "{input}", "{faps_out}"], **kw)


def run(tmp_path: Path, m: Path, ids, **kw):
    return run_cases(
        adapters.resolve(m), cases(ids), claim=None, out_dir=tmp_path / "run", jobs=1, progress=False, **kw
    )


# ------------------------------------------------------------------ the case folder


def test_a_case_folder_holds_exactly_the_input_forms_the_manifest_accepts():
    """Every case of every suite, for a decoder of the binary stream, a player, and one that
    takes every form: never the .fap of a binary case, never a golden, never another case's file."""
    decoder = SimpleNamespace(inputs=["fba"])
    player = SimpleNamespace(inputs=["fap"])
    everything = SimpleNamespace(inputs=["fba", "fap", "scene", "bifs"])
    n = 0
    for s in load_suites():
        for c in s.cases:
            n += 1
            named = {v for k, v in c.inputs.items() if k != "faces"} | set(c.inputs.get("faces", []))
            for who in (decoder, player, everything):
                staged = staged_inputs(who, c)
                names = {p.name for p in staged.values()} | {p.name for p in auxiliary_files(c)}
                assert all(p.parent == c.suite_dir for p in staged.values())
                assert names <= set(c.sha256) | named, (c.full_id, names)
                assert not any(p.suffix in (".npz",) for p in staged.values())
                if c.inputs.get("fba") and "fba" in who.inputs:
                    assert c.inputs.get("fap") not in names, c.full_id  # the reference decoding
            assert "scene" not in staged_inputs(decoder, c) and "scene_bifs" not in staged_inputs(decoder, c)
            assert "fba" not in staged_inputs(player, c)
    assert n > 100


def test_a_textured_case_stages_its_texture_and_its_scene_forms_only_as_accepted(tmp_path):
    (case,) = cases([TEXTURED])
    bt_only = SimpleNamespace(inputs=["fba", "scene"])
    staged = staged_inputs(bt_only, case)
    assert sorted(staged) == ["fba", "input", "scenario", "scene", "scene_bt"]
    assert [p.name for p in auxiliary_files(case)] == ["texture512.png"]
    assert staged_inputs(SimpleNamespace(inputs=["fba", "bifs"]), case)["scene"].suffix == ".bifs"


def test_the_sibling_copier_passes_no_case(tmp_path):
    """The ten-line shell "decoder" of `cp "${1%.fba}.fap" "$2"`."""
    needs_sandbox()
    m = manifest(tmp_path, "sibling", ["/bin/sh", "-c", 'cp "${1%.fba}.fap" "$2"', "sh", "{input}", "{faps_out}"])
    rs = run(tmp_path, m, WITH_SIBLING)
    assert len(rs) == len(WITH_SIBLING) and not [r for r in rs if r.outcome.ok], [r.message for r in rs]
    assert all("No such file" in r.stderr_tail for r in rs)  # there is no sibling to copy


def test_listing_the_case_folder_shows_the_inputs_and_nothing_else(tmp_path):
    needs_sandbox()
    body = """
        here = os.path.dirname(IN)
        print(json.dumps(sorted(os.listdir(here))), file=sys.stderr)
        sys.exit(3)
        """
    rs = run(
        tmp_path,
        python_decoder(tmp_path, "lister", body, inputs=("fba", "scene"), outputs=("faps",)),
        WITH_SIBLING[:1] + [TEXTURED],
    )
    seen = [json.loads(r.stderr_tail.strip().splitlines()[-1]) for r in rs]
    assert seen[0] == ["arith-q8-visemes-expressions.fba"]
    assert seen[1] == ["grid-limits-l1-scenario.toml", "grid-limits-l1.bt", "grid-limits-l1.fba", "texture512.png"]


# ------------------------------------------------------------------ everything else it can reach

INVENTORY = """
    import stat
    seen, notes = [], []
    def note(x):
        notes.append(str(x)[:300])
    # 1. up from its folder: every ancestor it can list
    d = os.getcwd()
    while True:
        try:
            seen.extend(os.path.join(d, e) for e in os.listdir(d))
        except OSError as e:
            note(f"listdir {d}: {e}")
        if d == "/":
            break
        d = os.path.dirname(d)
    # 2. /proc: every process it can see, its parent's cwd above all
    for pid in [p for p in os.listdir("/proc") if p.isdigit()]:
        for what in ("cmdline", "environ"):
            try:
                note(f"/proc/{pid}/{what}: " + open(f"/proc/{pid}/{what}", "rb").read().decode("utf-8", "replace"))
            except OSError as e:
                pass
        for link in ("cwd", "root"):
            try:
                seen.extend(os.path.join(f"/proc/{pid}/{link}", e) for e in os.listdir(f"/proc/{pid}/{link}"))
            except OSError:
                pass
        try:
            for fd in os.listdir(f"/proc/{pid}/fd"):
                p = f"/proc/{pid}/fd/{fd}"
                note(f"fd {pid}/{fd} -> {os.readlink(p)}")
                if os.path.isdir(p):
                    seen.extend(os.path.join(p, e) for e in os.listdir(p))
        except OSError:
            pass
    note(f"ppid {os.getppid()} pid {os.getpid()}")
    # 3. a crawl of every folder it can reach outside the system ones
    skip = ("/proc", "/sys", "/dev", "/usr", "/etc", "/bin", "/sbin", "/lib", "/lib32", "/lib64", "/libx32")
    for top in os.listdir("/"):
        if "/" + top in skip:
            continue
        for root, dirs, files in os.walk("/" + top):
            seen.extend(os.path.join(root, f) for f in files)
            if len(seen) > 400000:
                break
    out = os.path.join(os.path.dirname(OUT), "inventory.json")
    with open(out, "w") as f:
        json.dump({"seen": seen, "notes": notes, "env": dict(os.environ)}, f)
    sys.exit(3)
"""


def inventory(tmp_path: Path, extra_hidden: Path | None = None) -> dict:
    """What a {python} decoder sees from inside one case (the run keeps its case folder)."""
    needs_sandbox()
    m = python_decoder(tmp_path, "inventory", INVENTORY)
    rs = run(tmp_path, m, WITH_SIBLING[:1], keep_workdirs=True)
    assert rs[0].outcome == Outcome.FAIL
    (inv,) = list((tmp_path / "run" / "work").glob("case-*/out/inventory.json"))
    return json.loads(inv.read_text())


@pytest.fixture(scope="module")
def seen(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("inventory")
    (tmp / "results-of-another-run.jsonl").write_text("{}")  # beside the run folder: must not show
    return tmp, inventory(tmp)


def test_no_golden_and_no_reference_output_is_in_view(seen):
    tmp, inv = seen
    gold = str(golden_root().resolve())
    files = inv["seen"]
    assert not [p for p in files if p.startswith(gold) or "/golden/" in p]
    assert not [
        p for p in files if p.endswith((".fap", "faps.npz", "vertices.npz")) and "/conformance/data/" not in p
    ], "a reference output or golden is visible"
    assert not [p for p in files if p.startswith(str(suites_root().resolve()))]
    assert not [p for p in files if "/build/" in p and "fbaconf" in p], "a build copy (its goldens) is visible"


def test_the_project_root_is_not_in_view_only_the_package(seen):
    _tmp, inv = seen
    files = set(inv["seen"])
    assert not [p for p in files if p.startswith(str(ROOT / "tests")) or p.startswith(str(ROOT / ".git"))]
    assert str(ROOT / "harness" / "runner.py") in files  # the fbaconf package, which {python} needs
    assert not [p for p in files if p.startswith(str(ROOT / "examples")) or p == str(ROOT / "pyproject.toml")]


def test_its_program_and_manifest_folders_are_in_view(seen):
    tmp, inv = seen
    files = set(inv["seen"])
    assert str(tmp / "inventory" / "inventory.py") in files and str(tmp / "inventory" / "inventory.toml") in files
    assert str(Path(sys.executable)) in files  # {python}: the program's folder (the venv's bin)
    assert any(p.startswith(str(Path(sys.base_prefix).resolve()) + "/lib/") for p in files)


def test_nothing_of_the_run_folder_or_other_runs_is_in_view(seen):
    tmp, inv = seen
    run = str((tmp / "run").resolve())
    files = inv["seen"]
    case = next(p for p in files if p.endswith("/in/arith-q8-visemes-expressions.fba")).rsplit("/in/", 1)[0]
    # above its own case folder only the empty folders bubblewrap makes to mount it
    skeleton = {case} | {str(a) for a in Path(case).parents if str(a).startswith(run)}
    assert {p for p in files if p.startswith(run) and not p.startswith(case + "/")} <= skeleton
    assert not [p for p in files if p.endswith(("results.jsonl", "report.json", "results-of-another-run.jsonl"))]


def test_proc_shows_no_host_process_and_its_parent_cwd_leads_nowhere(seen):
    _tmp, inv = seen
    cmdlines = [n.split(": ", 1)[1].split("\x00") for n in inv["notes"] if "/cmdline: " in n]
    # the host's processes are another PID namespace: only bubblewrap's init (pid 1) and the decoder
    assert [c[0] for c in cmdlines] == ["/usr/bin/bwrap", sys.executable], [c[:3] for c in cmdlines]
    assert "ppid 1 pid 2" in inv["notes"]
    fds = [n for n in inv["notes"] if n.startswith("fd ")]
    assert not [n for n in fds if "results.jsonl" in n or "SHA256SUMS" in n]


def test_its_environment_holds_nothing_of_the_harness(seen):
    _tmp, inv = seen
    env = inv["env"]
    assert set(env) <= {
        "PATH",
        "LANG",
        "LC_ALL",
        "HOME",
        "TMPDIR",
        "TMP",
        "TEMP",
        "LD_LIBRARY_PATH",
        "JAVA_HOME",
        "PYTHONPATH",
        "VIRTUAL_ENV",
        "LC_CTYPE",
        "PWD",
    }, sorted(env)


def test_a_copy_anything_decoder_passes_no_case(tmp_path):
    """It crawls everything it can reach for a file that looks like its case's expected output."""
    needs_sandbox()
    body = """
        stem = os.path.splitext(os.path.basename(IN))[0]
        best = None
        skip = ("/proc", "/sys", "/dev", "/usr", "/etc", "/bin", "/sbin", "/lib", "/lib64")
        for top in os.listdir("/"):
            if "/" + top in skip:
                continue
            for root, dirs, files in os.walk("/" + top):
                for f in files:
                    p = os.path.join(root, f)
                    if p == IN:
                        continue
                    if (stem in p and f.endswith((".fap", ".npz"))) or f in ("faps.npz",):
                        best = p
        if best is None:
            sys.exit(3)
        shutil.copyfile(best, OUT)
        """
    rs = run(tmp_path, python_decoder(tmp_path, "copyall", body, fmt="npz"), WITH_SIBLING)
    assert not [r for r in rs if r.outcome.ok], [(r.case_id, r.message) for r in rs]


# ------------------------------------------------------------------ folders a view must not show


@pytest.mark.parametrize("where", ["/", "/tmp", str(ROOT), str(ROOT.parent), "/proc/1/root", str(Path.home())])
def test_a_view_that_would_show_too_much_is_refused(tmp_path, where):
    m = manifest(tmp_path, "broad", ["/bin/true", "{input}", "{faps_out}"])
    a = adapters.resolve(m)
    a.lab_read_only = [Path(where)]
    with pytest.raises(ViewError):
        a.sandbox_view(["/bin/true"], tmp_path / "case")


def test_a_python_script_beside_its_manifest_folder_is_in_view(tmp_path):
    """`{python} {manifest_dir}/../prog.py` (examples/glrender): the script is the program, so its
    folder shows read-only; a script in a folder no view may show (/tmp itself) is refused."""
    (tmp_path / "manifests").mkdir()
    script = tmp_path / "prog.py"
    script.write_text("")
    m = manifest(tmp_path / "manifests", "script", ["{python}", str(script), "{input}", "{faps_out}"])
    a = adapters.resolve(m)
    assert tmp_path.resolve() in a.sandbox_view([sys.executable, str(script)], tmp_path / "case").read_only
    loose = Path("/tmp") / f"fbaconf-view-test-{tmp_path.name}.py"
    loose.write_text("")
    try:
        with pytest.raises(ViewError, match="top-level"):
            a.sandbox_view([sys.executable, str(loose)], tmp_path / "case")
    finally:
        loose.unlink()


def test_a_manifest_in_the_project_root_is_refused_before_anything_runs(tmp_path):
    """A manifest beside the clone's build/ (a copy of the goldens) and keys would show them."""
    m = ROOT / "tmp-view-test-manifest.toml"
    m.write_text((manifest(tmp_path, "inroot", ["/bin/true", "{input}", "{faps_out}"])).read_text())
    try:
        a = adapters.resolve(m)
        with pytest.raises(ViewError, match="fbaconf project"):
            a.sandbox_view(["/bin/true"], tmp_path / "case")
    finally:
        m.unlink()


def test_the_python_view_is_the_interpreter_and_the_package(tmp_path):
    view = sandbox.python_view()
    assert ROOT not in view and (ROOT / "golden") not in view
    assert all(p.parent != ROOT or (p / "__init__.py").is_file() or p == Path(sys.prefix) for p in view), view
    assert Path(sys.base_prefix).resolve() in view


def test_a_secret_file_in_view_cannot_be_read(tmp_path):
    """The fallback under the refusal above: a key inside a folder a view shows anyway (the
    {python} view's folders are never checked) is covered, unreadable."""
    needs_sandbox()
    shown = tmp_path / "shown"
    shown.mkdir()
    key = shown / "lab.key"
    key.write_text("-----BEGIN PRIVATE KEY----- s3cr3t-k3y-bytes")
    (shown / "other.txt").write_text("visible")
    work = tmp_path / "case"
    (work / "in").mkdir(parents=True)
    view = sandbox.View(read_only=[shown, Path("/bin")], writable=[work], read_only_inside=[work / "in"])
    saved = set(sandbox._SECRETS)
    try:
        sandbox.keep_secret(key)
        res = sandbox.run(
            ["/bin/sh", "-c", f"cat {shown}/other.txt; cat {key}"], work, sandbox.Limits(timeout_s=10), view=view
        )
    finally:
        sandbox._SECRETS.clear()
        sandbox._SECRETS.update(saved)
    assert "visible" in res.stdout_tail and "s3cr3t" not in res.stdout_tail + res.stderr_tail
    assert "Permission denied" in res.stderr_tail


# ------------------------------------------------------------------ the speed phase


def test_the_speed_phase_shows_a_stream_decoder_no_expected_output(tmp_path):
    """The speed content folder is in the decoder's view: it holds the streams, never their .fap
    (the expected output), and a command that asks for {fap} cannot be given one."""
    needs_sandbox()
    from fbaconf.harness.speed import measure as speed  # noqa: PLC0415 (only this test)

    body = """
        here = os.path.dirname(IN)
        bad = [f for f in os.listdir(here) if f.endswith((".fap", ".npz"))]
        if bad:
            print("SAW", bad, file=sys.stderr)
            sys.exit(3)
        from fbaconf.reference.pipeline import reference_outputs
        reference_outputs(IN, faps_out=OUT)
        """
    m = python_decoder(tmp_path, "speedlook", body, fmt="npz", claim="simple@1")
    r = speed.measure(
        adapters.resolve(m),
        "simple@1",
        "decode",
        lengths=[8, 16],
        repeats=1,
        work_dir=tmp_path / "speed",
        persistent=False,
    )
    assert r is not None  # every run decoded (one that saw a .fap would have failed: SpeedRunError)
    asks = manifest(
        tmp_path, "asksfap", ["{python}", "-c", "pass", "{input}", "{fap}", "{faps_out}"], fmt="npz", claim="simple@1"
    )
    with pytest.raises(speed.SpeedError, match="fap"):
        speed.measure(
            adapters.resolve(asks),
            "simple@1",
            "decode",
            lengths=[8, 16],
            repeats=1,
            work_dir=tmp_path / "speed2",
            persistent=False,
        )
