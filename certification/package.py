"""Certification packages as a stranger checks them: digests, signature, and the verdict re-derived.

Written by :func:`seal` once every other file of the package is in place:

* ``SHA256SUMS`` — the sha256 of **every** file of the package (``certificate.json``,
  ``statement.md``, ``summary.txt``, ``index.html``, ``results.jsonl``, the copied suites,
  artefacts...), ``sha256sum`` format, sorted; only ``SHA256SUMS`` and ``SIGNATURE`` are not
  in it;
* ``SIGNATURE`` (with ``certify --key``) — the base64 Ed25519 signature of the bytes of
  ``SHA256SUMS``: the digest list, hence every byte of the package.

:func:`verify` reads each file **once**, into memory, and checks and uses those same bytes
(no file is opened twice, so swapping one while it runs changes nothing). It fails — naming
the file — on a changed, missing, added or uncovered file, a bad signature, and a
``certificate.json`` whose verdict, exit code, counts, claim or provisional differences
disagree with what ``results.jsonl``, ``report.json`` and the claim rules (the cases the
claim requires, from the packaged suites) give.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import re
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any, Literal, overload

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from fbaconf._atomic import atomic_write_text
from fbaconf.bitstreams import readings
from fbaconf.conformance import official
from fbaconf.conformance.provisional import rests_on
from fbaconf.conformance.suite import Case, load_suites
from fbaconf.errors import FbaconfInputError
from fbaconf.harness.selection import required_for
from fbaconf.harness.verdict import ClaimVerdict, claim_verdict
from fbaconf.safefs import confined, read_regular

CERTIFICATE = "certificate.json"
SUMS = "SHA256SUMS"
SIGNATURE = "SIGNATURE"
FORMAT = "fbaconf.certificate/2"
KEY_FILE, PUB_FILE = "fbaconf-signing.key", "fbaconf-signing.pub"
MAX_PACKAGE_FILE = 256 * 2**20
MAX_PACKAGE_BYTES = 1 << 30
MAX_PACKAGE_FILES = 20_000
MAX_JSON_DEPTH = 64
QUOTE_CHARS = 80


class Signature(StrEnum):
    """What a package's signature vouches for, in the words ``certify verify`` prints."""

    UNSIGNED = "unsigned: anyone could have written this"
    NOT_CHECKED = "signed, but the signature was not checked"
    INVALID = "signature INVALID"
    SIGNED = "signed, signature checked"


_SUMS_LINE = re.compile(r"([0-9a-f]{64})  (\S(?:.*\S)?)")


class SignatureError(FbaconfInputError):
    rule = "certificate-key"


