"""Fuzzing the loaders of what users hand fbaconf: decoder manifests (TOML), suite
manifests (JSON) and certification packages (a folder: ``SHA256SUMS``, ``certificate.json``,
``report.json``, ``results.jsonl``...). Each must read its input or refuse it with a typed
error (:class:`~fbaconf.errors.FbaconfInputError`); anything else escaping — a traceback — is
a finding.

Inputs are mutations of real ones: the repository's manifests, its suites' ``suite.json``
files, and a certified package (made once by ``certify --decoder reference-inprocess --claim
simple@1 --no-speed``, or given). Mutations are byte-level (flips, deletions, insertions of
interesting bytes, duplicated and spliced chunks) and structural (a parsed JSON or TOML value
replaced by one of another kind, nested deep, made huge or strange; lines of TOML dropped,
duplicated or swapped). A mutated package file gets its digest in ``SHA256SUMS`` updated half
of the time, so verification reaches the parsers behind the digests.

    python -m fbaconf.fuzz.loaders [--seconds 600] [--targets manifest,suite,package]
                                   [--package DIR] [--seed N] [--out DIR]

prints inputs/s and findings per target and writes each finding (the input and its
traceback) under ``--out``; exit 1 when a finding was made. ``tests/unit/test_loader_fuzz.py``
runs every target for a few seconds with a fixed seed.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import random
import shutil
import subprocess
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from fbaconf.certification.package import CERTIFICATE, SUMS, verify
from fbaconf.conformance.suite import Suite, suites_root
from fbaconf.errors import FbaconfInputError
from fbaconf.harness.adapters import load_manifest

ROOT = Path(__file__).resolve().parent.parent
_STRANGE = [
    None,
    True,
    0,
    -1,
    2**63,
    -(2**64),
    1e308,
    float("nan"),
    "",
    "x" * 5000,
    "\u202e\x00\udcff",
    [],
    {},
    [[[[[[[[[[[[[[[[]]]]]]]]]]]]]]]],
    {"a": {"b": {"c": {}}}},
    "../../etc/passwd",
    "simple@99",
    "{python}",
]
_BYTES = [
    b"\x00",
    b"\xff",
    b"\xef\xbb\xbf",
    b"\n",
    b"\r",
    b'"',
    b"[",
    b"]",
    b"{",
    b"}",
    b"=",
    b"#",
    b"\\",
    b"[[",
    b"\xc3",
    b"1e999",
    b"-0",
    b"inf",
    b"nan",
]


@dataclass
class Stats:
    inputs: int = 0
    findings: dict[str, tuple[bytes, str]] = field(default_factory=dict)  # signature -> (input, traceback)


# ------------------------------------------------------------------ mutators
def mutate_bytes(rng: random.Random, data: bytes, pool: list[bytes]) -> bytes:
    b = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        op = rng.randrange(6)
        at = rng.randrange(len(b) + 1)
        if op == 0 and b:
            b[min(at, len(b) - 1)] ^= 1 << rng.randrange(8)
        elif op == 1 and b:
            del b[at : at + rng.randint(1, 64)]
        elif op == 2:
            b[at:at] = rng.choice(_BYTES) * rng.choice((1, 1, 2, 100, 5000))
        elif op == 3 and b:
            n = rng.randint(1, 256)
            b[at:at] = b[at : at + n] * rng.randint(2, 8)
        elif op == 4 and pool:
            other = rng.choice(pool)
            j = rng.randrange(len(other) + 1)
            b[at:] = other[j : j + rng.randint(1, 4096)]
        else:
            b[at:at] = rng.choice(_BYTES)
    return bytes(b)


def _strange(rng: random.Random):
    v = rng.choice(_STRANGE)
    if rng.random() < 0.1:
        depth = rng.choice((40, 200, 5000))
        v = json.loads("[" * depth + "]" * depth)
    return v


def _mutate_value(rng: random.Random, v, depth: int = 0):
    """A JSON value with one of its parts replaced by a value of another kind."""
    if isinstance(v, dict) and v and depth < 8 and rng.random() < 0.8:
        k = rng.choice(list(v))
        if rng.random() < 0.15:
            return {kk: vv for kk, vv in v.items() if kk != k}  # a key dropped
        return {**v, k: _mutate_value(rng, v[k], depth + 1)}
    if isinstance(v, list) and v and depth < 8 and rng.random() < 0.8:
        i = rng.randrange(len(v))
        out = list(v)
        out[i] = _mutate_value(rng, v[i], depth + 1)
        return out
    return _strange(rng)


def mutate_json(rng: random.Random, data: bytes, pool: list[bytes]) -> bytes:
    try:
        v = json.loads(data)
    except (ValueError, RecursionError):
        return mutate_bytes(rng, data, pool)
    try:
        return json.dumps(_mutate_value(rng, v), allow_nan=True).encode("utf-8", "surrogatepass")
    except (ValueError, RecursionError):
        return mutate_bytes(rng, data, pool)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v) if v == v else "nan"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"
    return '"null"'


def mutate_toml(rng: random.Random, data: bytes, pool: list[bytes]) -> bytes:
    lines = data.split(b"\n")
    r = rng.random()
    if r < 0.3 and lines:  # a value replaced by one of another kind
        i = rng.randrange(len(lines))
        key, eq, _ = lines[i].partition(b"=")
        if eq:
            try:
                value = _toml_value(_strange(rng))
            except RecursionError:
                value = "0"
            lines[i] = key + b"= " + value.encode("utf-8", "surrogatepass")
        return b"\n".join(lines)
    if r < 0.45 and lines:  # a line dropped, duplicated or moved
        i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
        op = rng.randrange(3)
        if op == 0:
            del lines[i]
        elif op == 1:
            lines.insert(j, lines[i])
        else:
            lines[i], lines[j] = lines[j], lines[i]
        return b"\n".join(lines)
    if r < 0.55:  # a table or key that is not the schema's
        extra = rng.choice(
            [
                b'[sandbox]\nread_only = ["/"]',
                b'python = "subprocess:Popen"',
                b"[limits]\nx = 1",
                b"tools = 3",
                b"[commands]\nserve = []",
                b'serve_equivalent = "yes"',
                b"a = " + b"[" * 3000 + b"]" * 3000,
            ]
        )
        lines.insert(rng.randrange(len(lines) + 1), extra)
        return b"\n".join(lines)
    return mutate_bytes(rng, data, pool)


# ------------------------------------------------------------------ targets
class Target:
    """One loader: ``seeds`` (inputs), ``mutate`` and ``load`` (one input in a scratch folder)."""

    name = "?"

    def __init__(self, scratch: Path) -> None:
        self.scratch = scratch

    def seeds(self) -> list[bytes]:
        raise NotImplementedError

    def mutate(self, rng, data, pool) -> bytes:
        raise NotImplementedError

    def load(self, data: bytes) -> None:
        raise NotImplementedError


class ManifestTarget(Target):
    name = "manifest"

    def seeds(self) -> list[bytes]:
        files = sorted((ROOT / "harness" / "adapters").glob("*.toml")) + sorted((ROOT / "examples").rglob("*.toml"))
        return [p.read_bytes() for p in files if b"[commands]" in p.read_bytes() or b"python" in p.read_bytes()]

    def mutate(self, rng, data, pool) -> bytes:
        return mutate_toml(rng, data, pool)

    def load(self, data: bytes) -> None:
        p = self.scratch / "decoder.toml"
        p.write_bytes(data)
        a = load_manifest(p)
        a.describe()


class SuiteTarget(Target):
    name = "suite"

    def seeds(self) -> list[bytes]:
        return [p.read_bytes() for p in sorted(suites_root().glob("*/suite.json"))]

    def mutate(self, rng, data, pool) -> bytes:
        return mutate_json(rng, data, pool) if rng.random() < 0.7 else mutate_bytes(rng, data, pool)

    def load(self, data: bytes) -> None:
        d = self.scratch / "s"
        d.mkdir(exist_ok=True)
        (d / "suite.json").write_bytes(data)
        s = Suite.load(d)
        for c in s.cases:  # what a run asks of a loaded case
            c.to_json()
            _ = [c.input_path(k) for k in c.inputs if k != "faces"], c.face_paths(), c.golden_dir(self.scratch)


class PackageTarget(Target):
    """Inputs are one package file replaced, encoded as ``name\\0`` + a flag byte + the new bytes; the
    flag ``S`` updates the file's digest in ``SHA256SUMS``, ``K`` keeps the listed one."""

    name = "package"

    def __init__(self, scratch: Path, package: Path) -> None:
        super().__init__(scratch)
        self.pkg = scratch / "pkg"
        if self.pkg.exists():
            shutil.rmtree(self.pkg)
        shutil.copytree(package, self.pkg, symlinks=True)
        self.names = sorted(p.relative_to(self.pkg).as_posix() for p in self.pkg.rglob("*") if p.is_file())
        self.original = {n: (self.pkg / n).read_bytes() for n in self.names}

    def seeds(self) -> list[bytes]:
        return [n.encode() + b"\0S" + self.original[n] for n in self.names]

    def mutate(self, rng, data, pool) -> bytes:
        name, _, body = data.partition(b"\0")
        body = body[1:]
        if name.endswith((b".json", b".jsonl")) and rng.random() < 0.6:
            lines = body.split(b"\n")
            i = rng.randrange(len(lines))
            lines[i] = mutate_json(rng, lines[i], pool)
            body = b"\n".join(lines)
        else:
            body = mutate_bytes(rng, body, pool)
        return name + b"\0" + rng.choice((b"S", b"K")) + body

    def load(self, data: bytes) -> None:
        name, _, rest = data.partition(b"\0")
        fname, update, body = name.decode("utf-8", "replace"), rest[:1] == b"S", rest[1:]
        if fname not in self.original:
            return
        (self.pkg / fname).write_bytes(body)
        if update and fname != SUMS:  # the digest updated: verification goes past it to the parsers
            sums = self.original[SUMS].decode("utf-8", "replace").splitlines()
            digest = hashlib.sha256(body).hexdigest()
            sums = [f"{digest}  {fname}" if ln.endswith(f"  {fname}") else ln for ln in sums]
            (self.pkg / SUMS).write_text("\n".join(sums) + "\n")
        try:
            v = verify(self.pkg)
            _ = v.problems, v.certificate  # what `certify verify` prints
        finally:  # the package as it was, for the next input
            (self.pkg / fname).write_bytes(self.original[fname])
            (self.pkg / SUMS).write_bytes(self.original[SUMS])


