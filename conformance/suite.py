"""Suite and case model: what a conformance case is, and where its files live.

A suite is a folder ``conformance/suites/<name>/`` holding ``suite.json`` and the case
input files (streams ``.fba``, FAP text ``.fap``, scenes ``.bt``/``.bifs``, scenarios
``.toml``). Goldens live in ``golden/<suite>/<case>/`` (written only by
``fbaconf golden regenerate``). Every file a case names carries its sha256, so a run can
prove it used exactly the suite version it reports.

A case::

    {"id": "simple-core-arith-q8", "claim": "simple@1", "group": "core",
     "kind": "decode" | "error" | "multi",
     "description": "...", "tools": ["arithmetic"], "covers": ["quant:8", ...],
     "inputs": {"fba": "x.fba", "fap": "x.fap", "scene": "x.bt", "bifs": "x.bifs",
                "scenario": "x.toml", "faces": ["a.fba", "b.fba"]},
     "sha256": {"x.fba": "..."},
     "frames": 30,
     "stages": ["faps", "vertices", "images"],        # what the goldens cover
     "goldens": {"faps": "faps.npz", "vertices": "vertices.npz", "images": ["frame_00000.png", ...],
                 "faces": ["face0.npz", ...]},      # paths relative to golden/<suite>/<case>/
     "tolerances": {"vertices": {...}, "images": {...}},
     "expect": {"diagnostics": ["FAP-SYNTAX-003"]}} # error cases: what the checker must say

``claim`` is the lowest profile@level whose certification requires the case: a decoder
claiming P@L runs every case whose claim is P'@L' with P' included in P and L' <= L.

A manifest is read defensively (a suite folder can come from anywhere: ``FBACONF_SUITES``):
a regular file of at most :data:`MAX_MANIFEST_BYTES`, JSON nested at most :data:`MAX_DEPTH`
deep, every field of the kind the schema above gives it, every claim a known profile@level —
anything else is one :class:`SuiteError` naming the file, the case and the field, never a
traceback later in a run.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

from fbaconf.errors import FbaconfInputError
from fbaconf.profiles.model import Claim, load_profiles
from fbaconf.safefs import confined, read_regular, safe_name

SUITE_FORMAT = "fbaconf.suite/1"
MAX_MANIFEST_BYTES = 64 << 20
MAX_DEPTH = 32


class CaseKind(StrEnum):
    """What a case asks of a decoder: decode a valid stream, reject an invalid one, or decode
    several faces at once."""

    DECODE = "decode"
    ERROR = "error"
    MULTI = "multi"


KINDS = tuple(k.value for k in CaseKind)
STAGES = ("faps", "vertices", "images")
INPUT_KEYS = ("fba", "fap", "scene", "bifs", "scenario", "faces")


class SuiteError(FbaconfInputError):
    """A suite manifest or one of its files is missing, malformed or does not match its digest."""


def _quote(v, n: int = 60) -> str:
    text = repr(v)
    return text if len(text) <= n else text[:n] + "…"


_STR_LISTS = ("tools", "covers", "stages")
_TABLES = ("goldens", "tolerances", "expect")


def check_claim(claim, where: str) -> str:
    """``claim`` if it is a known profile@level, else SuiteError naming ``where``."""
    try:
        Claim.parse(claim, load_profiles())
    except ValueError as e:
        raise SuiteError(f"{where}: claim {_quote(claim)}: {e}", rule="suite-case") from None
    return claim


def _check_case(d: dict, suite: str) -> None:
    """Every field of case ``d`` of the kind the schema gives it (module doc)."""
    where = f"suite {suite}: case {_quote(d.get('id'))}"

    def bad(what: str) -> SuiteError:
        return SuiteError(f"{where}: {what}", rule="suite-case")

    for k in ("id", "claim", "group", "kind", "description"):
        if k in d and not isinstance(d[k], str):
            raise bad(f"{k} must be a string, not {type(d[k]).__name__}")
    for k in _STR_LISTS:
        if k in d and (not isinstance(d[k], list) or not all(isinstance(x, str) for x in d[k])):
            raise bad(f"{k} must be a list of strings, not {_quote(d[k])}")
    for k in _TABLES:
        if k in d and not isinstance(d[k], dict):
            raise bad(f"{k} must be a table, not {type(d[k]).__name__}")
    if "frames" in d and (isinstance(d["frames"], bool) or not isinstance(d["frames"], int) or d["frames"] < 0):
        raise bad(f"frames must be a whole number >= 0, not {_quote(d['frames'])}")
    inputs = d.get("inputs", {})
    if not isinstance(inputs, dict):
        raise bad(f"inputs must be a table of {', '.join(INPUT_KEYS)}, not {type(inputs).__name__}")
    for k, v in inputs.items():
        if k not in INPUT_KEYS:
            raise bad(f"inputs: unknown key {_quote(k)} (known: {', '.join(INPUT_KEYS)})")
        ok = (isinstance(v, list) and all(isinstance(x, str) for x in v)) if k == "faces" else isinstance(v, str)
        if not ok:
            raise bad(
                f"inputs.{k} must be {'a list of file names' if k == 'faces' else 'a file name'}, not {_quote(v)}"
            )
    sha = d.get("sha256", {})
    if not isinstance(sha, dict) or not all(
        isinstance(k, str) and isinstance(v, str) and len(v) == 64 and all(c in "0123456789abcdef" for c in v)
        for k, v in sha.items()
    ):
        raise bad("sha256 must be a table of file name = 64 lowercase hex digits")
    if "claim" not in d or "id" not in d:
        raise bad("a case needs an id and a claim")
    check_claim(d["claim"], where)


def package_root() -> Path:
    return Path(__file__).resolve().parent


def suites_root() -> Path:
    """Where suites are built and read: ``FBACONF_SUITES`` or ``conformance/suites``."""
    env = os.environ.get("FBACONF_SUITES")
    return Path(env) if env else package_root() / "suites"


def golden_root() -> Path:
    """Where goldens live: ``FBACONF_GOLDEN`` or the repository's ``golden/`` folder."""
    env = os.environ.get("FBACONF_GOLDEN")
    return Path(env) if env else package_root().parent / "golden"


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def digest_problems(root: Path, listed: dict[str, str], *, ignore=lambda rel: False) -> tuple[list, list, list]:
    """Check files under ``root`` against ``listed`` (relative posix path -> sha256):
    returns (missing, modified, extra) relative paths; ``ignore(rel)`` skips files on disk."""
    missing, modified = [], []
    for rel, digest in listed.items():
        p = root / rel
        if not p.is_file():
            missing.append(rel)
        elif sha256_file(p) != digest:
            modified.append(rel)
    on_disk = {p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file()}
    extra = sorted(rel for rel in on_disk - set(listed) if not ignore(rel))
    return missing, modified, extra