# ------------------------------------------------------------------ keys
def keygen(out_dir: Path) -> tuple[Path, Path]:
    """A new Ed25519 key pair: ``fbaconf-signing.key`` (PEM, PKCS#8, mode 0600) and
    ``fbaconf-signing.pub`` (PEM) in ``out_dir``; never overwrites an existing key."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    key_path, pub_path = out_dir / KEY_FILE, out_dir / PUB_FILE
    if key_path.exists() or pub_path.exists():
        raise SignatureError(f"{key_path} or {pub_path} exists already: not overwriting a key", file=str(out_dir))
    key = Ed25519PrivateKey.generate()
    pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())
    fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(pem)
    pub_path.write_bytes(
        key.public_key().public_bytes(serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo)
    )
    return key_path, pub_path


@overload
def load_key(path: Path, private: Literal[True]) -> Ed25519PrivateKey: ...
@overload
def load_key(path: Path, private: Literal[False]) -> Ed25519PublicKey: ...
def load_key(path: Path, private: bool) -> Ed25519PrivateKey | Ed25519PublicKey:
    """An Ed25519 key read (once) from a PEM file; :class:`SignatureError` for anything else.
    ``certify --key`` reads its key with this before any decoder starts."""
    try:
        data = read_regular(path, 64 * 1024)
        key = (
            serialization.load_pem_private_key(data, password=None)
            if private
            else serialization.load_pem_public_key(data)
        )
    except (FbaconfInputError, ValueError, TypeError) as e:
        why = e.message if isinstance(e, FbaconfInputError) else str(e)[:QUOTE_CHARS]
        raise SignatureError(f"not a PEM {'private' if private else 'public'} key: {why}", file=str(path)) from None
    if not isinstance(key, Ed25519PrivateKey if private else Ed25519PublicKey):
        raise SignatureError("not an Ed25519 key (make one with `fbaconf certify keygen`)", file=str(path))
    return key


# ------------------------------------------------------------------ writing
def seal(pkg: Path, key: Ed25519PrivateKey | None = None) -> bytes:
    """Write ``SHA256SUMS`` over every file of ``pkg`` (``certificate.json`` included) and,
    given a loaded private ``key``, ``SIGNATURE`` over those bytes. Returns the digest list."""
    pkg = Path(pkg)
    lines = []
    for p in sorted(_walk_files(pkg), key=lambda q: q.relative_to(pkg).as_posix()):
        rel = p.relative_to(pkg).as_posix()
        if rel in (SUMS, SIGNATURE):
            continue
        lines.append(f"{hashlib.sha256(read_regular(p, MAX_PACKAGE_FILE)).hexdigest()}  {rel}")
    sums = ("\n".join(lines) + "\n").encode("utf-8")
    atomic_write_text(pkg / SUMS, sums.decode("utf-8"))
    if key is not None:
        atomic_write_text(pkg / SIGNATURE, base64.b64encode(key.sign(sums)).decode("ascii") + "\n")
    return sums


# ------------------------------------------------------------------ the verdict, from the results
def derive_verdict(
    results: list[dict[str, Any]],
    *,
    strict: bool,
    speed: list[dict[str, Any]] | None,
    declared: list[str] | tuple[str, ...] = (),
) -> ClaimVerdict:
    """A claim's verdict from its required cases' result lines, the speed results (None: not
    measured) and the decoder's declared other readings (:mod:`fbaconf.harness.verdict`): the
    one rule ``certify`` writes and ``verify`` re-derives."""
    return claim_verdict(results, strict=strict, speed=speed, declared=declared)


def counts(results: list[dict[str, Any]]) -> dict[str, int]:
    out: dict[str, int] = {}
    for r in results:
        out[str(r.get("outcome"))] = out.get(str(r.get("outcome")), 0) + 1
    return out


# ------------------------------------------------------------------ verifying
@dataclass
class Verification:
    problems: list[str] = field(default_factory=list)
    state: Signature = Signature.UNSIGNED
    certificate: dict[str, Any] = field(default_factory=dict)  # JSON, read from the package
    # what of the package's suites and goldens is not this fbaconf's (conformance/official.py)
    unofficial: list[str] = field(default_factory=list)

    @property
    def isolated(self) -> bool:
        """Whether the certificate says the decoder ran isolated (an in-process bundled adapter counts)."""
        return self.certificate.get("isolated") is not False

    @property
    def authentic(self) -> bool:
        return self.state == Signature.SIGNED


def _quote(text: object) -> str:
    s = repr(text)
    return s if len(s) <= QUOTE_CHARS else s[:QUOTE_CHARS] + "…"


def _json(data: bytes, what: str) -> Any:  # JSON: its callers check its shape
    """Parsed JSON (at most MAX_JSON_DEPTH deep); FbaconfInputError naming ``what`` otherwise."""
    try:
        value = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as e:
        raise FbaconfInputError(f"not JSON: {_quote(str(e))}", rule="certificate-json", file=what) from None
    except RecursionError:
        raise FbaconfInputError(f"nested more than {MAX_JSON_DEPTH} deep", rule="certificate-json", file=what) from None
    if _depth(value) > MAX_JSON_DEPTH:
        raise FbaconfInputError(f"nested more than {MAX_JSON_DEPTH} deep", rule="certificate-json", file=what)
    return value


def _depth(value: object) -> int:
    """How deep ``value``'s containers nest (0 for a scalar), counted a level at a time and
    stopped one level past MAX_JSON_DEPTH; only containers are visited."""
    level, deepest = ([value] if isinstance(value, (dict, list)) else []), 0
    while level and deepest <= MAX_JSON_DEPTH:
        deepest += 1
        level = [x for v in level for x in (v.values() if isinstance(v, dict) else v) if isinstance(x, (dict, list))]
    return deepest


def verify(pkg: Path, pubkey: Path | None = None) -> Verification:
    """Check a package (module doc). Never raises for the package's content."""
    pkg = Path(pkg)
    v = Verification()
    if pkg.is_symlink() or not pkg.is_dir():
        v.problems.append(f"{pkg} is not a package folder")
        return v
    try:
        sums = read_regular(pkg / SUMS, 16 * 2**20)
    except FbaconfInputError as e:
        v.problems.append(f"{SUMS}: {e.message}")
        return v
    files, listed = _read_listed(pkg, sums, v.problems)
    _check_signature(pkg, sums, pubkey, v)
    if CERTIFICATE not in listed:
        v.problems.append(
            f"{CERTIFICATE}: not covered by {SUMS}" if os.path.lexists(pkg / CERTIFICATE) else f"{CERTIFICATE}: missing"
        )
    if CERTIFICATE not in files:
        return v
    try:
        cert = _json(files[CERTIFICATE], CERTIFICATE)
        if not isinstance(cert, dict):
            raise FbaconfInputError("not a JSON object", rule="certificate-json", file=CERTIFICATE)
    except FbaconfInputError as e:
        v.problems.append(f"{CERTIFICATE}: {e.message}")
        return v
    v.certificate = cert
    if cert.get("format") != FORMAT:
        v.problems.append(f"{CERTIFICATE}: unknown format {_quote(cert.get('format'))} (this fbaconf writes {FORMAT})")
        return v
    if not v.problems:  # re-derived from files whose digests hold (a changed file is named already)
        _check_verdict(files, cert, v.problems)
        named = cert.get("suites")
        suites = [s for s in named if isinstance(s, dict)] if isinstance(named, list) else []
        v.unofficial = official.differences(suites, files.get("golden-MANIFEST.json"))
    return v