# ------------------------------------------------------------------ the loop
def fuzz(target: Target, seconds: float, seed: int, *, max_inputs: int | None = None) -> Stats:
    """Mutate the target's seeds for ``seconds`` (or ``max_inputs``); findings by signature."""
    rng = random.Random(seed)
    pool = target.seeds()
    if not pool:
        raise FbaconfInputError(f"{target.name}: no seeds", rule="fuzz-setup")
    st = Stats()
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds and (max_inputs is None or st.inputs < max_inputs):
        data = target.mutate(rng, rng.choice(pool), pool)
        st.inputs += 1
        try:
            target.load(data)
        except FbaconfInputError:
            continue
        except Exception as e:  # noqa: BLE001 - the finding
            tb = traceback.format_exc()
            where = traceback.extract_tb(e.__traceback__)[-1]
            sig = f"{type(e).__name__}@{Path(where.filename).name}:{where.lineno}"
            if sig not in st.findings or len(data) < len(st.findings[sig][0]):
                st.findings[sig] = (data, tb)
    return st


def make_package(out: Path) -> Path:
    """``certify --decoder reference-inprocess --claim simple@1 --no-speed`` into ``out``."""
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "fbaconf",
            "certify",
            "--decoder",
            "reference-inprocess",
            "--claim",
            "simple@1",
            "--no-speed",
            "-o",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=1800,
    )
    if r.returncode != 0 or not (out / CERTIFICATE).is_file():
        raise FbaconfInputError(f"cannot make a package to fuzz: {r.stderr.strip()[-300:]}", rule="fuzz-setup")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m fbaconf.fuzz.loaders", description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=600.0, help="per target")
    ap.add_argument("--targets", default="manifest,suite,package")
    ap.add_argument("--package", type=Path, help="a certified package to mutate (default: one made now)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path, default=Path("fbaconf-loader-fuzz"))
    args = ap.parse_args(argv)
    scratch = Path(tempfile.mkdtemp(prefix="fbaconf-loaders-"))
    found = 0
    try:
        for name in args.targets.split(","):
            if name == "package":
                pkg = args.package or make_package(scratch / "certified")
                target: Target = PackageTarget(scratch, pkg)
            else:
                target = {"manifest": ManifestTarget, "suite": SuiteTarget}[name](scratch)
            st = fuzz(target, args.seconds, args.seed)
            print(
                f"{name}: {st.inputs} inputs in {args.seconds:g} s ({st.inputs / args.seconds:,.0f}/s), "
                f"{len(st.findings)} traceback(s)"
            )
            for sig, (data, tb) in st.findings.items():
                found += 1
                d = args.out / name / hashlib.sha256(sig.encode()).hexdigest()[:12]
                d.mkdir(parents=True, exist_ok=True)
                (d / "input").write_bytes(data)
                (d / "traceback.txt").write_text(tb)
                print(f"  {sig}: {len(data)} bytes -> {d}")
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
