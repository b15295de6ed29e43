"""Certification packages: run exactly what a claim requires, write a signed package, verify it.

Package layout (``-o DIR``)::

    certificate.json     claim, decoder, verdict, suite versions + digests, sha256 of SHA256SUMS
    SHA256SUMS           sha256 of every other file in the package (sha256sum format)
    statement.md         the human statement: verdict, what was run, provisional rules/limits
    decoder.toml         the decoder manifest as used
    report.json          the full run record (fbaconf.run/1)
    junit.xml, index.html (+ artefacts/), summary.txt
    suites/<name>.json   the suite manifests run;  golden-MANIFEST.json   the golden digests

"Signed by sha256 digests": ``verify`` recomputes every digest, checks that no file was
added or removed, and that ``certificate.json`` names the exact SHA256SUMS — changing any
byte of any file makes verification fail.
"""
from __future__ import annotations

import json
import shutil
import sys
import time
from pathlib import Path

from fbaconf._atomic import atomic_write_text
from fbaconf.conformance.suite import digest_problems, sha256_file

CERTIFICATE = "certificate.json"
SUMS = "SHA256SUMS"
FORMAT = "fbaconf.certificate/1"


def certify(decoder: str, claim: str | None, out: Path, *, jobs=None, speed: bool = True) -> int:
    from fbaconf.conformance.golden import MANIFEST
    from fbaconf.conformance.suite import golden_root, load_suites
    from . import reports
    from .adapters import resolve
    from .session import execute, preflight, resolve_claim, select_cases, write_reports
    t0 = time.perf_counter()
    adapter = resolve(decoder)
    claim = resolve_claim(claim, adapter)
    if not any(_covers(c, claim) for c in adapter.claims):
        print(f"fbaconf certify: error: the decoder does not claim {claim} (claims: {', '.join(adapter.claims)})",
              file=sys.stderr)
        return 2
    preflight(adapter)
    if adapter.is_player:
        print(f"fbaconf certify: error: {adapter.name} reads only the .fap text form (inputs: "
              f"{', '.join(adapter.inputs)}): it is a FAP player, not a decoder. An MPEG-4 profile certificate "
              f"requires decoding the binary face-object stream (inputs must include \"fba\"). Test a player "
              f"with `fbaconf run` (docs/harness.md, \"Players\").", file=sys.stderr)
        return 2
    suites = load_suites()
    cases = select_cases(suites, claim, [], [], only_required=True)
    out = Path(out)
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    record = execute(adapter, claim, cases, suites, out, jobs=jobs, progress=None, speed=speed)
    write_reports(record, out)
    verdict = {0: "PASS", 1: "FAIL", 3: "FAIL (speed)"}.get(record.exit_code, "ERROR")
    basis = claim_basis(record, cases, claim)
    (out / "suites").mkdir()
    for s in suites:
        if s.name in {c.suite for c in cases}:
            shutil.copyfile(s.manifest_path(), out / "suites" / f"{s.name}.json")
    gm = golden_root() / MANIFEST
    if gm.is_file():
        shutil.copyfile(gm, out / "golden-MANIFEST.json")
    if adapter.manifest_path:
        shutil.copyfile(adapter.manifest_path, out / "decoder.toml")
    summary = reports.terminal_summary(record, color=False)
    atomic_write_text(out / "summary.txt", summary + "\n")
    atomic_write_text(out / "statement.md", _statement(record, verdict, speed, basis))
    sums = []
    for p in sorted(q for q in out.rglob("*") if q.is_file()):
        rel = p.relative_to(out).as_posix()
        if rel in (CERTIFICATE, SUMS):
            continue
        sums.append(f"{sha256_file(p)}  {rel}")
    atomic_write_text(out / SUMS, "\n".join(sums) + "\n")
    cert = {"format": FORMAT, "decoder": adapter.name, "decoder_manifest_sha256": adapter.digest(),
            "claim": claim, "verdict": verdict, "exit_code": record.exit_code,
            "cases": len(record.results), "counts": record.counts(),
            "speed": [{"operation": s.operation, "rate_fps": s.rate_fps, "required_fps": s.required_fps,
                       "passed": s.passed} for s in record.speed] if speed else "not measured",
            "suites": record.suites, "provisional": record.provisional, "issued": record.finished,
            "rests_on": basis,
            "sha256sums_sha256": sha256_file(out / SUMS)}
    atomic_write_text(out / CERTIFICATE, json.dumps(cert, indent=1) + "\n")
    print(summary)
    print(f"certificate: {out / CERTIFICATE}  report: {out / 'index.html'}  ({time.perf_counter() - t0:.1f} s)")
    return record.exit_code


def _covers(claimed: str, claim: str) -> bool:
    from .runner import claim_covers
    return claim_covers(claimed, claim)


