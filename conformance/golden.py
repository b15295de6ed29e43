"""``fbaconf golden regenerate|verify``: golden outputs of the reference, with sha256 digests.

Goldens are written only here, from the reference pipeline (``fbaconf.reference.pipeline``, the same code
the bundled reference decoder ``reference/decoder.py`` runs):
``golden/<suite>/<case>/faps.npz`` (decoded FapFrames), ``vertices.npz`` (FaceState),
``frame_NNNNN.png`` (images), ``face<i>.npz`` (multi-face cases). Beside them, for every other
reading of a provisional decision (``bitstreams/data/readings.toml``) that changes what the
case's streams decode to: ``readings/<slug>/`` with the same outputs under that reading, or
``reject.json`` when that reading rejects a stream fbaconf decodes (error cases: ``faps.npz``
when the reading decodes what fbaconf rejects). ``golden/MANIFEST.json`` lists every file with
its sha256 and the digest of the suite manifest it was made from.

``.npz`` files are rewritten in a canonical form (fixed zip timestamps, sorted members,
deflate) so that regeneration is bit-identical; ``verify`` proves (1) every golden file
matches its digest and nothing is missing or extra, (2) every suite's input files match
their digests, and (3) regenerating into a temporary folder reproduces every file byte
for byte -- or, where a value crosses a rounding step on this platform (numpy, BLAS, libm and
PNG encoder builds differ in their last digits and bytes), within one step (the file is named
and the tolerance said: conformance/precision.py).
"""

from __future__ import annotations

import io
import json
import shutil
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from fbaconf._atomic import atomic_write_bytes, atomic_write_text
from fbaconf.bitstreams import readings
from fbaconf.bitstreams.frames import FapFrames
from fbaconf.errors import FbaconfInputError
from fbaconf.reference.pipeline import load_stream, multi_outputs, reference_outputs

from .precision import ROUNDED, round_array, within_tolerance
from .suite import CaseKind, Suite, SuiteError, digest_problems, golden_root, load_suites, sha256_file

MANIFEST = "MANIFEST.json"
# Image goldens approximate the ideal (infinitely supersampled) image: 8 x 8 ordered samples per
# pixel, whatever the case's scenario asks of a player (at least N x N samples, any pattern). Measured
#: against 8 x 8 goldens the spread of faithful renderers with 2 x 2 to 4 x 4 samples,
# rotated grids and MSAA roughly halves compared with goldens made by one 2 x 2 sampler.
GOLDEN_SUPERSAMPLE = 8
FORMAT = "fbaconf.golden/1"
READINGS = "readings"  # a case's goldens under the other readings: <case>/readings/<slug>/
REJECT = "reject.json"  # in a reading's folder: that reading rejects the stream


def canonical_npz(path: Path, keep: list[str] | None = None) -> None:
    """Rewrite an .npz with fixed metadata so equal arrays give equal bytes. The computed float
    arrays of a FaceState are stored rounded to 6 decimals (``precision.ROUNDED``: vertices and
    feature points as float32, FIT/expression FAP values as float64): their comparison has a
    tolerance far above that resolution, and a build's last-digit noise reaches the stored bytes
    only for a value within that noise of a rounding boundary (``fbaconf golden margins``).
    ``keep``: store only these arrays (what the case compares)."""
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files if keep is None or k in keep or k == "format"}
        if "format" in arrays and str(arrays["format"]).startswith("fbaconf.FaceState"):
            for k in ROUNDED:
                if k in arrays:
                    arrays[k] = round_array(k, arrays[k])
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name in sorted(arrays):
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            data = io.BytesIO()
            np.lib.format.write_array(data, np.array(arrays[name], order="C"), allow_pickle=False)
            zf.writestr(info, data.getvalue(), compresslevel=9)
    atomic_write_bytes(path, buf.getvalue())


