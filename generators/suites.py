"""``fbaconf suites build``: generate every suite of ``conformance/data/suites.toml`` into
``conformance/suites/`` (content in :mod:`.content`, scenes in :mod:`.suite_scenes`, error and
special streams in :mod:`.streams`).

Deterministic: the same fbaconf version writes byte-identical files on any machine
(procedural content, reference encoder, fixed seeds, the bundled models from their committed
data, generated geometry rounded to 6 decimals before it is written), so the sha256 digests in each
``suite.json`` are stable
and the goldens made from them (``fbaconf golden regenerate``) can be verified bit for bit.

Each case folder-less: a suite folder holds ``suite.json`` and the case files named
``<case>.fba``, ``<case>.fap``, ``<case>.bt``, ``<case>.bifs`` (when the BIFS codec is
available), ``scenario.toml`` (shared by the suite's image cases), ``<case>-face<i>.fba``.
"""

from __future__ import annotations

import json
import shutil
import tempfile
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np

from fbaconf._atomic import atomic_write_bytes, atomic_write_text
from fbaconf.animation.engine import compile_scene, load_scene
from fbaconf.animation.rbf import CONDITION_BOUND
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.faptext import read_fap_file, write_fap
from fbaconf.bitstreams.frames import RETAINED, SET
from fbaconf.conformance.golden import regenerate
from fbaconf.conformance.suite import SUITE_FORMAT, Case, Suite, SuiteError, sha256_file, suites_root
from fbaconf.errors import FbaconfInputError
from fbaconf.rendering.scenario import Scenario
from fbaconf.scenes import bifs, bt

from .content import encoder_options, make_content
from .streams import edit_valid, mutate, special_stream
from .suite_scenes import make_scene

# Generated geometry is written at this many decimals: the files do not change with a
# numpy/libm build's last digit (0.000001 mm-like units: far below every tolerance).
GEOMETRY_DECIMALS = 6
# the case kind of each generator kind in conformance/data/suites.toml
_CASE_KIND = {"stream": "decode", "multi": "multi", "error": "error", "file": "decode", "special": "decode"}


def spec(data_dir: Path | None = None) -> dict:
    """suites.toml, with the [[suite]] / [[case]] lists of data/regression.toml (promoted fuzz
    findings, written by the fuzzer) appended when that file exists."""
    data = Path(data_dir) if data_dir is not None else resources.files("fbaconf.conformance").joinpath("data")
    s = tomllib.loads(data.joinpath("suites.toml").read_text("utf-8"))
    reg = data.joinpath("regression.toml")
    if reg.is_file():
        r = tomllib.loads(reg.read_text("utf-8"))
        known = {x["name"] for x in s["suite"]}
        s["suite"] = s["suite"] + [x for x in r.get("suite", []) if x["name"] not in known]
        s["case"] = s["case"] + list(r.get("case", []))
    return s


def scenario_names(sc_spec: dict) -> list[str]:
    """The scenarios image cases render under (suites.toml ``[scenario] scenarios``), first = the
    case's own, the others as ``<case>-<scenario>`` image-only cases."""
    return list(sc_spec.get("scenarios", ["front"]))