def claim_basis(record, cases, claim: str) -> dict:
    """What a verdict rests on: the tools the claim needs, the coverage points exercised by the
    cases that passed (of those the claim's cases exercise), and the required cases the decoder
    could not take."""
    from fbaconf.conformance.coverage import case_points
    from fbaconf.profiles.model import Claim, load_profiles
    ps = load_profiles()
    c = Claim.parse(claim, ps)
    ok = {r.case_id for r in record.results if r.outcome.ok}
    exercised, possible = set(), set()
    for case in cases:
        pts = case_points(case).points
        possible |= pts
        if case.full_id in ok:
            exercised |= pts
    return {"tools": sorted(ps.profiles[c.profile].tools),
            "coverage_points_exercised": len(exercised), "coverage_points_of_claim": len(possible),
            "not_exercised": sorted(possible - exercised),
            "cases_not_taken": list(record.missing)}


def _statement(record, verdict: str, speed: bool, basis: dict) -> str:
    c = record.counts()
    lines = [f"# fbaconf certification: {record.decoder['name']} — {record.claim}", "",
             f"**Verdict: {verdict}**", "",
             f"- decoder manifest sha256: `{record.decoder.get('manifest_sha256')}`",
             f"- cases run: {len(record.results)} (" + ", ".join(f"{k} {v}" for k, v in c.items() if v) + ")",
             "- suites: " + ", ".join(f"{s['name']} {s['version']}" for s in record.suites),
             f"- issued: {record.finished}", ""]
    if speed:
        lines.append("## Speed")
        for s in record.speed:
            lines.append(f"- {s.operation}: {s.rate_fps:.1f} frames/s measured, {s.required_fps:g} required "
                         f"({s.provenance}) — {'pass' if s.passed else 'FAIL'}")
    else:
        lines.append("Speed was not measured (--no-speed): this certificate does not cover the level's minimum rates.")
    lines += ["", "## What this verdict rests on", "",
              f"- tools the claim requires: {', '.join(basis['tools'])}",
              f"- coverage points exercised by passing cases: {basis['coverage_points_exercised']} of the "
              f"{basis['coverage_points_of_claim']} the claim's cases exercise"]
    if basis["not_exercised"]:
        lines.append(f"- not exercised (their cases did not pass): {', '.join(basis['not_exercised'][:40])}"
                     + (" …" if len(basis["not_exercised"]) > 40 else ""))
    if basis["cases_not_taken"]:
        lines += ["- required cases the decoder could not take (each fails the claim):"]
        lines += [f"  - {m}" for m in basis["cases_not_taken"]]
    else:
        lines.append("- the decoder took every required case")
    lines += ["", "## Provisional rules and limits", "",
              "The ISO/IEC 14496 text was not available to fbaconf. This verdict rests on these provisional "
              "decisions and limits:", ""]
    lines += [f"- {p}" for p in record.provisional]
    return "\n".join(lines) + "\n"


def verify_package(pkg: Path) -> list[str]:
    pkg = Path(pkg)
    problems: list[str] = []
    try:
        cert = json.loads((pkg / CERTIFICATE).read_text(encoding="utf-8"))
    except FileNotFoundError:
        return [f"no {CERTIFICATE} in {pkg}"]
    except (OSError, ValueError) as e:
        return [f"{CERTIFICATE} unreadable: {e}"]
    if cert.get("format") != FORMAT:
        problems.append(f"{CERTIFICATE}: unknown format {cert.get('format')!r}")
    sums_path = pkg / SUMS
    if not sums_path.is_file():
        return problems + [f"no {SUMS}"]
    if sha256_file(sums_path) != cert.get("sha256sums_sha256"):
        problems.append(f"{SUMS} does not match the digest in {CERTIFICATE}")
    listed: dict[str, str] = {}
    for n, line in enumerate(sums_path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        digest, sep, rel = line.partition("  ")
        if not sep or len(digest) != 64:
            problems.append(f"{SUMS} line {n} malformed")
            continue
        listed[rel] = digest
    missing, modified, extra = digest_problems(pkg, listed, ignore=lambda rel: rel in (CERTIFICATE, SUMS))
    problems += [f"missing file {rel}" for rel in missing]
    problems += [f"{rel} was modified (sha256 mismatch)" for rel in modified]
    problems += [f"file {rel} was added after signing" for rel in extra]
    try:
        report = json.loads((pkg / "report.json").read_text(encoding="utf-8"))
        if report.get("claim") != cert.get("claim") or report.get("exit_code") != cert.get("exit_code"):
            problems.append("report.json disagrees with the certificate (claim or exit code)")
    except (OSError, ValueError):
        problems.append("report.json unreadable")
    return problems