def generate_case(case, out: Path) -> list[Path]:
    """Write one case's goldens into ``out``; returns the files written."""
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    if case.kind == CaseKind.ERROR:
        return written
    if case.kind == CaseKind.MULTI:
        tmp = out / ".faces"
        multi_outputs(case.face_paths(), tmp, "npz")
        for src, name in zip(case.face_paths(), case.goldens["faces"]):
            (tmp / f"{src.stem}.npz").replace(out / name)
            written.append(out / name)
        shutil.rmtree(tmp, ignore_errors=True)
    else:
        stream = case.input_path("fba") or case.input_path("fap")
        kw = {}
        if "faps" in case.stages:
            kw["faps_out"] = out / case.goldens["faps"]
        if "vertices" in case.stages:
            kw["vertices_out"] = out / case.goldens["vertices"]
        if "images" in case.stages:
            kw["images_dir"] = out
            kw["scenario"] = case.input_path("scenario")
        reference_outputs(stream, scene=case.input_path("scene"), supersample=GOLDEN_SUPERSAMPLE, **kw)
        for k in ("faps_out", "vertices_out"):
            if k in kw:
                written.append(kw[k])
        written += [out / n for n in case.goldens.get("images", [])]
    key = case.tolerances.get("vertices", {}).get("key")
    for p in written:
        if p.suffix == ".npz":
            canonical_npz(p, keep=[key] if (key and p.name == case.goldens.get("vertices")) else None)
    return written


def _decodings(case) -> list[FapFrames] | FbaconfInputError | None:
    """What the reference decodes the case's stream(s) to, or the error that rejects one; None
    for a case without a binary stream (a player's .fap text)."""
    streams = case.face_paths() if case.kind == CaseKind.MULTI else [case.input_path("fba")]
    if not streams or any(s is None for s in streams):
        return None
    try:
        return [load_stream(s) for s in streams]
    except FbaconfInputError as e:
        return e


_COMPARED = ("values", "status", "high", "frame_number", "time_ms")


def _same(a, b) -> bool:
    """Whether two decodings are the same for every comparison the harness makes (a reading
    that only moves bit offsets or intra flags changes no verdict)."""
    if isinstance(a, FbaconfInputError) or isinstance(b, FbaconfInputError):
        return isinstance(a, FbaconfInputError) and isinstance(b, FbaconfInputError)
    return len(a) == len(b) and all(
        x.frame_rate == y.frame_rate and all(np.array_equal(getattr(x, k), getattr(y, k)) for k in _COMPARED)
        for x, y in zip(a, b)
    )


def reading_goldens(case, root: Path | None = None) -> dict[str, Path]:
    """The other readings that change ``case``'s result, by id, with their folders (what
    :func:`generate_readings` wrote for the case)."""
    d = case.golden_dir(root or golden_root()) / READINGS
    if not d.is_dir():
        return {}
    out = {}
    for sub in sorted(d.iterdir()):
        r = readings.by_slug(sub.name)
        if r is not None and sub.is_dir():
            out[r.id] = sub
    return out


def generate_readings(case, out: Path) -> list[Path]:
    """For each other reading that changes what ``case``'s streams decode to: the case's goldens
    under that reading in ``out/readings/<slug>/`` (``reject.json`` where it rejects a stream);
    returns the files written."""
    base = _decodings(case)
    if base is None:
        return []
    written: list[Path] = []
    for r in readings.catalogue().values():
        with readings.using(r.id):
            alt = _decodings(case)
            if _same(alt, base):
                continue
            d = out / READINGS / r.slug
            d.mkdir(parents=True, exist_ok=True)
            if isinstance(alt, FbaconfInputError):
                doc = {"reading": r.id, "rule": alt.rule, "message": alt.message[:300]}
                atomic_write_text(d / REJECT, json.dumps(doc, indent=1, sort_keys=True) + "\n")
                written.append(d / REJECT)
            elif case.kind == CaseKind.ERROR:  # fbaconf rejects it; this reading decodes it
                alt[0].save_npz(d / "faps.npz")
                canonical_npz(d / "faps.npz")
                written.append(d / "faps.npz")
            else:
                written += generate_case(case, d)
    return written


def regenerate(suites: list[Suite], root: Path | None = None, log=print) -> dict:
    root = root or golden_root()
    for s in suites:
        d = root / s.name
        if d.exists():
            shutil.rmtree(d)
    files: dict[str, str] = {}
    for s in suites:
        for c in s.cases:
            for p in generate_case(c, c.golden_dir(root)) + generate_readings(c, c.golden_dir(root)):
                files[p.relative_to(root).as_posix()] = sha256_file(p)
        log(f"goldens for {s.name}: {sum(1 for k in files if k.startswith(s.name + '/'))} file(s)")
    manifest = {
        "format": FORMAT,
        "suites": {s.name: {"version": s.version, "manifest_sha256": s.digest()} for s in suites},
        "files": dict(sorted(files.items())),
    }
    atomic_write_text(root / MANIFEST, json.dumps(manifest, indent=1) + "\n")
    return manifest