def compared_frames(frames, rule: str) -> list[int]:
    """The frames an image case compares: ``"ends"`` = first, middle and last; ``"ends+extreme"``
    adds the frame whose FAP values are largest in magnitude (the animation's extreme); ``"all"``:
    every frame (a case whose frames each show other FAPs, e.g. a sweep)."""
    n = len(frames)
    if rule == "all":
        return list(range(n))
    out = {0, n // 2, n - 1}
    if rule == "ends+extreme" and n:
        mag = np.where(frames.status != 0, np.abs(frames.values.astype(np.float64)), 0.0).sum(axis=1)
        out.add(int(np.argmax(mag)))
    return sorted(out)


def _scenario_toml(sc_spec: dict, name: str, frames) -> str:
    path = resources.files("fbaconf.conformance").joinpath("data", "scenarios", f"{name}.toml")
    if not path.is_file():
        raise SuiteError(
            f"[scenario] names scenario {name!r}: no conformance/data/scenarios/{name}.toml", rule="suite-spec"
        )
    d = tomllib.loads(Scenario.from_dict(tomllib.loads(path.read_text("utf-8")), file=str(path)).to_toml())
    d["width"], d["height"], d["supersample"] = sc_spec["width"], sc_spec["height"], sc_spec["supersample"]
    if sc_spec.get("frames"):
        d["frames"] = compared_frames(frames, sc_spec["frames"])
    return _dump_toml(d)


def _dump_toml(d: dict, prefix: str = "") -> str:
    def val(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(val(x) for x in v) + "]"
        if isinstance(v, float):
            return repr(v)
        return str(v)

    lines, tables, arrays = [], [], []
    for k, v in d.items():
        if isinstance(v, dict):
            tables.append((k, v))
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            arrays.append((k, v))
        else:
            lines.append(f"{k} = {val(v)}")
    out = "\n".join(lines) + "\n"
    for k, v in tables:
        out += f"\n[{prefix}{k}]\n" + _dump_toml(v, f"{prefix}{k}.")
    for k, items in arrays:
        for it in items:
            out += f"\n[[{prefix}{k}]]\n" + _dump_toml(it, f"{prefix}{k}.")
    return out


def _write(dirpath: Path, name: str, data: bytes | str, case: Case, key: str | None) -> str:
    p = dirpath / name
    if isinstance(data, str):
        atomic_write_text(p, data)
    else:
        atomic_write_bytes(p, data)
    case.sha256[name] = sha256_file(p)
    if key:
        case.inputs[key] = name
    return name


def _write_scene(d: Path, case: Case, spec: str) -> None:
    """The case's scene as BT and binary BIFS, and the files it names (textures)."""
    scene, files = make_scene(spec)
    for name, blob in sorted(files.items()):
        if not (d / name).is_file():
            _write(d, name, blob, case, None)
        else:
            case.sha256[name] = sha256_file(d / name)
    scene = bt.rounded(scene, GEOMETRY_DECIMALS)
    _write(d, f"{case.id}.bt", bt.write(scene), case, "scene")
    _write(d, f"{case.id}.bifs", bifs.encode(scene), case, "bifs")


def _share_scene(d: Path, case: Case, other: str) -> None:
    """The scene files (BT and BIFS) of ``other``, a case of the same suite built before: named,
    not copied (a large scene ships once)."""
    for key, ext in (("scene", "bt"), ("bifs", "bifs")):
        name = f"{other}.{ext}"
        if not (d / name).is_file():
            raise SuiteError(
                f"case {case.id}: scene_of names {other!r}, which has no {name} (it must come first in its suite)",
                rule="suite-spec",
            )
        case.inputs[key] = name
        case.sha256[name] = sha256_file(d / name)


def _error_expect(c: dict) -> dict:
    """An error case's expectation: the checker's diagnostics, and whether a decoder may
    decode (conceal) instead of rejecting (``conceal = true`` in suites.toml)."""
    out = {"diagnostics": list(c.get("expect", []))}
    if c.get("conceal"):
        out["conceal"] = True
    return out


def sparse_text(frames):
    """The frames a player is given as .fap text: a FAP's mask bit is 1 only in the frames where
    its value (or a high-level field) changes, so the text says "keep the previous value"
    everywhere else, as the format allows. A player's output is its state — every FAP that
    holds a value, in every frame — so the input is never the expected output: a program that
    copies its input fails every case with a held value."""
    out = frames.copy()
    st = out.status
    for k in range(1, len(out)):
        same = frames.values[k] == frames.values[k - 1]
        for fap, sl in ((1, slice(0, 4)), (2, slice(4, 10))):
            same[fap - 1] = bool((frames.high[k, sl] == frames.high[k - 1, sl]).all())
        prev_has = np.isin(frames.status[k - 1], (SET, RETAINED))
        hold = (st[k] == SET) & same & prev_has
        st[k] = np.where(hold, RETAINED, st[k])
    return out


def build_case(c: dict, suite: dict, d: Path, sc_spec: dict) -> list[Case]:
    """The case ``c`` of suites.toml, built into ``d``, followed by its image-only views under
    the other scenarios (when it compares images)."""
    views: list[Case] = []
    return [_build(c, suite, d, sc_spec, views)] + views


def _build(c: dict, suite: dict, d: Path, sc_spec: dict, views: list[Case]) -> Case:
    gen = c.get("generator", "stream")
    case = Case(
        id=c["id"],
        suite=suite["name"],
        claim=c.get("claim", suite["claim"]),
        group=suite["group"],
        kind=_CASE_KIND[gen],
        description=c.get("description", ""),
        tools=list(c.get("tools", [])),
        covers=list(c.get("covers", [])),
        suite_dir=d,
    )
    if gen == "file":
        # a committed input (e.g. a promoted fuzz finding, conformance/data/regression/): an error
        # case, or a valid stream decoded by the reference for the goldens
        src = Path(str(resources.files("fbaconf.conformance").joinpath("data", c["file"])))
        if not src.is_file():
            raise SuiteError(f"case {case.id}: file {c['file']} not found under conformance/data", rule="suite-spec")
        ext = src.suffix.lower().lstrip(".")
        _write(d, f"{case.id}.{ext}", src.read_bytes(), case, ext)
        if c.get("expect") is not None or c.get("valid") is False:
            case.kind = "error"
            case.expect = _error_expect(c)
        else:
            case.stages = ["faps"]
            case.goldens = {"faps": "faps.npz"}
            if ext == "fba":  # a valid stream: the players' input too (sparse text, see sparse_text)
                decoded = decode(src.read_bytes()).frames
                _write(d, f"{case.id}.fap", write_fap(sparse_text(decoded), name=case.id), case, "fap")
                case.frames = len(decoded)
        return case
    if (
        gen == "error"
        and c.get("mutation")
        in (
            "too-short",
            "not-face",
            "stuffing",
            "viseme-select",
            "expression-select",
            "intensity",
            "value-overflow",
            "first-predicted-decodable",
            "trailing-zero-byte",
        )
        and "content" not in c
    ):
        c = dict(c, content={"frames": 5, "faps": [3, 4]})
    content = make_content(c.get("content", {}))
    opts = encoder_options(c.get("options", {}), len(content))
    if gen == "multi":
        faces = []
        per_face = c.get("face_options", [])
        per_content = c.get("face_content", [])
        for i in range(int(c["faces"])):
            cc = dict(c.get("content", {}), **(per_content[i] if i < len(per_content) else {}))
            cc["seed"] = int(cc.get("seed", 0)) * 10 + i
            fo = per_face[i] if i < len(per_face) else {}
            if "frame_rate" in fo:
                cc["rate"] = fo["frame_rate"]
            res = encode(
                make_content(cc), encoder_options({**c.get("options", {}), **fo}, len(content)) if fo else opts
            )
            faces.append(_write(d, f"{case.id}-face{i}.fba", res.data, case, None))
        case.inputs["faces"] = faces
        case.frames = len(content)
        case.stages = ["faps"]
        case.goldens = {"faces": [f"face{i}.npz" for i in range(len(faces))]}
        return case
    res = encode(content, opts)
    if gen == "error":
        data = (
            mutate(res.data, c["mutation"], int(c.get("content", {}).get("seed", 0))) if c.get("mutation") else res.data
        )
        _write(d, f"{case.id}.fba", data, case, "fba")
        if "scene" in c:  # a valid stream with an invalid scene: the decoder must load it to see
            _write_scene(d, case, c["scene"])
            case.stages = ["faps", "vertices"]
        case.expect = _error_expect(c)
        case.frames = len(content)
        return case
    data = special_stream(c["special"]) if c.get("special") else res.data
    if c.get("edit"):
        data = edit_valid(data, c["edit"])
    decoded = decode(data).frames
    _write(d, f"{case.id}.fba", data, case, "fba")
    if c.get("text", True):  # the players' input: the decoded frames as sparse text (see sparse_text)
        _write(d, f"{case.id}.fap", write_fap(sparse_text(decoded), name=case.id), case, "fap")
    case.frames = len(decoded)
    case.stages = list(c.get("stages", ["faps"]))
    case.goldens = {"faps": "faps.npz"}
    if "scene" in c:
        _write_scene(d, case, c["scene"])
    elif "scene_of" in c:
        _share_scene(d, case, c["scene_of"])
    if "vertices" in case.stages:
        case.goldens["vertices"] = "vertices.npz"
        if c.get("vertices_key"):
            case.tolerances.setdefault("vertices", {})["key"] = c["vertices_key"]
    if "images" in case.stages:
        if c.get("image_frames"):  # the case's own rule for the frames its images compare
            sc_spec = dict(sc_spec, frames=c["image_frames"])
        _image_goldens(case, d, _scenario_toml(sc_spec, scenario_names(sc_spec)[0], decoded))
        views += [
            _view(case, d, _scenario_toml(sc_spec, n, decoded), n)
            for n in scenario_names(sc_spec)[1:] + list(c.get("extra_scenarios", []))
        ]
    return case


def _image_goldens(case: Case, d: Path, text: str) -> None:
    _write(d, f"{case.id}-scenario.toml", text, case, "scenario")
    frames = tomllib.loads(text).get("frames", list(range(case.frames)))
    case.goldens["images"] = [f"frame_{k:05d}.png" for k in frames]


def _view(case: Case, d: Path, text: str, name: str) -> Case:
    """An image-only case: ``case``'s inputs (the same files, not copies) under another scenario."""
    v = Case(
        id=f"{case.id}-{name}",
        suite=case.suite,
        claim=case.claim,
        group=case.group,
        kind="decode",
        description=f"{case.id} rendered under scenario {name!r}",
        tools=list(case.tools),
        covers=[],
        inputs={k: x for k, x in case.inputs.items() if k != "scenario"},
        sha256={k: x for k, x in case.sha256.items() if not k.endswith("-scenario.toml")},
        frames=case.frames,
        stages=["images"],
        goldens={},
        suite_dir=d,
    )
    _image_goldens(v, d, text)
    return v


def reference_conditioning(cases: list[Case]) -> list[tuple[str, str, str, float]]:
    """(suite, case, system, condition number) of every linear system the reference solves to
    compile the scenes of the valid ``cases`` (calibration: ``warp``, ``texture``; see
    animation/rbf.py). Raises SuiteError (rule ``suite-reference``) for a case whose scene the
    reference refuses -- e.g. a system above ``rbf.CONDITION_BOUND`` -- so that no suite is built
    whose goldens would depend on the platform's LAPACK."""
    out, seen = [], {}
    for case in cases:
        path = case.input_path("scene")
        if path is None or case.kind == "error":
            continue
        key = case.sha256.get(path.name) or str(path)
        if key not in seen:
            try:
                seen[key] = compile_scene(load_scene(path)).extras.get("conditioning", {})
            except FbaconfInputError as e:
                raise SuiteError(
                    f"case {case.suite}/{case.id}: the reference cannot compile its scene: {e}", rule="suite-reference"
                ) from None
        out += [(case.suite, case.id, system, cond) for system, cond in seen[key].items()]
    return out


def worst_conditioning(rows: list[tuple[str, str, str, float]]) -> str:
    """One line: the worst condition number among ``rows`` and the bound."""
    if not rows:
        return "reference conditioning: no linear system solved"
    suite, case, system, cond = max(rows, key=lambda r: r[3])
    return (
        f"reference conditioning: worst condition number {cond:.3g} ({suite}/{case}, {system}) of "
        f"{len(rows)} system(s); bound {CONDITION_BOUND:.0e} (animation/rbf.py)"
    )


def build(root: Path | None = None, names: list[str] | None = None, log=print) -> list[Suite]:
    """Regenerate the suites (all, or ``names``) under ``root``; returns them. Refuses a case whose
    reference would rest on an ill-conditioned system (:func:`reference_conditioning`) and logs the
    worst condition number."""
    s = spec()
    root = root or suites_root()
    root.mkdir(parents=True, exist_ok=True)
    suites, conditioning = [], []
    known = {x["name"] for x in s["suite"]}
    for c in s["case"]:
        if c["suite"] not in known:
            raise SuiteError(f"case {c['id']} names unknown suite {c['suite']!r}", rule="suite-spec")
    for sd in s["suite"]:
        if names and sd["name"] not in names:
            continue
        d = root / sd["name"]
        if d.exists():
            shutil.rmtree(d)
        d.mkdir(parents=True)
        cases = [x for c in s["case"] if c["suite"] == sd["name"] for x in build_case(c, sd, d, s["scenario"])]
        conditioning += reference_conditioning(cases)
        suite = Suite(sd["name"], sd.get("description", ""), sd["claim"], sd["group"], s["version"], cases, d)
        atomic_write_text(d / "suite.json", json.dumps(suite.to_json(), indent=1, sort_keys=False) + "\n")
        suites.append(suite)
        log(f"built {suite.name}: {len(cases)} case(s)")
    log(worst_conditioning(conditioning))
    return suites


EXTERNAL_SUITE = "simple-l2-real"
EXTERNAL_QUANTS = (1, 8, 31)
EXTERNAL_RATES = (None, 10.0)  # the file's own rate, and resampled to 10 Hz


def build_external(src: Path, out: Path | None = None, log=print) -> Suite | None:
    """The optional EXTERNAL suite: every ``.fap`` file under ``src`` (e.g. ../shared/data/fap)
    as it is (a raw text case for players) and encoded at several quantisers and frame rates,
    with goldens, under ``out`` (default: a new
    temporary folder). Never written into the repository. Returns None when ``src`` holds no
    .fap file. Run it with ``FBACONF_SUITES=<out>/suites FBACONF_GOLDEN=<out>/golden fbaconf run``."""
    src = Path(src)
    files = sorted(p for p in src.rglob("*.fap") if p.is_file()) if src.is_dir() else []
    if not files:
        return None
    out = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="fbaconf-external-"))
    d = out / "suites" / EXTERNAL_SUITE
    if d.exists():
        shutil.rmtree(d)
    d.mkdir(parents=True)
    cases = []
    for f in files:
        try:
            frames = read_fap_file(f)[0]
        except (OSError, FbaconfInputError) as e:
            log(f"external: {f}: skipped ({e})")
            continue
        stem = f"{f.parent.name}-{f.stem}".replace(" ", "_")
        # the file itself, as its tool wrote it, for players (group "text": informative for the
        # decoders of the binary stream); the golden is fbaconf's reading of it
        raw = Case(
            id=f"{stem}-raw",
            suite=EXTERNAL_SUITE,
            claim="simple@1",
            group="text",
            kind="decode",
            description=f"real file {f.relative_to(src)} as written (players)",
            suite_dir=d,
        )
        _write(d, f"{raw.id}.fap", f.read_bytes(), raw, "fap")
        raw.frames = len(frames)
        raw.stages = ["faps"]
        raw.goldens = {"faps": "faps.npz"}
        cases.append(raw)
        for q in EXTERNAL_QUANTS:
            for rate in EXTERNAL_RATES:
                cid = f"{stem}-q{q}" + (f"-{rate:g}hz" if rate else "")
                try:
                    res = encode(frames, EncoderOptions(fap_quant=q, frame_rate=rate, intra_period=25))
                except FbaconfInputError as e:
                    log(f"external: {cid}: not codable ({e.message if hasattr(e, 'message') else e})")
                    continue
                case = Case(
                    id=cid,
                    suite=EXTERNAL_SUITE,
                    claim="simple@2",
                    group="real",
                    kind="decode",
                    description=f"real file {f.relative_to(src)} at fap_quant {q}" + (f", {rate:g} Hz" if rate else ""),
                    tools=["arithmetic"],
                    suite_dir=d,
                )
                _write(d, f"{cid}.fba", res.data, case, "fba")
                _write(d, f"{cid}.fap", write_fap(res.recon, name=cid), case, "fap")
                case.frames = len(res.recon)
                case.stages = ["faps"]
                case.goldens = {"faps": "faps.npz"}
                cases.append(case)
    suite = Suite(
        EXTERNAL_SUITE,
        f"EXTERNAL: the real .fap files of {src} (not committed)",
        "simple@2",
        "real",
        spec()["version"],
        cases,
        d,
    )
    atomic_write_text(d / "suite.json", json.dumps(suite.to_json(), indent=1) + "\n")
    regenerate([suite], out / "golden", log=lambda *_: None)
    log(f"built external suite {EXTERNAL_SUITE}: {len(cases)} case(s) from {len(files)} file(s) in {out}")
    return suite


__all__ = ["build", "build_external", "spec", "SUITE_FORMAT"]
