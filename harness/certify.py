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

import base64
import hashlib
import json
import os
import re
import shutil
import sys
import time
from pathlib import Path

from fbaconf._atomic import atomic_write_text
from fbaconf.conformance.coverage import case_points
from fbaconf.conformance.golden import MANIFEST
from fbaconf.conformance.suite import golden_root, load_suites, sha256_file
from fbaconf.errors import FbaconfInputError
from fbaconf.isolation import sandbox
from fbaconf.profiles.model import Claim, load_profiles
from fbaconf.safefs import confined, read_regular, remove_tree

from . import reports
from .adapters import CommandAdapter, resolve
from .selection import claim_covers, select_cases
from .session import RunOptions, UsageError, execute, preflight, resolve_claim, write_reports

CERTIFICATE = "certificate.json"
SUMS = "SHA256SUMS"
FORMAT = "fbaconf.certificate/1"


def certify(decoder: str, claim: str | None, out: Path, *, jobs=None, speed: bool = True, key: Path | None = None,  # noqa: PLR0913
            force: bool = False, allow_unisolated: bool = False, cluster: str | None = None) -> int:
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
    isolated = sandbox.isolation() != "none" or not isinstance(adapter, CommandAdapter)
    if not isolated and not allow_unisolated:
        print("fbaconf certify: error: bubblewrap (bwrap) is not available, so the decoder would run unisolated "
              "(it could read the goldens); install it (Debian: apt-get install bubblewrap) or give "
              "--allow-unisolated (the statement then says so)", file=sys.stderr)
        return 2
    if key is not None:
        _load_key(Path(key), private=True)  # a bad key is a set-up error before anything runs
    suites = load_suites()
    cases = select_cases(suites, claim, [], [], only_required=True, adapter=adapter)
    out = Path(out).resolve()
    prepare_output(out, force)
    record = execute(adapter, claim, cases, suites, out, RunOptions(jobs=jobs, speed=speed, cluster=cluster))
    write_reports(record, out)
    if record.exit_code >= 128:
        print(f"fbaconf certify: interrupted: no certificate written; partial report in {out}", file=sys.stderr)
        return record.exit_code
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
    basis["isolation"] = ("bubblewrap sandbox" if sandbox.isolation() == "bwrap" and isinstance(adapter, CommandAdapter)
                          else "in-process (trusted Python adapter)" if not isinstance(adapter, CommandAdapter)
                          else "NONE: the decoder ran unisolated (--allow-unisolated)")
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
    if key is not None:
        sign_package(out, key)
    print(summary)
    print(f"certificate: {out / CERTIFICATE}  report: {out / 'index.html'}  ({time.perf_counter() - t0:.1f} s)")
    return record.exit_code


def _covers(claimed: str, claim: str) -> bool:
    return claim_covers(claimed, claim)


def claim_basis(record, cases, claim: str) -> dict:
    """What a verdict rests on: the tools the claim needs, the coverage points exercised by the
    cases that passed (of those the claim's cases exercise), and the required cases the decoder
    could not take."""
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
              f"- isolation of the decoder: {basis.get('isolation', 'unknown')}",
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


# ------------------------------------------------------------------ signatures
SIGNATURE = "SIGNATURE"
KEY_FILE, PUB_FILE = "fbaconf-signing.key", "fbaconf-signing.pub"
MAX_PACKAGE_FILE = 256 * 2**20


class SignatureError(FbaconfInputError):
    rule = "certificate-key"


def keygen(out_dir: Path) -> tuple[Path, Path]:
    """A new Ed25519 key pair: ``fbaconf-signing.key`` (PEM, PKCS#8, mode 0600) and
    ``fbaconf-signing.pub`` (PEM) in ``out_dir``; never overwrites an existing key."""
    from cryptography.hazmat.primitives import serialization  # noqa: PLC0415 (signing only)
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey  # noqa: PLC0415 (signing only)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    key_path, pub_path = out_dir / KEY_FILE, out_dir / PUB_FILE
    if key_path.exists() or pub_path.exists():
        raise SignatureError(f"{key_path} or {pub_path} exists already: not overwriting a key", file=str(out_dir))
    key = Ed25519PrivateKey.generate()
    pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                            serialization.NoEncryption())
    fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(pem)
    pub_path.write_bytes(key.public_key().public_bytes(serialization.Encoding.PEM,
                                                       serialization.PublicFormat.SubjectPublicKeyInfo))
    return key_path, pub_path


def _load_key(path: Path, private: bool):
    from cryptography.hazmat.primitives import serialization  # noqa: PLC0415 (signing only)
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey  # noqa: PLC0415 (signing only)
    try:
        data = read_regular(path, 64 * 1024)
        key = (serialization.load_pem_private_key(data, password=None) if private
               else serialization.load_pem_public_key(data))
    except (FbaconfInputError, ValueError, TypeError) as e:
        raise SignatureError(f"not a PEM {'private' if private else 'public'} key: {e}", file=str(path)) from None
    want = Ed25519PrivateKey if private else Ed25519PublicKey
    if not isinstance(key, want):
        raise SignatureError("not an Ed25519 key (make one with `fbaconf certify keygen`)", file=str(path))
    return key


def sign_package(pkg: Path, key_path: Path) -> None:
    """Sign the certificate (which pins SHA256SUMS, which pins every file): ``SIGNATURE``
    holds the base64 Ed25519 signature of ``certificate.json``'s bytes."""
    key = _load_key(Path(key_path), private=True)
    sig = key.sign((Path(pkg) / CERTIFICATE).read_bytes())
    atomic_write_text(Path(pkg) / SIGNATURE, base64.b64encode(sig).decode("ascii") + "\n")