def _read_listed(pkg: Path, sums: bytes, problems: list[str]) -> tuple[dict[str, bytes], set[str]]:
    """(the bytes of every file ``SHA256SUMS`` lists that matches its digest — read once, the
    names it lists); problems for the rest and for every file it does not list."""
    listed: dict[str, str] = {}
    for n, line in enumerate(sums.decode("utf-8", "replace").splitlines(), 1):
        m = _SUMS_LINE.fullmatch(line)
        if not m:
            problems.append(f"{SUMS} line {n} malformed")
            continue
        try:
            confined(pkg, m.group(2), what=f"{SUMS} line {n} entry")
        except FbaconfInputError as e:
            problems.append(e.message)
            continue
        listed[m.group(2)] = m.group(1)
    files: dict[str, bytes] = {}
    total = 0
    for rel, digest in sorted(listed.items()):
        try:
            data = read_regular(pkg / rel, MAX_PACKAGE_FILE)
        except FbaconfInputError as e:
            problems.append(f"{rel}: {e.message}" if os.path.lexists(pkg / rel) else f"{rel}: missing")
            continue
        total += len(data)
        if total > MAX_PACKAGE_BYTES:
            problems.append(f"{rel}: the package is over {MAX_PACKAGE_BYTES} bytes")
            break
        if hashlib.sha256(data).hexdigest() != digest:
            problems.append(f"{rel}: modified (sha256 mismatch)")
            continue
        files[rel] = data
    for n, p in enumerate(_walk_files(pkg)):
        if n > MAX_PACKAGE_FILES:
            problems.append(f"the package holds over {MAX_PACKAGE_FILES} files")
            break
        rel = p.relative_to(pkg).as_posix()
        if rel not in listed and rel not in (SUMS, SIGNATURE):
            problems.append(f"{_quote(rel)}: not covered by {SUMS} (added after the package was sealed)")
    return files, set(listed)