@dataclass
class Case:
    id: str
    suite: str
    claim: str
    group: str = "core"
    kind: CaseKind = CaseKind.DECODE
    description: str = ""
    tools: list[str] = field(default_factory=list)
    covers: list[str] = field(default_factory=list)
    inputs: dict[str, Any] = field(default_factory=dict)
    sha256: dict[str, str] = field(default_factory=dict)
    frames: int = 0
    stages: list[str] = field(default_factory=list)
    goldens: dict[str, Any] = field(default_factory=dict)
    tolerances: dict[str, dict] = field(default_factory=dict)
    expect: dict[str, Any] = field(default_factory=dict)
    suite_dir: Path | None = None

    @property
    def full_id(self) -> str:
        return f"{self.suite}/{self.id}"

    def input_path(self, key: str) -> Path | None:
        v = self.inputs.get(key)
        if v is None or self.suite_dir is None:
            return None
        return self.suite_dir / v

    def face_paths(self) -> list[Path]:
        return [self.suite_dir / p for p in self.inputs.get("faces", [])] if self.suite_dir else []

    def golden_dir(self, root: Path | None = None) -> Path:
        return (root or golden_root()) / self.suite / self.id

    def to_json(self) -> dict:
        d = {
            k: getattr(self, k)
            for k in (
                "id",
                "claim",
                "group",
                "kind",
                "description",
                "tools",
                "covers",
                "inputs",
                "sha256",
                "frames",
                "stages",
                "goldens",
                "tolerances",
                "expect",
            )
        }
        return d

    @classmethod
    def from_json(cls, d: dict, suite: str, suite_dir: Path | None) -> Case:
        _check_case(d, suite)
        try:
            c = cls(
                suite=suite,
                suite_dir=suite_dir,
                **{k: d[k] for k in d if k in cls.__dataclass_fields__ and k not in ("suite", "suite_dir")},
            )
        except TypeError as e:
            raise SuiteError(f"suite {suite}: malformed case {d.get('id')!r}: {e}", rule="suite-case") from None
        safe_name(str(c.id), what=f"suite {suite}: case id")
        files = [v for k, v in c.inputs.items() if k != "faces"] + list(c.inputs.get("faces", [])) + list(c.sha256)
        for rel in files:  # every file a case names stays inside its suite folder
            confined(suite_dir or Path("."), str(rel), what=f"suite {suite}: case {c.id}: file")
        if c.kind not in KINDS:
            raise SuiteError(f"suite {suite}: case {c.id}: kind {c.kind!r} not one of {KINDS}", rule="suite-case")
        c.kind = CaseKind(c.kind)
        bad = [s for s in c.stages if s not in STAGES]
        if bad:
            raise SuiteError(f"suite {suite}: case {c.id}: unknown stage(s) {bad}", rule="suite-case")
        return c


