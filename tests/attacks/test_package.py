"""Hostile edits of a certification package: every byte is covered, the verdict is
re-derived, the signature covers the digest list, each file is read once.

Uses the session's packages (tests/conftest.py: ``certify --decoder reference-inprocess
--claim simple@1 --no-speed``, unsigned and signed)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from fbaconf.certification import package
from fbaconf.certification.certify import PUB_FILE, keygen, verify


def cli(*args):
    return subprocess.run(
        [sys.executable, "-m", "fbaconf", "certify", "verify", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=300,
    )


def reseal(pkg: Path) -> None:
    """What a forger without the key can do: recompute SHA256SUMS over the edited files."""
    (pkg / package.SIGNATURE).unlink(missing_ok=True)
    package.seal(pkg)


def edit_json(path: Path, change) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data, indent=1) + "\n")


def leaves(value, path=()):
    """Every scalar field of a JSON value, as a key path."""
    if isinstance(value, dict):
        for k, v in value.items():
            yield from leaves(v, (*path, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from leaves(v, (*path, i))
    else:
        yield path


def changed(v):
    if isinstance(v, bool):
        return not v
    if isinstance(v, (int, float)):
        return v + 1
    if v is None:
        return "x"
    return str(v) + "x"


def test_every_file_is_covered(certified_package):
    sums = (certified_package / package.SUMS).read_text().splitlines()
    listed = {ln.split("  ", 1)[1] for ln in sums}
    present = {p.relative_to(certified_package).as_posix() for p in certified_package.rglob("*") if p.is_file()}
    assert present - listed == {package.SUMS}
    for name in (
        "certificate.json",
        "statement.md",
        "summary.txt",
        "index.html",
        "results.jsonl",
        "report.json",
        "junit.xml",
        "decoder.toml",
        "golden-MANIFEST.json",
        "suites/simple-l1-core.json",
    ):
        assert name in listed, name


def test_editing_any_field_of_the_certificate_is_caught_and_names_the_file(certified_package, tmp_path):
    """Every scalar field of certificate.json, edited in place: the digest names the file."""
    cert_path = certified_package / package.CERTIFICATE
    cert = json.loads(cert_path.read_text())
    fields = list(leaves(cert))
    assert len(fields) > 40
    for path in fields:
        edited = json.loads(json.dumps(cert))
        obj = edited
        for k in path[:-1]:
            obj = obj[k]
        obj[path[-1]] = changed(obj[path[-1]])
        cert_path.write_text(json.dumps(edited, indent=1) + "\n")
        v = verify(certified_package)
        assert any(p.startswith("certificate.json:") for p in v.problems), path
    r = cli(certified_package)
    assert r.returncode == 1 and "certificate.json" in r.stderr


@pytest.mark.parametrize(
    "key,value",
    [
        ("verdict", "FAIL"),
        ("exit_code", 1),
        ("cases", 3),
        ("counts", {"Pass": 1}),
        ("claim", "simple@2"),
        ("provisional_differences", [{"case_id": "simple-l1-core/dct-q4", "rests_on": ["D8"]}]),
    ],
)
def test_a_resealed_certificate_that_disagrees_with_the_results_fails(certified_package, key, value):
    """The forger recomputes SHA256SUMS: verify re-derives the verdict and names the field."""
    edit_json(certified_package / package.CERTIFICATE, lambda c: c.__setitem__(key, value))
    reseal(certified_package)
    v = verify(certified_package)
    assert v.problems and all(
        p.startswith(("certificate.json:", "report.json:", "results.jsonl:", "statement.md:", "summary.txt:"))
        for p in v.problems
    ), v.problems
    assert any(p.startswith("certificate.json:") for p in v.problems) or key == "claim"
    r = cli(certified_package)
    assert r.returncode == 1


def test_a_failing_package_rewritten_to_pass_fails(certified_package):
    """The issue's edit, done thoroughly: one result turned to Fail, everything else left PASS."""
    res = certified_package / "results.jsonl"
    lines = res.read_text().splitlines()
    first = json.loads(lines[0])
    first["outcome"] = "Fail"
    first["rests_on"] = []
    res.write_text("\n".join([json.dumps(first)] + lines[1:]) + "\n")
    reseal(certified_package)
    v = verify(certified_package)
    assert any("verdict is 'PASS', but the results give 'FAIL'" in p for p in v.problems), v.problems


def test_dropping_a_required_result_or_marking_it_optional_fails(certified_package):
    res = certified_package / "results.jsonl"
    lines = res.read_text().splitlines()
    res.write_text("\n".join(lines[1:]) + "\n")
    reseal(certified_package)
    assert any("no result for" in p for p in verify(certified_package).problems)
    first = json.loads(lines[0])
    first["required"] = False
    res.write_text("\n".join([json.dumps(first)] + lines[1:]) + "\n")
    reseal(certified_package)
    assert any("marked not required" in p for p in verify(certified_package).problems)


def test_a_forged_provisional_basis_is_caught(certified_package):
    """A real failure relabelled as resting on D8 would turn FAIL into PASS (provisional ...)."""
    res = certified_package / "results.jsonl"
    lines = [json.loads(x) for x in res.read_text().splitlines()]
    target = next(r for r in lines if r["case_id"] == "simple-l1-core/arith-q1-all-faps")
    target.update(outcome="Fail", rests_on=["D8"], stages=[])
    res.write_text("\n".join(json.dumps(r) for r in lines) + "\n")
    edit_json(
        certified_package / package.CERTIFICATE,
        lambda c: c.update(
            verdict="PASS (provisional differences: 1)",
            provisional_differences=[{"case_id": target["case_id"], "rests_on": ["D8"]}],
            counts={"Pass": c["counts"]["Pass"] - 1, "Fail": 1},
        ),
    )
    reseal(certified_package)
    assert any("arith-q1-all-faps" in p and "rests on []" in p for p in verify(certified_package).problems)