def _check_signature(pkg: Path, sums: bytes, pubkey: Path | None, v: Verification) -> None:
    sig_path = pkg / SIGNATURE
    if not os.path.lexists(sig_path):
        v.state = Signature.UNSIGNED
        if pubkey is not None:
            v.problems.append(f"{SIGNATURE}: missing — the package is unsigned, so --pubkey cannot vouch for it")
        return
    try:
        sig_text = read_regular(sig_path, 4096)
    except FbaconfInputError as e:
        v.state = Signature.INVALID
        v.problems.append(f"{SIGNATURE}: {e.message}")
        return
    if pubkey is None:
        v.state = Signature.NOT_CHECKED
        return
    key = load_key(Path(pubkey), private=False)
    try:
        key.verify(base64.b64decode(sig_text.strip(), validate=True), sums)
    except (InvalidSignature, ValueError):
        v.state = Signature.INVALID
        v.problems.append(
            f"{SIGNATURE}: does not verify {SUMS} with {pubkey}: the package was changed after "
            f"signing, or signed with another key"
        )
        return
    v.state = Signature.SIGNED


def _check_verdict(files: dict[str, bytes], cert: dict[str, Any], problems: list[str]) -> None:
    """Re-derive the verdict from results.jsonl, report.json and the claim rules."""
    claim = cert.get("claim")
    try:
        lines = files.get("results.jsonl", b"").splitlines()
        results = [_json(line, "results.jsonl") for line in lines if line.strip()]
        report = _json(files["report.json"], "report.json") if "report.json" in files else None
    except FbaconfInputError as e:
        problems.append(f"{e.file}: {e.message}")
        return
    if "results.jsonl" not in files or report is None or not isinstance(report, dict):
        problems.append("results.jsonl/report.json: missing or unusable: the verdict cannot be re-derived")
        return
    if not all(isinstance(r, dict) and isinstance(r.get("case_id"), str) for r in results):
        problems.append("results.jsonl: a line is not a case result")
        return
    required = _required_cases(files, cert, problems)
    if required is None:
        return
    by_id = {r["case_id"]: r for r in results}
    for cid in sorted(set(required) - set(by_id)):
        problems.append(f"results.jsonl: no result for {_quote(cid)}, which {claim} requires")
    for cid in sorted(set(by_id) - set(required)):
        problems.append(f"results.jsonl: {_quote(cid)} is not a case {claim} requires")
    for cid in sorted(set(required) & set(by_id)):
        if by_id[cid].get("required") is not True:
            problems.append(f"results.jsonl: {_quote(cid)} is marked not required; {claim} requires it")
    _check_rests_on(by_id, files, problems)
    _check_cases(by_id, required, problems)
    declared = _declared_readings(files, report, problems)
    speed = report.get("speed") if cert.get("speed") != "not measured" else None
    if speed is not None and not isinstance(speed, list):
        problems.append("report.json: speed is not a list")
        return
    for cid, r in sorted(by_id.items()):
        if r.get("reading") is not None and r.get("reading") not in declared:
            problems.append(
                f"results.jsonl: {_quote(cid)} was judged by the reading {_quote(r.get('reading'))}, "
                f"which the decoder does not declare"
            )
    cv = derive_verdict(list(by_id.values()), strict=bool(cert.get("strict")), speed=speed, declared=declared)
    verdict, code = cv.verdict, cv.exit_code
    for key, want in (
        ("verdict", verdict),
        ("exit_code", code),
        ("provisional_differences", cv.differences),
        ("unverified", cv.unverified),
        ("counts", counts(list(by_id.values()))),
        ("cases", len(by_id)),
    ):
        got = cert.get(key)
        if key == "counts" and isinstance(got, dict):
            got = {k: n for k, n in got.items() if n}
        if got != want:
            problems.append(f"{CERTIFICATE}: {key} is {_quote(got)}, but the results give {_quote(want)}")
    if report.get("claim") != claim or report.get("exit_code") != code:
        problems.append("report.json: disagrees with the results (claim or exit code)")
    for name, text in (("statement.md", f"**Verdict: {verdict}**"), ("summary.txt", f"result: {verdict}")):
        if text.encode("utf-8") not in files.get(name, b""):
            problems.append(f"{name}: does not state the verdict the results give ({verdict})")


