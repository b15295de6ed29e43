"""The lab, not the manifest, sets the bounds (items 5 and 7): limits up to the lab's
ceilings and never "none", 0 or unbounded; ``[env]`` carries data, never a runtime's start-up
hook; a decoder cannot take a bundled adapter's name; ``run`` names which limits hold and how.
Every hostile manifest here is written from the issue's description."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from fbaconf.harness import adapters
from fbaconf.isolation import bounds, cgroups, sandbox
from fbaconf.isolation.bounds import limits_in_force
from fbaconf.isolation.environ import env_problem
from fbaconf.isolation.report import report

from lib.sandbox import needs_sandbox

BASE = 'name = "acme"\nclaims = ["predictable@2"]\ninputs = ["fba"]\noutputs = ["faps"]\nfaps_format = "npz"\n'
COMMANDS = '[commands]\ndecode = ["/bin/true", "{input}", "{faps_out}"]\n'


def write(tmp_path: Path, text: str, name="acme.toml") -> Path:
    d = tmp_path / "vendor"
    d.mkdir(exist_ok=True)
    p = d / name
    p.write_text(text)
    return p


def fbaconf(*args, timeout=600) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "fbaconf", *map(str, args)], capture_output=True, text=True, timeout=timeout
    )


# ------------------------------------------------------------------ limits


# the manifests: each was accepted by run and certify, and held or wrote what it asked for
@pytest.mark.parametrize(
    "limits,words",
    [
        ('memory_kind = "none"', 'memory_kind = "none" is no limit'),
        ("memory_mb = 0", "memory_mb = 0 is no limit"),
        (
            "output_mb = 1048576",
            "output_mb = 1048576 is over the lab's ceiling of 1024 (the lab raises it with --max-output-mb)",
        ),
        (
            "processes = 4096",
            "processes = 4096 is over the lab's ceiling of 256 (the lab raises it with --max-processes)",
        ),
        (
            "timeout_s = 86400",
            "timeout_s = 86400 is over the lab's ceiling of 600 (the lab raises it with --max-timeout-s)",
        ),
        (
            "memory_mb = 8192",
            "memory_mb = 8192 is over the lab's ceiling of 4096 (the lab raises it with --max-memory-mb)",
        ),
    ],
)
def test_a_limit_past_the_labs_ceiling_or_no_limit_is_refused(tmp_path, limits, words):
    m = write(tmp_path, BASE + COMMANDS + f"[limits]\n{limits}\n")
    with pytest.raises(adapters.ManifestError) as e:
        adapters.resolve(m)
    assert e.value.rule == "manifest-limits" and words in str(e.value), str(e.value)


def test_the_labs_ceilings_are_the_safe_defaults_and_the_lab_raises_them(tmp_path):
    assert bounds.DEFAULT_CEILINGS == bounds.Ceilings(timeout_s=600, memory_mb=4096, output_mb=1024, processes=256)
    m = write(tmp_path, BASE + COMMANDS + "[limits]\nmemory_mb = 8192\ntimeout_s = 900\n")
    a = adapters.resolve(m, ceilings=bounds.Ceilings(timeout_s=900, memory_mb=8192))
    assert (a.limits.memory_mb, a.limits.timeout_s) == (8192, 900)  # as asked: never capped silently
    with pytest.raises(ValueError, match="--max-memory-mb"):
        bounds.Ceilings(memory_mb=0)
    with pytest.raises(ValueError, match="--max-timeout-s"):
        bounds.Ceilings(timeout_s=float("inf"))


def test_run_and_certify_refuse_a_limit_past_the_ceiling_before_anything_runs(tmp_path):
    m = write(tmp_path, BASE + COMMANDS + "[limits]\ntimeout_s = 86400\n")
    r = fbaconf("run", "--decoder", m, "-o", tmp_path / "run")
    assert r.returncode == 2 and "timeout_s = 86400 is over the lab's ceiling of 600" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "run").exists()
    r = fbaconf("certify", "--decoder", m, "--claim", "predictable@2", "--no-speed", "-o", tmp_path / "pkg")
    assert r.returncode == 2 and "--max-timeout-s" in r.stderr and not (tmp_path / "pkg").exists()
    r = fbaconf("run", "--decoder", m, "--max-timeout-s", "0", "-o", tmp_path / "run")
    assert r.returncode == 2 and "--max-timeout-s must be a number in (0, 86400]" in r.stderr, r.stderr


def test_the_raised_ceiling_is_the_labs_flag_on_every_verb():
    for verb in ("run", "certify", "bench", "fuzz"):
        r = fbaconf(verb, "--help", timeout=60)
        assert all(
            f in r.stdout for f in ("--max-timeout-s", "--max-memory-mb", "--max-output-mb", "--max-processes")
        ), verb


# ------------------------------------------------------------------ what run says holds


def test_run_names_the_limits_in_force_with_writable_cgroups(monkeypatch):
    if "memory" not in cgroups.controllers() or "pids" not in cgroups.controllers():
        pytest.skip("no writable memory and pids cgroups here")
    monkeypatch.setattr(sandbox, "isolation", lambda: "bwrap")
    a = adapters.resolve("reference")
    lines = limits_in_force(a)
    assert (
        lines[1] == "memory: 4096 MB over the whole process tree (cgroup memory limit; OOM events read from the kernel)"
    )
    assert lines[3] == "processes: 64 in the tree (cgroup pids limit)"
    line = report(a).notice()
    assert "NOT" not in line and "over the whole process tree" in line


def test_without_writable_cgroups_run_never_reads_as_limited_for_the_tree(monkeypatch):
    """Before: "decoders run isolated" while 3 x 800 MB under memory_mb = 1024 passed."""
    monkeypatch.setattr(cgroups, "_CG_BASES", [])  # as the other tests simulate a machine without cgroups
    monkeypatch.setattr(sandbox, "isolation", lambda: "bwrap")
    a = adapters.resolve("reference")
    line = report(a).notice()
    assert "decoders run isolated" not in line and "NOT fully isolated" in line
    assert (
        "memory: 4096 MB of address space per process (RLIMIT_AS) — no cgroup here, so NOT over the whole tree" in line
    )
    assert "processes: NOT limited (no writable pids cgroup here)" in line
    assert "over the whole process tree (cgroup" not in line
    inproc = limits_in_force(adapters.resolve("reference-inprocess"))
    assert inproc == [
        "in-process: reference-inprocess runs inside fbaconf's own process: the timeout (120 s) is "
        "checked after each call; no memory, output or process limit"
    ]


# ------------------------------------------------------------------ [env]


HOOKS = {
    "PYTHONPATH": "{dir}",
    "PYTHONSTARTUP": "{dir}/sitecustomize.py",
    "PYTHONHOME": "{dir}",
    "LD_PRELOAD": "{dir}/hook.so",
    "LD_LIBRARY_PATH": "{dir}",
    "JAVA_TOOL_OPTIONS": "-javaagent:{dir}/a.jar",
    "_JAVA_OPTIONS": "-Xmx1g",
    "JDK_JAVA_OPTIONS": "-Dx=1",
    "NODE_OPTIONS": "--require {dir}/hook.js",
    "PERL5OPT": "Mhook",
    "RUBYOPT": "rhook",
    "BASH_ENV": "{dir}/hook.sh",
    "ENV": "{dir}/hook.sh",
    "CLASSPATH": "{dir}",
    "GODEBUG": "x",
    "ASAN_OPTIONS": "log_path",
    "PATH": "{dir}",
    "HOME": "x",
}


@pytest.mark.parametrize("name", sorted(HOOKS))
def test_a_start_up_hook_in_env_is_refused(tmp_path, name):
    value = HOOKS[name].format(dir=tmp_path / "vendor")
    m = write(tmp_path, BASE + COMMANDS + f'[env]\n{name} = "{value}"\n')
    with pytest.raises(adapters.ManifestError) as e:
        adapters.resolve(m)
    assert e.value.rule == "manifest-env" and name in str(e.value)


@pytest.mark.parametrize(
    "name,value",
    [
        ("FOO_FLAGS", "--load hook"),  # a runtime the list does not know: an option
        ("FOO_OPTS", "fast -Xhook"),
        ("FOO_ARGS", "@/opt/args.txt"),  # an argument file
        ("FOO_CONF", "preload=hook"),  # a setting
    ],
)
def test_a_value_that_is_an_option_or_a_setting_is_refused_whatever_the_name(name, value):
    assert env_problem(name, value) is not None


@pytest.mark.parametrize(
    "name,value",
    [
        ("ACME_MODE", "strict"),
        ("BUG", "sign"),
        ("ACME_LICENSE", "ci"),
        ("GOBLIN_MODE", "fast"),
        ("THREADS", "2"),
        ("ACME_MODELS", "/opt/acme/models"),
    ],
)  # shows nothing more: see environ.py
def test_plain_data_passes(name, value):
    assert env_problem(name, value) is None


SITECUSTOMIZE = """
# runs before any decoder code when PYTHONPATH names this folder
import sys
sys.stderr.write("HOOKED\\n")
"""


def test_the_sitecustomize_attack_certifies_nothing_and_the_hook_was_real(tmp_path):
    """The attack: `{python} -m fbaconf.reference.decoder …` reads as the reference, and `[env]
    PYTHONPATH` (the manifest's own folder) makes Python run the vendor's sitecustomize.py
    first. certify refuses the manifest (exit 2, no package); the control shows that the
    interpreter would have run the hook."""
    needs_sandbox()
    vendor = tmp_path / "vendor"
    vendor.mkdir()
    (vendor / "sitecustomize.py").write_text(SITECUSTOMIZE)
    m = write(
        tmp_path,
        BASE + '[commands]\ndecode = ["{python}", "-c", "pass", "{input}", "{faps_out}"]\n'
        f'[env]\nPYTHONPATH = "{vendor}"\n',
    )
    r = fbaconf("certify", "--decoder", m, "--claim", "predictable@2", "--no-speed", "-o", tmp_path / "pkg")
    assert r.returncode == 2 and "PYTHONPATH is in the PYTHON… namespace" in r.stderr, r.stderr
    assert not (tmp_path / "pkg").exists()
    case = tmp_path / "case"
    (case / "in").mkdir(parents=True)
    view = sandbox.View(read_only=[vendor, *sandbox.python_view()], writable=[case])
    res = sandbox.run(
        [sys.executable, "-c", "pass"], case, sandbox.Limits(timeout_s=30), env={"PYTHONPATH": str(vendor)}, view=view
    )
    assert "HOOKED" in res.stderr_tail  # what the manifest would have done


# ------------------------------------------------------------------ reserved names


@pytest.mark.parametrize("name", ["reference", "Reference", "reference-inprocess", "dummy", "mutant", "DUMMY"])
def test_a_bundled_adapters_name_is_reserved(tmp_path, name):
    m = write(tmp_path, BASE.replace('"acme"', f'"{name}"') + COMMANDS)
    with pytest.raises(adapters.ManifestError) as e:
        adapters.resolve(m)
    assert e.value.rule == "manifest-name" and "reserved" in str(e.value)


def test_the_reserved_names_come_from_the_bundled_manifests(tmp_path):
    names = adapters.reserved_names()
    assert set(names) == {p.stem for p in adapters.BUNDLED_DIR.glob("*.toml")}
    for n in names:
        assert adapters.resolve(n).name == n  # the bundled manifests themselves load
    m = write(tmp_path, BASE.replace('"acme"', '"reference-acme"') + COMMANDS)
    assert adapters.resolve(m).name == "reference-acme"


def test_certify_refuses_a_vendor_decoder_called_reference(tmp_path):
    """Before: verify printed "— reference simple@1: PASS" for a vendor's program."""
    m = write(tmp_path, textwrap.dedent(BASE.replace('"acme"', '"reference"')) + COMMANDS)
    r = fbaconf("certify", "--decoder", m, "--claim", "predictable@2", "--no-speed", "-o", tmp_path / "pkg")
    assert r.returncode == 2 and "name 'reference' is reserved" in r.stderr and not (tmp_path / "pkg").exists()