def _check_signature(pkg: Path, pubkey: Path | None) -> tuple[str, list[str]]:
    """("signed", []) / ("unsigned", []) / ("signature not checked", []) or problems."""
    from cryptography.exceptions import InvalidSignature  # noqa: PLC0415 (signing only)
    sig_path = pkg / SIGNATURE
    if not sig_path.exists() and not sig_path.is_symlink():
        return "unsigned", ([f"no {SIGNATURE}: the package is unsigned"] if pubkey is not None else [])
    if pubkey is None:
        return "signature not checked (give --pubkey)", []
    key = _load_key(Path(pubkey), private=False)
    try:
        sig = base64.b64decode(read_regular(sig_path, 4096).strip(), validate=True)
        key.verify(sig, read_regular(pkg / CERTIFICATE, MAX_PACKAGE_FILE))
    except (InvalidSignature, ValueError, FbaconfInputError):
        return "signature INVALID", [f"{SIGNATURE} does not verify with {pubkey}: the certificate was changed or "
                                     f"signed with another key"]
    return "signed", []


def prepare_output(out: Path, force: bool) -> None:
    """``certify -o``: an absent or empty folder, or — with ``force`` — an fbaconf package to
    replace. Anything else of the user's is left alone (exit 2)."""
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise UsageError(f"-o {out}: exists and is not a folder")
    if not out.exists() or not any(out.iterdir()):
        out.mkdir(parents=True, exist_ok=True)
        return
    try:
        is_pkg = json.loads(read_regular(out / CERTIFICATE, 1 << 20)).get("format") == FORMAT
    except (FbaconfInputError, ValueError, AttributeError):
        is_pkg = False
    if not is_pkg:
        raise UsageError(f"-o {out}: the folder is not empty and is not an fbaconf certification package; "
                         f"give an empty or new folder")
    if not force:
        raise UsageError(f"-o {out}: holds a certification package already; give --force to replace it")
    remove_tree(out)
    out.mkdir(parents=True)


_SUMS_LINE = re.compile(r"([0-9a-f]{64})  (\S(?:.*\S)?)")


def verify_package(pkg: Path, pubkey: Path | None = None) -> list[str]:
    """Every problem of a package (digests, files, and the signature when ``pubkey`` is given)."""
    return verify(pkg, pubkey)[0]


def verify(pkg: Path, pubkey: Path | None = None) -> tuple[list[str], str]:
    """(problems, signature state). Reads only regular files inside the package, each capped
    in size; a SHA256SUMS entry that leaves the package, or names a link, is a problem."""
    pkg = Path(pkg)
    problems: list[str] = []
    if not pkg.is_dir() or pkg.is_symlink():
        return [f"{pkg} is not a package folder"], "unsigned"
    try:
        cert = json.loads(read_regular(pkg / CERTIFICATE, 1 << 20).decode("utf-8"))
        if not isinstance(cert, dict):
            raise ValueError("not a JSON object")
    except FbaconfInputError as e:
        return [f"{CERTIFICATE}: {e.message}"], "unsigned"
    except (UnicodeDecodeError, ValueError) as e:
        return [f"{CERTIFICATE} unreadable: {e}"], "unsigned"
    if cert.get("format") != FORMAT:
        problems.append(f"{CERTIFICATE}: unknown format {str(cert.get('format'))[:80]!r}")
    try:
        sums_bytes = read_regular(pkg / SUMS, 16 * 2**20)
    except FbaconfInputError as e:
        return problems + [f"{SUMS}: {e.message}"], "unsigned"
    if hashlib.sha256(sums_bytes).hexdigest() != cert.get("sha256sums_sha256"):
        problems.append(f"{SUMS} does not match the digest in {CERTIFICATE}")
    listed: dict[str, str] = {}
    for n, line in enumerate(sums_bytes.decode("utf-8", "replace").splitlines(), 1):
        m = _SUMS_LINE.fullmatch(line)
        if not m:
            problems.append(f"{SUMS} line {n} malformed")
            continue
        rel = m.group(2)
        try:
            confined(pkg, rel, what=f"{SUMS} line {n} entry")
        except FbaconfInputError as e:
            problems.append(e.message)
            continue
        listed[rel] = m.group(1)
    for rel, digest in sorted(listed.items()):
        try:
            data = read_regular(pkg / rel, MAX_PACKAGE_FILE)
        except FbaconfInputError as e:
            problems.append(f"{rel}: {e.message}" if (pkg / rel).exists() or (pkg / rel).is_symlink()
                            else f"missing file {rel}")
            continue
        if hashlib.sha256(data).hexdigest() != digest:
            problems.append(f"{rel} was modified (sha256 mismatch)")
    for p in _walk_files(pkg):
        rel = p.relative_to(pkg).as_posix()
        if rel not in listed and rel not in (CERTIFICATE, SUMS, SIGNATURE):
            problems.append(f"file {rel} was added after signing")
    try:
        report = json.loads(read_regular(pkg / "report.json", MAX_PACKAGE_FILE).decode("utf-8"))
        if not isinstance(report, dict) or report.get("claim") != cert.get("claim") or \
                report.get("exit_code") != cert.get("exit_code"):
            problems.append("report.json disagrees with the certificate (claim or exit code)")
    except (FbaconfInputError, UnicodeDecodeError, ValueError):
        problems.append("report.json unreadable")
    state, sig_problems = _check_signature(pkg, pubkey)
    return problems + sig_problems, state


def _walk_files(root: Path):
    """Every non-directory entry below ``root`` (links included, never followed)."""
    stack = [root]
    while stack:
        d = stack.pop()
        for e in os.scandir(d):
            p = Path(e.path)
            if e.is_dir(follow_symlinks=False):
                stack.append(p)
            else:
                yield p