@dataclass
class Suite:
    name: str
    description: str
    claim: str  # the profile@level group this suite belongs to
    group: str
    version: str
    cases: list[Case]
    path: Path | None = None

    def to_json(self) -> dict:
        return {
            "format": SUITE_FORMAT,
            "name": self.name,
            "description": self.description,
            "claim": self.claim,
            "group": self.group,
            "version": self.version,
            "cases": [c.to_json() for c in self.cases],
        }

    def manifest_path(self) -> Path:
        if self.path is None:
            raise ValueError(f"suite {self.name} was not loaded from a folder")
        return self.path / "suite.json"

    def digest(self) -> str:
        return sha256_file(self.manifest_path())

    @classmethod
    def load(cls, directory: Path) -> Suite:
        directory = Path(directory)
        mf = directory / "suite.json"
        if not mf.exists() and not mf.is_symlink():
            raise SuiteError(f"no suite manifest: {mf}", rule="suite-missing", file=str(mf))
        try:  # a regular file (never a FIFO that blocks, a link elsewhere, a device that streams)
            d = json.loads(read_regular(mf, MAX_MANIFEST_BYTES).decode("utf-8"))
        except FbaconfInputError as e:
            raise SuiteError(f"unreadable suite manifest: {e.message}", rule="suite-manifest", file=str(mf)) from None
        except (ValueError, RecursionError) as e:  # not UTF-8, not JSON, nested past the parser's depth
            raise SuiteError(
                f"unreadable suite manifest: {str(e)[:200] or type(e).__name__}", rule="suite-manifest", file=str(mf)
            ) from None
        if not isinstance(d, dict) or d.get("format") != SUITE_FORMAT:
            raise SuiteError(f"not an {SUITE_FORMAT} manifest", rule="suite-manifest", file=str(mf))
        if _depth(d) > MAX_DEPTH:
            raise SuiteError(f"malformed manifest: nested deeper than {MAX_DEPTH}", rule="suite-manifest", file=str(mf))
        try:
            name = safe_name(d["name"], what="suite name")
            claim, cases = d["claim"], d["cases"]
            if not isinstance(claim, str) or not isinstance(cases, list) or not all(isinstance(c, dict) for c in cases):
                raise TypeError("claim must be a string and cases a list of objects")
            check_claim(claim, f"suite {name}")
            suite = cls(
                name=name,
                description=str(d.get("description", "")),
                claim=claim,
                group=str(d.get("group", "")),
                version=str(d.get("version", "")),
                path=directory,
                cases=[Case.from_json(c, name, directory) for c in cases],
            )
        except KeyError as e:
            raise SuiteError(f"manifest lacks {e.args[0]!r}", rule="suite-manifest", file=str(mf)) from None
        except (TypeError, FbaconfInputError) as e:
            raise SuiteError(
                f"malformed manifest: {getattr(e, 'message', e)}", rule="suite-manifest", file=str(mf)
            ) from None
        return suite

    def verify_inputs(self) -> list[str]:
        """Problems with the suite's input files (missing, digest mismatch); empty when sound."""
        problems = []
        for c in self.cases:
            for rel, digest in c.sha256.items():
                p = self.path / rel
                if not p.is_file():
                    problems.append(f"{c.full_id}: missing {rel}")
                elif sha256_file(p) != digest:
                    problems.append(f"{c.full_id}: {rel} does not match its sha256")
        return problems


def _depth(obj) -> int:
    """How deep ``obj`` (parsed JSON) nests, without recursion."""
    deepest, todo = 0, [(obj, 1)]
    while todo:
        o, k = todo.pop()
        deepest = max(deepest, k)
        if deepest > MAX_DEPTH:
            return deepest
        if isinstance(o, dict):
            todo += [(v, k + 1) for v in o.values()]
        elif isinstance(o, list):
            todo += [(v, k + 1) for v in o]
    return deepest


def load_suites(root: Path | None = None, names: list[str] | None = None) -> list[Suite]:
    root = root or suites_root()
    if not root.is_dir():
        raise SuiteError(f"no suites at {root}: run `fbaconf suites build` first", rule="suite-missing", file=str(root))
    suites = [Suite.load(p) for p in sorted(root.iterdir()) if (p / "suite.json").is_file()]
    if names:
        known = {s.name for s in suites}
        missing = [n for n in names if n not in known]
        if missing:
            raise SuiteError(
                f"unknown suite(s): {', '.join(missing)} (known: {', '.join(sorted(known))})", rule="suite-missing"
            )
        suites = [s for s in suites if s.name in names]
    return suites