def _declared_readings(files: dict[str, bytes], report: dict[str, Any], problems: list[str]) -> list[str]:
    """The other readings the decoder declared (report.json), each a listed one and each the
    packaged manifest's when the package holds it."""
    declared = (report.get("decoder") or {}).get("readings") or []
    if not isinstance(declared, list) or not all(isinstance(r, str) and r in readings.catalogue() for r in declared):
        problems.append(f"report.json: the decoder's readings {_quote(declared)} are not listed readings")
        return []
    if "decoder.toml" in files:
        try:
            manifest = tomllib.loads(files["decoder.toml"].decode("utf-8"))
        except (UnicodeDecodeError, tomllib.TOMLDecodeError):
            problems.append("decoder.toml: not TOML")
            return declared
        if list(manifest.get("readings", [])) != declared:
            problems.append(
                f"report.json: the decoder's readings {_quote(declared)} are not decoder.toml's "
                f"{_quote(manifest.get('readings', []))}"
            )
    return declared


def _check_cases(by_id: dict[str, dict[str, Any]], required: dict[str, Case], problems: list[str]) -> None:
    """What a result says of its case (kind, tools) must be the packaged suite's: the verdict
    sets a tool's cases aside by them."""
    for cid in sorted(set(by_id) & set(required)):
        r, case = by_id[cid], required[cid]
        if r.get("kind") != case.kind.value or sorted(r.get("tools") or []) != sorted(case.tools):
            problems.append(
                f"results.jsonl: {_quote(cid)} says kind {_quote(r.get('kind'))}, tools "
                f"{_quote(r.get('tools'))}; its suite says {case.kind.value}, {sorted(case.tools)}"
            )


@dataclass(frozen=True)
class _NotAPlayer:
    """What the claim rules ask of a certified decoder: it decodes the binary stream."""

    is_player: bool = False


def _required_cases(files: dict[str, bytes], cert: dict[str, Any], problems: list[str]) -> dict[str, Case] | None:
    """The cases the certificate's claim requires, by id, from the packaged suite manifests
    (each must be one the certificate names, by digest)."""
    claim = cert.get("claim")
    named = cert.get("suites")
    if not isinstance(claim, str) or not isinstance(named, list):
        problems.append(f"{CERTIFICATE}: claim or suites missing")
        return None
    out: dict[str, Case] = {}
    decoder = _NotAPlayer()  # certify refuses players
    for s in named:
        name = s.get("name") if isinstance(s, dict) else None
        rel = f"suites/{name}.json"
        data = files.get(rel) if isinstance(name, str) else None
        if data is None:
            problems.append(
                f"{rel if isinstance(name, str) else CERTIFICATE}: a suite the certificate names is not in the package"
            )
            continue
        if hashlib.sha256(data).hexdigest() != s.get("sha256"):
            problems.append(f"{rel}: not the suite the certificate names (sha256)")
        try:
            doc = _json(data, rel)
            for c in doc["cases"]:
                case = Case.from_json(c, doc["name"], None)
                if required_for(claim, case, decoder):
                    out[case.full_id] = case
        except (FbaconfInputError, KeyError, TypeError, ValueError, AttributeError) as e:
            problems.append(f"{rel}: unusable suite manifest ({type(e).__name__})")
            return None
    return out


def _check_rests_on(by_id: dict[str, dict[str, Any]], files: dict[str, bytes], problems: list[str]) -> None:
    """What a case rests on must be what this fbaconf derives from the same suite's goldens and
    tools (when the installed suite is the packaged one, by digest): the verdict sets cases aside
    and names provisional differences by it."""
    try:
        suites = load_suites()
    except FbaconfInputError:
        return
    same = {s.name for s in suites if hashlib.sha256(files.get(f"suites/{s.name}.json", b"")).hexdigest() == s.digest()}
    local = {c.full_id: c for s in suites if s.name in same for c in s.cases}
    for cid in sorted(by_id):
        case = local.get(cid)
        if case is None:
            continue
        derived = rests_on(case)
        if derived != list(by_id[cid].get("rests_on") or []):
            problems.append(
                f"results.jsonl: {_quote(cid)} rests on {derived} (from its goldens and tools), "
                f"not {_quote(by_id[cid].get('rests_on'))}"
            )


def _walk_files(root: Path) -> Iterator[Path]:
    """Every non-directory entry below ``root`` (links included, never followed)."""
    stack = [root]
    while stack:
        d = stack.pop()
        with os.scandir(d) as it:
            for e in it:
                p = Path(e.path)
                if e.is_dir(follow_symlinks=False):
                    stack.append(p)
                else:
                    yield p
