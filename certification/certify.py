"""Certification packages: run exactly what a claim requires, write a sealed package.

Package layout (``-o DIR``)::

    certificate.json     claim, decoder, verdict, provisional differences, suite versions + digests
    statement.md         the human statement: verdict, isolation, what it rests on, what was not verified
    decoder.toml         the decoder manifest as used
    report.json          the full run record (fbaconf.run/1);  results.jsonl  one line per case
    junit.xml, index.html (+ artefacts/), summary.txt
    suites/<name>.json   the suite manifests run;  golden-MANIFEST.json   the golden digests
    SHA256SUMS           sha256 of every file above;  SIGNATURE  (--key) Ed25519 over SHA256SUMS

Sealing and verifying live in :mod:`.package`: ``certify verify`` re-reads every file once,
re-derives the verdict from ``results.jsonl`` and the claim rules, and fails on any change.

The lab sets isolation: the private key is read before anything else and hidden from every
decoder view; a ``python =`` adapter is accepted only from the bundled manifests; without
bubblewrap or writable cgroups ``certify`` refuses (naming what is missing) unless
``--allow-unisolated``, and the statement then says "not isolated: …".
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fbaconf._atomic import atomic_write_text
from fbaconf.conformance import official
from fbaconf.conformance.coverage_table import points_of
from fbaconf.conformance.golden import MANIFEST
from fbaconf.conformance.suite import Case, golden_root, load_suites
from fbaconf.errors import FbaconfInputError
from fbaconf.explain.causes import explain
from fbaconf.harness import reports
from fbaconf.harness.adapters import Adapter, CommandAdapter, resolve
from fbaconf.harness.preflight import preflight
from fbaconf.harness.results import RunRecord
from fbaconf.harness.selection import claim_covers, select_cases
from fbaconf.harness.session import RunOptions, execute, write_reports
from fbaconf.harness.usage import UsageError, lab_folders, resolve_claim
from fbaconf.harness.verdict import ClaimVerdict, describe
from fbaconf.isolation import sandbox
from fbaconf.isolation.bounds import DEFAULT_CEILINGS, Ceilings, limits_in_force
from fbaconf.isolation.report import report
from fbaconf.profiles.model import Claim, load_profiles
from fbaconf.safefs import read_regular, remove_tree

from .package import (
    CERTIFICATE,
    FORMAT,
    KEY_FILE,
    PUB_FILE,
    SIGNATURE,
    SUMS,
    SignatureError,
    Verification,
    derive_verdict,
    keygen,
    load_key,
    seal,
    verify,
)

__all__ = [
    "certify",
    "CertifyOptions",
    "verify",
    "verify_package",
    "keygen",
    "Verification",
    "SignatureError",
    "CERTIFICATE",
    "SUMS",
    "SIGNATURE",
    "FORMAT",
    "KEY_FILE",
    "PUB_FILE",
    "prepare_output",
    "claim_basis",
]


@dataclass
class CertifyOptions:
    """How ``certify`` runs: parallelism, the speed phase, the signing key, replacing a package,
    certifying without isolation, a Dask cluster, ``strict`` (provisional differences fail the
    claim) and the lab's extra read-only folders for the decoder's runtime (``--sandbox-ro``)."""

    jobs: int | None = None
    speed: bool = True
    key: Path | None = None
    force: bool = False
    allow_unisolated: bool = False
    cluster: str | None = None
    strict: bool = False
    sandbox_ro: list[Path] = field(default_factory=list)
    ceilings: Ceilings = DEFAULT_CEILINGS  # the most a manifest's [limits] may ask for (--max-*)


def certify(decoder: str, claim: str | None, out: Path, options: CertifyOptions | None = None, **kw: Any) -> int:
    """Certify ``decoder`` for ``claim`` into the package folder ``out`` (``kw``: fields of
    :class:`CertifyOptions`). Returns the exit code (0 pass, 1 fail, 2 set-up, 3 speed)."""
    o = options or CertifyOptions(**kw)
    t0 = time.perf_counter()
    key = None
    if o.key is not None:  # read first, hidden from every decoder from here on
        key = load_key(Path(o.key), private=True)
        sandbox.keep_secret(Path(o.key))
    adapter = resolve(decoder, untrusted=True, ceilings=o.ceilings)
    claim = resolve_claim(claim, adapter)
    if not any(claim_covers(c, claim) for c in adapter.claims):
        print(
            f"fbaconf certify: error: the decoder does not claim {claim} (claims: {', '.join(adapter.claims)})",
            file=sys.stderr,
        )
        return 2
    if isinstance(adapter, CommandAdapter):
        adapter.lab_read_only = lab_folders(o.sandbox_ro)
    preflight(adapter, claim)
    if adapter.is_player:
        print(
            f"fbaconf certify: error: {adapter.name} reads only the .fap text form (inputs: "
            f"{', '.join(adapter.inputs)}): it is a FAP player, not a decoder. An MPEG-4 profile certificate "
            f'requires decoding the binary face-object stream (inputs must include "fba"). Test a player '
            f'with `fbaconf run` (docs/harness.md, "Players").',
            file=sys.stderr,
        )
        return 2
    isolated = report(adapter)
    gaps = [] if isolated.complete else list(isolated.missing)
    if gaps and not o.allow_unisolated:
        print(
            "fbaconf certify: error: the decoder cannot be isolated on this machine: "
            + "; ".join(gaps)
            + ". Install bubblewrap (Debian: apt-get install bubblewrap) and run where cgroups are writable (as "
            'root, or in a delegated cgroup), or give --allow-unisolated (the statement then says "not '
            'isolated")',
            file=sys.stderr,
        )
        return 2
    suites = load_suites()
    cases = select_cases(suites, claim, [], [], only_required=True, adapter=adapter)
    out = Path(out).resolve()
    prepare_output(out, o.force)
    record = execute(
        adapter, claim, cases, suites, out, RunOptions(jobs=o.jobs, speed=o.speed, cluster=o.cluster, strict=o.strict)
    )
    write_reports(record, out, heading="fbaconf certification")
    if record.exit_code >= 128:
        print(f"fbaconf certify: interrupted: no certificate written; partial report in {out}", file=sys.stderr)
        return record.exit_code
    results = [r.to_json() for r in record.results]
    speed = [s.to_json() for s in record.speed] if o.speed else None
    cv = derive_verdict(results, strict=o.strict, speed=speed, declared=adapter.readings)
    verdict, code = cv.verdict, cv.exit_code
    if code != record.exit_code:  # one rule: the session's exit code and the package's verdict agree
        raise RuntimeError(f"certify: the run's exit code {record.exit_code} and the verdict {verdict} disagree")
    basis = claim_basis(record, cases, claim)
    basis["isolation"] = isolated.statement()
    basis["sandbox_ro"] = [str(p) for p in getattr(adapter, "lab_read_only", [])]
    basis["timing"] = timing_note(record, adapter)
    basis["limits"] = limits_in_force(adapter) if isinstance(adapter, CommandAdapter) else []
    (out / "suites").mkdir()
    for s in suites:
        if s.name in {c.suite for c in cases}:
            shutil.copyfile(s.manifest_path(), out / "suites" / f"{s.name}.json")
    gm = golden_root() / MANIFEST
    if gm.is_file():
        shutil.copyfile(gm, out / "golden-MANIFEST.json")
    if adapter.manifest_path:
        shutil.copyfile(adapter.manifest_path, out / "decoder.toml")
    unofficial = official.differences(record.suites, gm.read_bytes() if gm.is_file() else None)
    basis["unofficial"] = unofficial
    notices = [f"NOT ISOLATED: {basis['isolation']}"] * bool(gaps) + [
        f"UNOFFICIAL SUITES (not the suites and goldens this fbaconf ships; the verdict is not the release's "
        f"claim): {'; '.join(unofficial)}"
    ] * bool(unofficial)
    for n in notices:
        print(f"fbaconf certify: {n}", file=sys.stderr)
    summary = "".join(f"{n}\n" for n in notices) + reports.terminal_summary(record, color=False)
    atomic_write_text(out / "summary.txt", summary + "\n")
    atomic_write_text(
        out / "statement.md", _statement(record, cv, o.speed, basis) + _cause_lines(record, cases, verdict)
    )
    counts = {k: n for k, n in record.counts().items() if n}
    cert = {
        "format": FORMAT,
        "decoder": adapter.name,
        "decoder_manifest_sha256": adapter.digest(),
        "claim": claim,
        "verdict": verdict,
        "exit_code": code,
        "strict": o.strict,
        "readings": list(adapter.readings),
        "provisional_differences": cv.differences,
        "unverified": cv.unverified,
        "cases": len(results),
        "counts": counts,
        "isolated": not gaps,
        "unofficial": unofficial,
        "speed": speed if speed is not None else "not measured",
        "suites": record.suites,
        "provisional": record.provisional,
        "issued": record.finished,
        "rests_on": basis,
    }
    atomic_write_text(out / CERTIFICATE, json.dumps(cert, indent=1) + "\n")
    seal(out, key)
    print(summary)
    print(f"certificate: {out / CERTIFICATE}  report: {out / 'index.html'}  ({time.perf_counter() - t0:.1f} s)")
    return record.exit_code


def timing_note(record: RunRecord, adapter: Adapter) -> dict[str, Any]:
    """What the FAP stage could not say about timing: for ``.fap`` output, the cases whose plane
    times (time codes, rate changes) the text cannot carry."""
    if adapter.faps_format != "fap" or "faps" not in adapter.outputs:
        return {"verified": True, "cases_not_verified": []}
    cases = [
        r.case_id
        for r in record.results
        if any(st.stage == "faps" and st.metrics.get("times_unverified", 0) > 0 for st in r.stages)
    ]
    return {"verified": False, "cases_not_verified": cases}


def claim_basis(record: RunRecord, cases: list[Case], claim: str) -> dict[str, Any]:
    """What a verdict rests on: the tools the claim needs, the coverage points exercised by the
    cases that passed (of those the claim's cases exercise), and the required cases the decoder
    could not take."""
    ps = load_profiles()
    c = Claim.parse(claim, ps)
    ok = {r.case_id for r in record.results if r.outcome.ok}
    exercised, possible = set(), set()
    for case in cases:
        pts = points_of(case)  # stored with the suites when the case is as committed, else computed
        possible |= pts
        if case.full_id in ok:
            exercised |= pts
    return {
        "tools": sorted(ps.profiles[c.profile].tools),
        "coverage_points_exercised": len(exercised),
        "coverage_points_of_claim": len(possible),
        "not_exercised": sorted(possible - exercised),
        "cases_not_taken": list(record.missing),
    }


def _statement(record: RunRecord, cv: ClaimVerdict, speed: bool, basis: dict[str, Any]) -> str:
    c = record.counts()
    lines = [
        f"# fbaconf certification: {record.decoder['name']} — {record.claim}",
        "",
        f"**Verdict: {cv.verdict}**",
        "",
        f"- decoder manifest sha256: `{record.decoder.get('manifest_sha256')}`",
        f"- cases run: {len(record.results)} (" + ", ".join(f"{k} {v}" for k, v in c.items() if v) + ")",
        "- suites: " + ", ".join(f"{s['name']} {s['version']}" for s in record.suites),
        f"- issued: {record.finished}",
        "",
    ]
    if speed:
        lines.append("## Speed")
        for s in record.speed:
            word = {"pass": "pass", "inconclusive": "INCONCLUSIVE"}.get(s.verdict, "FAIL")
            lines.append(
                f"- {s.operation}: {s.rate_fps:.1f} frames/s measured, {s.required_fps:g} required "
                f"({s.provenance}) — {word}" + (f": {s.reason}" if s.reason else "")
            )
    else:
        lines.append("Speed was not measured (--no-speed): this certificate does not cover the level's minimum rates.")
    lines += [
        "",
        "## What this verdict rests on",
        "",
        f"- isolation of the decoder: {basis.get('isolation', 'unknown')}",
        "- limits in force: " + ("; ".join(basis.get("limits") or []) or "none (in-process)"),
        "- suites and goldens: "
        + (
            "UNOFFICIAL: " + "; ".join(basis["unofficial"])
            if basis.get("unofficial")
            else "the ones this fbaconf ships"
        ),
        "- read-only folders the lab added (--sandbox-ro): " + (", ".join(basis.get("sandbox_ro") or []) or "none"),
        f"- tools the claim requires: {', '.join(basis['tools'])}",
        f"- coverage points exercised by passing cases: {basis['coverage_points_exercised']} of the "
        f"{basis['coverage_points_of_claim']} the claim's cases exercise",
    ]
    if basis["not_exercised"]:
        lines.append(
            f"- not exercised (their cases did not pass): {', '.join(basis['not_exercised'][:40])}"
            + (" …" if len(basis["not_exercised"]) > 40 else "")
        )
    if basis["cases_not_taken"]:
        lines += [
            "- required cases the decoder could not take (each fails the claim, unless its tool is named "
            "unverified below):"
        ]
        lines += [f"  - {m}" for m in basis["cases_not_taken"]]
    else:
        lines.append("- the decoder took every required case")
    lines += _timing_lines(basis.get("timing") or {})
    lines += _provisional_lines(record, cv)
    lines += [
        "",
        "## Provisional rules and limits",
        "",
        "The ISO/IEC 14496 text was not available to fbaconf. This verdict rests on these provisional "
        "decisions and limits:",
        "",
    ]
    lines += [f"- {p}" for p in record.provisional]
    return "\n".join(lines) + "\n"


TOP_CAUSES = 3


def _cause_lines(record: RunRecord, cases: list[Case], verdict: str) -> str:
    """On FAIL, the top causes the spectrum ranks (no decoder is run for them here: ``fbaconf
    explain`` on the package confirms each with a variant)."""
    if not verdict.startswith("FAIL"):
        return ""
    ex = explain(record, {c.full_id: c for c in cases}, why_not="the certificate runs no extra decoder")
    if not ex.failing:
        return ""
    lines = ["", "## Why it fails (top causes, ranked)", "", f"{ex.headline()}; the first {TOP_CAUSES}:", ""]
    for c in ex.causes[:TOP_CAUSES]:
        n = len(c.cases)
        lines.append(
            f"- {c.what} (`{c.feature}`): {n} case{'s' * (n != 1)}, e.g. {', '.join(c.cases[:3])}"
            + (f"; concerns {c.concerns}" if c.concerns else "")
        )
    lines += ["", "Not confirmed by a decoder run here: `fbaconf explain PACKAGE` confirms each cause with a variant."]
    return "\n".join(lines) + "\n"


def _timing_lines(timing: dict[str, Any]) -> list[str]:
    if timing.get("verified", True):
        return []
    cases = timing.get("cases_not_verified") or []
    out = [
        "",
        "## Timing",
        "",
        "- timing not verified (.fap output): a .fap file carries frame numbers (with the skips, checked) and one "
        'header rate (checked), not plane times. Write .npz output (faps_format = "npz") to have plane times '
        "verified.",
    ]
    if cases:
        out.append(
            f"- {len(cases)} case(s) whose plane times .fap cannot carry (time codes, rate changes): "
            + ", ".join(cases)
        )
    return out


def _provisional_lines(record: RunRecord, cv: ClaimVerdict) -> list[str]:
    declared = list(record.decoder.get("readings") or [])
    out = [
        "",
        "## Tools and provisional decisions",
        "",
        "Per tool and per decision: verified, differs (judged by a reading the decoder declared), declined, "
        'unverified, or fails (docs/harness.md, "Provisional requirements"). A difference counts as '
        "provisional only where the decoder declared the other reading and its result is that reading's, value "
        "for value; a tool whose every case rests on an open decision (D8) and that the decoder does not decode "
        "as fbaconf does is named unverified. --strict fails both"
        + (" (this certificate was made with --strict)." if record.strict else "."),
        "",
        f"- other readings the decoder declares: {', '.join(declared) if declared else 'none'}",
    ]
    out += [f"- {line}" for line in describe(cv.to_json())]
    if cv.differences:
        out += ["", f"Provisional differences ({len(cv.differences)}):"]
        out += [
            f"- {d['case_id']} (rests on {', '.join(d['rests_on'])}; judged by the declared reading {d['reading']})"
            for d in cv.differences
        ]
    return out


def verify_package(pkg: Path, pubkey: Path | None = None) -> list[str]:
    """Every problem of a package (:func:`.package.verify`)."""
    return verify(pkg, pubkey).problems


def prepare_output(out: Path, force: bool) -> None:
    """``certify -o``: an absent or empty folder, or — with ``force`` — an fbaconf package to
    replace. Anything else of the user's is left alone (exit 2)."""
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise UsageError(f"-o {out}: exists and is not a folder")
    if not out.exists() or not any(out.iterdir()):
        out.mkdir(parents=True, exist_ok=True)
        return
    try:
        is_pkg = str(json.loads(read_regular(out / CERTIFICATE, 1 << 20)).get("format")).startswith(
            "fbaconf.certificate/"
        )
    except (FbaconfInputError, ValueError, AttributeError, RecursionError):
        is_pkg = False
    if not is_pkg:
        raise UsageError(
            f"-o {out}: the folder is not empty and is not an fbaconf certification package; "
            f"give an empty or new folder"
        )
    if not force:
        raise UsageError(f"-o {out}: holds a certification package already; give --force to replace it")
    remove_tree(out)
    out.mkdir(parents=True)