def _not_a_golden(rel: str) -> bool:
    """Files under the golden folder that are not goldens: the manifest, hidden files, and the
    package marker that installs the folder as ``fbaconf.golden`` (with its bytecode)."""
    parts = Path(rel).parts
    return rel in (MANIFEST, "__init__.py") or parts[0] == "__pycache__" or Path(rel).name.startswith(".")


def compare_regenerated(
    files: dict[str, str], root: Path, regen: dict[str, str], regen_root: Path
) -> tuple[list[str], list[str]]:
    """(problems, files within tolerance): the committed goldens ``files`` (relative path ->
    sha256, under ``root``) against a regeneration ``regen`` (under ``regen_root``). A file
    whose bytes differ is accepted when :func:`precision.within_tolerance` says how it still
    matches (named in the second list); otherwise it is a problem."""
    problems, near = [], []
    for rel, digest in files.items():
        got = regen.get(rel)
        if got is None:
            problems.append(f"regeneration does not write {rel}")
        elif got != digest:
            how = within_tolerance(root / rel, regen_root / rel)
            if how is None:
                problems.append(f"regenerating {rel} does not reproduce it (not even within one rounding step)")
            else:
                near.append(f"{rel}: {how}")
    problems += [f"regeneration writes {rel}, which the goldens lack" for rel in sorted(set(regen) - set(files))]
    return problems, near


def verify(
    root: Path | None = None, *, regenerate_check: bool = True, only: list[str] | None = None, log=print
) -> list[str]:
    """Problems found (empty list = goldens verified). ``only``: regenerate only these suites (the
    digests of every golden and suite input are checked all the same)."""
    root = root or golden_root()
    mp = root / MANIFEST
    try:
        manifest = json.loads(mp.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return [f"no golden manifest {mp}: run `fbaconf golden regenerate`"]
    except ValueError as e:
        return [f"golden manifest {mp} is not valid JSON: {e}"]
    problems: list[str] = []
    files = manifest.get("files", {})
    missing, modified, extra = digest_problems(root, files, ignore=_not_a_golden)
    problems += [f"missing golden file {rel}" for rel in missing]
    problems += [f"golden file {rel} does not match its sha256" for rel in modified]
    problems += [f"golden file {rel} is not in the manifest" for rel in extra]
    try:
        suites = load_suites()
    except SuiteError as e:
        return problems + [str(e)]
    by_name = {s.name: s for s in suites}
    for name, info in manifest.get("suites", {}).items():
        s = by_name.get(name)
        if s is None:
            problems.append(f"goldens name suite {name}, which is not built")
            continue
        if s.digest() != info.get("manifest_sha256"):
            problems.append(f"suite {name}: suite.json changed since the goldens were made (regenerate them)")
        problems += [f"suite {name}: {p}" for p in s.verify_inputs()]
    for s in suites:
        if s.name not in manifest.get("suites", {}):
            problems.append(f"suite {s.name} has no goldens")
    log(f"digests: {len(files)} golden file(s) checked")
    unknown = sorted(set(only or ()) - set(by_name))
    if unknown:
        return problems + [f"no suite named {', '.join(unknown)}"]
    if regenerate_check and not problems:
        if only:
            suites = [s for s in suites if s.name in only]
            files = {rel: d for rel, d in files.items() if rel.split("/", 1)[0] in only}
        with tempfile.TemporaryDirectory(prefix="fbaconf-golden-") as tmp:
            t = Path(tmp)
            regen = regenerate(suites, t, log=lambda *_: None)
            bad, near = compare_regenerated(files, root, regen["files"], t)
            problems += bad
        log(
            f"regeneration: {len(files)} file(s) compared: {len(files) - len(near)} byte for byte"
            + (
                f", {len(near)} within tolerance (a value across a rounding step on this platform: vertex "
                f"arrays +-1e-6 and one float32 ulp, images +-1 of 255; see conformance/precision.py)"
                if near
                else ""
            )
        )
        for n in near:
            log(f"  within tolerance: {n}")
    return problems