@pytest.mark.parametrize(
    "name",
    [
        "statement.md",
        "summary.txt",
        "index.html",
        "results.jsonl",
        "report.json",
        "suites/simple-l1-core.json",
        "golden-MANIFEST.json",
        "decoder.toml",
    ],
)
def test_one_changed_byte_in_any_file_is_named(certified_package, name):
    p = certified_package / name
    data = bytearray(p.read_bytes())
    data[len(data) // 2] ^= 0x20
    p.write_bytes(bytes(data))
    v = verify(certified_package)
    assert v.problems == [f"{name}: modified (sha256 mismatch)"]
    r = cli(certified_package)
    assert r.returncode == 1 and name in r.stderr


def test_signed_packages_verify_with_the_key_and_fail_with_another(signed_package, tmp_path):
    pkg, pub = signed_package
    r = cli(pkg, "--pubkey", pub)
    assert r.returncode == 0 and "OK (signed, signature checked" in r.stdout
    keygen(tmp_path / "other")
    r = cli(pkg, "--pubkey", tmp_path / "other" / PUB_FILE)
    assert r.returncode == 1 and "SIGNATURE" in r.stderr
    # without --pubkey nothing vouches for it: said, and not OK unless accepted
    r = cli(pkg)
    assert r.returncode == 1 and "not checked" in r.stdout
    r = cli(pkg, "--unsigned-ok")
    assert r.returncode == 0 and "not checked" in r.stdout


def test_a_signed_package_edited_and_resealed_fails_with_the_key(signed_package):
    pkg, pub = signed_package
    edit_json(pkg / package.CERTIFICATE, lambda c: c.__setitem__("issued", "2000-01-01"))
    sig = (pkg / package.SIGNATURE).read_bytes()
    package.seal(pkg)
    (pkg / package.SIGNATURE).write_bytes(sig)  # the old signature kept
    v = verify(pkg, pub)
    assert v.state == package.Signature.INVALID and any(p.startswith("SIGNATURE:") for p in v.problems)
    (pkg / package.SIGNATURE).unlink()  # or dropped: then --pubkey says it is unsigned
    v = verify(pkg, pub)
    assert any(p.startswith("SIGNATURE: missing") for p in v.problems)
    assert cli(pkg).stdout.count("unsigned: anyone could have written this") == 1


def test_verify_reads_each_file_once(certified_package, monkeypatch):
    """No check-then-use: one read per file, the same bytes checked and parsed."""
    seen: dict[str, int] = {}
    real = package.read_regular

    def counting(path, limit):
        seen[Path(path).name] = seen.get(Path(path).name, 0) + 1
        return real(path, limit)

    monkeypatch.setattr(package, "read_regular", counting)
    assert verify(certified_package).problems == []
    assert seen and max(seen.values()) == 1, seen
    assert seen["certificate.json"] == 1 and seen["results.jsonl"] == 1


def test_a_certificate_swapped_after_its_digest_was_checked_changes_nothing(certified_package, monkeypatch):
    """The race of the issue: certificate.json replaced while verify runs (after it was read)."""
    real = package.read_regular
    forged = certified_package.parent / "forged.json"
    edit = json.loads((certified_package / package.CERTIFICATE).read_text())
    edit["verdict"] = "FAIL"
    forged.write_text(json.dumps(edit))

    def swapping(path, limit):
        data = real(path, limit)
        if Path(path).name == package.CERTIFICATE:
            os.replace(forged, Path(path))  # too late: the bytes are in memory
        return data

    monkeypatch.setattr(package, "read_regular", swapping)
    v = verify(certified_package)
    assert v.problems == [] and v.certificate["verdict"] == "PASS"


@pytest.mark.parametrize(
    "content", [b"[" * 100_000 + b"]" * 100_000, b'{"a":' * 100_000 + b"1" + b"}" * 100_000, b"\xff\xfe", b"[]", b'"x"']
)
def test_malformed_certificates_are_one_problem_never_a_traceback(certified_package, content):
    (certified_package / package.CERTIFICATE).write_bytes(content)
    reseal(certified_package)
    v = verify(certified_package)
    assert len(v.problems) == 1 and v.problems[0].startswith("certificate.json:"), v.problems
    r = cli(certified_package)
    assert r.returncode == 1 and "Traceback" not in r.stderr


def test_deep_results_lines_are_a_problem(certified_package):
    res = certified_package / "results.jsonl"
    res.write_bytes(res.read_bytes() + b"[" * 50_000 + b"]" * 50_000 + b"\n")
    reseal(certified_package)
    assert any(p.startswith("results.jsonl:") for p in verify(certified_package).problems)


def test_non_regular_files_are_refused_unopened(certified_package):
    os.mkfifo(certified_package / "fifo")
    (certified_package / "link").symlink_to("/etc/passwd")
    v = verify(certified_package)  # returns: a FIFO is never opened
    assert {p.split(":")[0] for p in v.problems} == {"'fifo'", "'link'"}
