"""The harness comparison ladder (harness/compare/): FAPs, vertices, images, tolerances,
and untrusted decoder outputs."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from fbaconf.animation.engine import animate
from fbaconf.animation.stateio import save_npz
from fbaconf.bitstreams.faptext import write_fap_file
from fbaconf.bitstreams.frames import DERIVED, FREE, RETAINED, SET, FapFrames, first_difference
from fbaconf.bitstreams.synth import synthetic_sequence
from fbaconf.bitstreams.tables import fap_table
from fbaconf.harness.compare import (
    ImageTolerances,
    OutputError,
    ToleranceError,
    VertexTolerances,
    compare_faps,
    compare_images,
    compare_vertices,
    load_output_faps,
    load_output_vertices,
    load_tolerances,
    part_namer,
    worst,
)
from fbaconf.harness.results import OUTCOME_ORDER, Outcome
from fbaconf.rendering.images import encode_srgb8, read_linear_rgb, write_exr
from fbaconf.rendering.render import render_frames
from fbaconf.rendering.scenario import Scenario

FAST = settings(max_examples=40, deadline=None)


# ----------------------------------------------------------------------------- helpers
def random_frames(seed: int, n: int) -> FapFrames:
    """FapFrames with a random mix of SET / RETAINED / FREE / DERIVED statuses."""
    rng = np.random.default_rng(seed)
    f = FapFrames.empty(n)
    f.values[:, 2:] = rng.integers(-500, 500, size=(n, 66))
    f.status[:] = rng.choice([FREE, SET, RETAINED, DERIVED], size=f.status.shape, p=[0.3, 0.4, 0.2, 0.1])
    f.high[:] = rng.integers(0, 7, size=f.high.shape)
    f.frame_number[:] = np.arange(n) * 2
    return f


def name_of(fap: int) -> str:
    return fap_table()[fap - 1].name


# ----------------------------------------------------------------------------- worst
@given(st.lists(st.sampled_from(list(Outcome)), max_size=8))
def test_worst_is_first_in_outcome_order(outcomes):
    expected = min(outcomes, key=OUTCOME_ORDER.index) if outcomes else Outcome.PASS
    assert worst(outcomes) is expected


def test_worst_examples():
    assert worst([Outcome.PASS, Outcome.QUALITY_WARNING]) is Outcome.QUALITY_WARNING
    assert worst([Outcome.ERROR, Outcome.FAIL, Outcome.QUALITY_WARNING]) is Outcome.FAIL
    assert worst([Outcome.FAIL, Outcome.CRASH]) is Outcome.CRASH
    assert worst([Outcome.SKIPPED, Outcome.NOT_SUPPORTED]) is Outcome.NOT_SUPPORTED
    assert worst([]) is Outcome.PASS


# ----------------------------------------------------------------------------- tolerances
def test_tolerance_defaults_come_from_the_data_file():
    data = load_tolerances()
    img, vert = ImageTolerances.defaults(), VertexTolerances.defaults()
    assert img.to_dict() == {k: float(v) for k, v in data["images"].items()}
    assert vert.to_dict() == {k: float(v) for k, v in data["vertices"].items()}
    assert img.interior_deltae_warn_mean <= img.interior_deltae_fail_mean and img.contrast_k < 1.0


def test_tolerance_overrides_and_validation():
    base = ImageTolerances.defaults()
    t = ImageTolerances.from_dict(base, {"abs_tol": 0.5, "fail_percent": 3})
    assert t.abs_tol == 0.5 and t.fail_percent == 3.0 and t.contrast_k == base.contrast_k
    assert ImageTolerances.from_dict(None, {"abs_tol": 0.5}) == t.__class__(
        **{**base.to_dict(), "abs_tol": 0.5, "fail_percent": base.fail_percent}
    )
    assert VertexTolerances.from_dict({"max_tol": 1, "rms_tol": 0.5}, None) == VertexTolerances(1.0, 0.5)
    for bad in (
        {"absTol": 1},
        {"abs_tol": "x"},
        {"abs_tol": True},
        {"abs_tol": -1},
        {"abs_tol": float("nan")},
        {"interior_deltae_warn_mean": 2, "interior_deltae_fail_mean": 1},
    ):
        with pytest.raises(ToleranceError):
            ImageTolerances.from_dict(base, bad)
    with pytest.raises(ToleranceError):
        VertexTolerances.from_dict({"max_tol": 1}, None)  # rms_tol missing


# ----------------------------------------------------------------------------- FAPs
@FAST
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 6), text=st.booleans())
def test_identical_faps_pass(seed, n, text):
    f = random_frames(seed, n)
    r = compare_faps(f, f.copy(), text_output=text)
    assert r.outcome is Outcome.PASS and r.stage == "faps" and r.first_difference is None
    assert r.metrics["frames_compared"] == n and r.metrics["frames_differing"] == 0
    assert r.series["faps_differing"] == [0.0] * n and len(r.series["max_abs_diff"]) == n


@FAST
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 6),
    pick=st.integers(0, 10**6),
    delta=st.integers(1, 50),
    text=st.booleans(),
)
def test_one_changed_normative_value_fails_naming_frame_and_fap(seed, n, pick, delta, text):
    e = random_frames(seed, n)
    cells = np.argwhere(e.status != FREE)
    k, j = (int(x) for x in cells[pick % len(cells)])
    g = e.copy()
    if j >= 2:
        g.values[k, j] += delta
    else:
        g.high[k, 0 if j == 0 else 4] += delta
    r = compare_faps(e, g, text_output=text)
    assert r.outcome is Outcome.FAIL
    d = r.first_difference
    assert (d["frame"], d["fap"], d["name"]) == (k, j + 1, name_of(j + 1))
    assert d["frame_number"] == int(e.frame_number[k])
    assert f"frame {k} (frame_number {int(e.frame_number[k])})" in r.message
    assert f"FAP {j + 1} {name_of(j + 1)}" in r.message
    assert r.metrics["frames_differing"] == 1 and r.series["faps_differing"][k] == 1.0
    if j >= 2:
        assert d["expected"] == int(e.values[k, j]) and d["got"] == int(e.values[k, j]) + delta
        assert r.metrics["max_abs_diff"] == delta
    if not text:  # agrees with the FapFrames comparison of the bitstream stage
        assert first_difference(e, g)["frame"] == k


@FAST
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 6), pick=st.integers(0, 10**6), text=st.booleans())
def test_changed_free_values_pass(seed, n, pick, text):
    e = random_frames(seed, n)
    e.status[pick % n, :] = FREE  # a whole frame FREE: also FAP 1/2 -> high-level fields free
    g = e.copy()
    free = e.status == FREE
    g.values[free] += 7
    g.high[pick % n] += 3
    assert compare_faps(e, g, text_output=text).outcome is Outcome.PASS


def test_status_matters_for_npz_but_not_for_text():
    e = synthetic_sequence(4, faps=[3, 4, 19, 31])
    g = e.copy()
    g.status[2, 30] = RETAINED  # FAP 31 held instead of set: same value
    r = compare_faps(e, g, text_output=False)
    assert r.outcome is Outcome.FAIL
    fd = dict(r.first_difference)
    assert fd.pop("faps") == [{"fap": 31, "name": name_of(31), "frames": 1, "first": 2, "last": 2}]
    assert fd == {
        "frame": 2,
        "frame_number": 2,
        "fap": 31,
        "name": name_of(31),
        "what": "status",
        "expected": "SET",
        "got": "RETAINED",
    }
    assert compare_faps(e, g, text_output=True).outcome is Outcome.PASS


def test_every_differing_fap_is_listed_with_counts():
    """A decoder that copies FAP 4 into FAP 3 in every frame: the pattern shows in the list of
    differing FAPs, not only the first difference."""
    e = synthetic_sequence(10, faps=[3, 4, 19, 31])
    g = e.copy()
    g.values[:, 2] = g.values[:, 3]
    g.values[5:8, 18] += 1  # and FAP 19 off in frames 5..7
    r = compare_faps(e, g, text_output=False)
    diff3 = int((e.values[:, 2] != e.values[:, 3]).sum())
    rows = {x["fap"]: x for x in r.first_difference["faps"]}
    assert rows[3]["frames"] == diff3 and rows[19] == {
        "fap": 19,
        "name": name_of(19),
        "frames": 3,
        "first": 5,
        "last": 7,
    }
    assert "differing FAPs: 3 " in r.message and "19 " in r.message


def test_text_output_missing_value():
    e = synthetic_sequence(3, faps=[3, 31])
    g = e.copy()
    g.status[1, 2] = FREE
    r = compare_faps(e, g, text_output=True)
    assert r.outcome is Outcome.FAIL
    assert r.first_difference["what"] == "missing" and r.first_difference["fap"] == 3
    assert "expected a value" in r.message and "got none" in r.message and "open_jaw" in r.message


def test_frame_count_and_frame_number_differences():
    e = synthetic_sequence(5, faps=[3])
    r = compare_faps(e, e.select(slice(0, 3)), text_output=False)
    assert r.outcome is Outcome.FAIL and r.first_difference["what"] == "frame count"
    assert "expected 5, got 3" in r.message and r.metrics["frames_compared"] == 3
    g = e.copy()
    g.frame_number[3] += 1
    r = compare_faps(e, g, text_output=True)
    assert r.first_difference["what"] == "frame number" and r.first_difference["frame"] == 3
    # an earlier value difference is reported before the count difference
    g = e.select(slice(0, 4)).copy()
    g.values[1, 2] += 1
    r = compare_faps(e, g, text_output=False)
    assert r.first_difference["frame"] == 1 and "frame count" in r.message


def test_result_is_json_serialisable():
    e = random_frames(1, 3)
    g = e.copy()
    g.values[e.status != FREE] += 1
    json.dumps(compare_faps(e, g, text_output=False).to_json(), allow_nan=False)


# ----------------------------------------------------------------------------- FAP outputs
def test_load_output_faps_round_trips(tmp_path):
    e = synthetic_sequence(6, faps=[3, 4, 19, 20, 48])
    e.save_npz(tmp_path / "out.npz")
    assert compare_faps(e, load_output_faps(tmp_path / "out.npz"), text_output=False).outcome is Outcome.PASS
    write_fap_file(tmp_path / "out.fap", e)
    got = load_output_faps(tmp_path / "out.fap")
    assert compare_faps(e, got, text_output=True).outcome is Outcome.PASS
    (tmp_path / "misnamed.fap").write_bytes((tmp_path / "out.npz").read_bytes())  # sniffed as zip
    assert compare_faps(e, load_output_faps(tmp_path / "misnamed.fap"), text_output=False).outcome is Outcome.PASS


def _npz(path: Path, **arrays) -> Path:
    with open(path, "wb") as f:
        np.savez(f, **arrays)
    return path


def _fapframes_arrays(n=3, **changes):
    f = synthetic_sequence(n, faps=[3, 4])
    a = {
        "format": np.array("fbaconf.FapFrames/1"),
        "values": f.values,
        "status": f.status,
        "high": f.high,
        "frame_number": f.frame_number,
        "time_ms": f.time_ms,
        "frame_rate": np.float64(25.0),
        "gender": np.int64(0),
    }
    a.update(changes)
    return {k: v for k, v in a.items() if v is not None}


def _huge_header_npz(path: Path) -> Path:
    """A valid zip whose values.npy header claims a (10**9, 68) int32 array."""
    hdr = io.BytesIO()
    np.lib.format.write_array_header_1_0(hdr, {"descr": "<i4", "fortran_order": False, "shape": (10**9, 68)})
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("format.npy", _npy(np.array("fbaconf.FapFrames/1")))
        z.writestr("values.npy", hdr.getvalue() + b"\0" * 64)
    return path


def _npy(a) -> bytes:
    b = io.BytesIO()
    np.save(b, a)
    return b.getvalue()


GARBAGE_FAPS = {
    "binary junk .npz": lambda p: (p / "a.npz").write_bytes(b"\x00\xffjunk" * 50) and p / "a.npz",
    "binary junk .fap": lambda p: (p / "a.fap").write_bytes(bytes(range(256)) * 4) and p / "a.fap",
    "empty .fap": lambda p: (p / "e.fap").write_bytes(b"") or p / "e.fap",
    "text not fap": lambda p: (p / "t.fap").write_text("hello world\nthis is not a fap file\n") and p / "t.fap",
    "truncated zip": lambda p: (p / "t.npz").write_bytes(synthetic_sequence(5).to_npz_bytes()[:300]) and p / "t.npz",
    "no format tag": lambda p: _npz(p / "n.npz", **_fapframes_arrays(format=None)),
    "wrong format tag": lambda p: _npz(p / "w.npz", **_fapframes_arrays(format=np.array("fbaconf.FaceState/1"))),
    "missing status": lambda p: _npz(p / "m.npz", **_fapframes_arrays(status=None)),
    "values 67 wide": lambda p: _npz(p / "s.npz", **_fapframes_arrays(values=np.zeros((3, 67), np.int32))),
    "status rows differ": lambda p: _npz(p / "r.npz", **_fapframes_arrays(status=np.zeros((2, 68), np.uint8))),
    "float values": lambda p: _npz(p / "f.npz", **_fapframes_arrays(values=np.zeros((3, 68)))),
    "status 7": lambda p: _npz(p / "s7.npz", **_fapframes_arrays(status=np.full((3, 68), 7, np.uint8))),
    "values beyond int32": lambda p: _npz(p / "big.npz", **_fapframes_arrays(values=np.full((3, 68), 2**40, np.int64))),
    "NaN time": lambda p: _npz(p / "nan.npz", **_fapframes_arrays(time_ms=np.array([0.0, np.nan, 80.0]))),
    "NaN frame rate": lambda p: _npz(p / "fr.npz", **_fapframes_arrays(frame_rate=np.float64(np.nan))),
    "frame rate array": lambda p: _npz(p / "fra.npz", **_fapframes_arrays(frame_rate=np.ones(3))),
    "string values": lambda p: _npz(p / "str.npz", **_fapframes_arrays(values=np.array([["a"] * 68] * 3))),
    "huge dims": lambda p: _huge_header_npz(p / "h.npz"),
    "directory": lambda p: p,
    "missing file": lambda p: p / "nope.npz",
}


@pytest.mark.parametrize("case", sorted(GARBAGE_FAPS))
def test_garbage_fap_outputs_raise_output_error(tmp_path, case):
    path = Path(GARBAGE_FAPS[case](tmp_path))
    with pytest.raises(OutputError) as ei:
        load_output_faps(path)
    assert str(path) in str(ei.value) and ei.value.file == str(path)


def test_object_arrays_are_refused_without_unpickling(tmp_path):
    a = _fapframes_arrays()
    a["values"] = np.array([[object()] * 68] * 3, dtype=object)
    buf = io.BytesIO()
    np.savez(buf, **a)  # pickled member
    (tmp_path / "o.npz").write_bytes(buf.getvalue())
    with pytest.raises(OutputError, match="dtype"):
        load_output_faps(tmp_path / "o.npz")


def test_output_size_cap(tmp_path):
    synthetic_sequence(50).save_npz(tmp_path / "x.npz")
    with pytest.raises(OutputError, match="limit"):
        load_output_faps(tmp_path / "x.npz", max_bytes=1000)
    # a highly compressible member (zip bomb shape) is refused on its decompressed size
    _npz(tmp_path / "bomb.npz", **_fapframes_arrays(values=np.zeros((20000, 68), np.int32)))
    with pytest.raises(OutputError, match="limit"):
        load_output_faps(tmp_path / "bomb.npz", max_bytes=200_000)


@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_mutated_outputs_never_raise_anything_else(tmp_path_factory, data):
    good = synthetic_sequence(3, faps=[3, 4]).to_npz_bytes()
    blob = bytearray(good)
    for _ in range(data.draw(st.integers(1, 8))):
        blob[data.draw(st.integers(0, len(blob) - 1))] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(0, len(blob)))
    d = tmp_path_factory.mktemp("mut")
    for name, content in (
        ("m.npz", bytes(blob[:cut] if data.draw(st.booleans()) else blob)),
        ("m.fap", data.draw(st.binary(max_size=300))),
    ):
        (d / name).write_bytes(content)
        try:
            out = load_output_faps(d / name)
        except OutputError:
            continue
        assert isinstance(out, FapFrames)


# ----------------------------------------------------------------------------- vertices
def _verts(seed=0, F=3, N=40):
    return np.random.default_rng(seed).normal(0.0, 50.0, size=(F, N, 3))


@FAST
@given(seed=st.integers(0, 2**32 - 1), frac=st.floats(0.0, 0.9), F=st.integers(1, 4))
def test_vertex_perturbation_within_tolerance_passes(seed, frac, F):
    e = _verts(seed, F)
    g = e.copy()
    rng = np.random.default_rng(seed + 1)
    k, v = int(rng.integers(F)), int(rng.integers(e.shape[1]))
    direction = rng.normal(size=3)
    g[k, v] += direction / np.linalg.norm(direction) * 0.01 * frac
    r = compare_vertices(e, g, max_tol=0.01, rms_tol=0.01)
    assert r.outcome is Outcome.PASS and r.stage == "vertices"
    assert r.metrics["max_error"] == pytest.approx(0.01 * frac, abs=1e-9)
    assert len(r.series["max_error"]) == F and len(r.series["rms_error"]) == F


@FAST
@given(seed=st.integers(0, 2**32 - 1), factor=st.floats(1.5, 1000.0), F=st.integers(1, 4))
def test_vertex_perturbation_over_tolerance_fails_naming_it(seed, factor, F):
    e = _verts(seed, F)
    g = e.copy()
    rng = np.random.default_rng(seed + 1)
    k, v = int(rng.integers(F)), int(rng.integers(e.shape[1]))
    g[k, v, 1] += 0.01 * factor
    parts = [("skin", 0, 30), ("teeth", 30, 10)]
    r = compare_vertices(e, g, max_tol=0.01, rms_tol=1e9, part_of=part_namer(parts), what="feature_points")
    assert r.outcome is Outcome.FAIL and r.stage == "feature_points"
    d = r.first_difference
    assert (d["frame"], d["vertex"], d["part"]) == (k, v, "skin" if v < 30 else "teeth")
    assert d["expected"] == e[k, v].tolist() and d["got"] == g[k, v].tolist()
    assert f"frame {k}, vertex {v} ({d['part']})" in r.message


def test_vertex_rms_and_shape_and_nonfinite():
    e = _verts()
    r = compare_vertices(e, e + np.array([0.0, 0.005, 0.0]), max_tol=0.01, rms_tol=0.002)
    assert r.outcome is Outcome.FAIL and r.first_difference["what"] == "rms" and r.first_difference["frame"] == 0
    assert compare_vertices(e, e.copy(), max_tol=0.0, rms_tol=0.0).outcome is Outcome.PASS
    r = compare_vertices(e, e[:, :-1], max_tol=1, rms_tol=1)
    assert r.outcome is Outcome.FAIL and "vertex count" in r.message and "expected 40, got 39" in r.message
    r = compare_vertices(e, e[:2], max_tol=1, rms_tol=1)
    assert r.outcome is Outcome.FAIL and "frame count" in r.message
    assert compare_vertices(e, e[..., :2], max_tol=1, rms_tol=1).first_difference["what"] == "coordinate count"
    assert compare_vertices(e, e[0], max_tol=1, rms_tol=1).outcome is Outcome.FAIL
    g = e.copy()
    g[2, 7, 0] = np.nan
    r = compare_vertices(e, g, max_tol=1, rms_tol=1)
    assert r.outcome is Outcome.FAIL and (r.first_difference["frame"], r.first_difference["vertex"]) == (2, 7)
    assert compare_vertices(g, e, max_tol=1, rms_tol=1).outcome is Outcome.ERROR  # broken golden


def test_load_output_vertices(tmp_path):
    state = animate(synthetic_sequence(2, faps=[3, 19]))
    save_npz(state, tmp_path / "state.npz")
    v = load_output_vertices(tmp_path / "state.npz")
    assert v.dtype == np.float64 and np.array_equal(v, state.vertices)
    fp = load_output_vertices(tmp_path / "state.npz", key="extra_feature_points")
    assert np.array_equal(fp, state.extras["feature_points"])
    r = compare_vertices(state.vertices, v, max_tol=0, rms_tol=0, part_of=part_namer(state.parts))
    assert r.outcome is Outcome.PASS
    g = v.copy()
    g[1, 200] += 1.0
    r = compare_vertices(state.vertices, g, max_tol=0.01, rms_tol=0.1, part_of=part_namer(state.parts))
    assert r.first_difference["part"] == "Skin"
    # any npz with a float vertices array
    _npz(tmp_path / "plain.npz", vertices=np.zeros((2, 5, 3), np.float32))
    assert load_output_vertices(tmp_path / "plain.npz").shape == (2, 5, 3)


@pytest.mark.parametrize(
    "arrays, match",
    [
        ({"vertices": np.zeros((2, 5, 2))}, "shape"),
        ({"vertices": np.zeros((10, 3))}, "shape"),
        ({"vertices": np.zeros((2, 5, 3), np.int32)}, "dtype"),
        ({"vertices": np.array([[[0.0, np.inf, 0.0]]])}, "frame 0, vertex 0"),
        ({"verts": np.zeros((2, 5, 3))}, "no array 'vertices'"),
    ],
)
def test_garbage_vertex_outputs_raise_output_error(tmp_path, arrays, match):
    p = _npz(tmp_path / "v.npz", **arrays)
    with pytest.raises(OutputError, match=match):
        load_output_vertices(p)
    (tmp_path / "j.npz").write_bytes(b"PK\x03\x04" + b"\x00" * 100)
    with pytest.raises(OutputError):
        load_output_vertices(tmp_path / "j.npz")


# ----------------------------------------------------------------------------- images
@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> list[Path]:
    out = tmp_path_factory.mktemp("golden")
    state = animate(synthetic_sequence(2, faps=[3, 4, 5, 19, 20, 31, 32]))
    return render_frames(state, Scenario.default().with_(width=64, height=64), out)


def _read8(path: Path) -> np.ndarray:
    import OpenImageIO as oiio  # noqa: PLC0415 (image I/O loads on first use)

    buf = oiio.ImageBuf(str(path))
    return np.asarray(buf.get_pixels(oiio.UINT8))


def _write8(path: Path, px: np.ndarray) -> Path:
    import OpenImageIO as oiio  # noqa: PLC0415 (image I/O loads on first use)

    out = oiio.ImageOutput.create(str(path))
    h, w, c = px.shape
    out.open(str(path), oiio.ImageSpec(w, h, c, oiio.UINT8))
    out.write_image(np.ascontiguousarray(px, np.uint8))
    out.close()
    return path


TOL = ImageTolerances.defaults()


def test_identical_images_pass(rendered, tmp_path):
    r = compare_images(rendered, list(rendered), TOL, tmp_path / "art")
    assert r.outcome is Outcome.PASS and r.stage == "images" and not r.artefacts
    assert r.series["psnr"] == [100.0, 100.0] and r.series["deltae_mean"] == [0.0, 0.0]
    assert not (tmp_path / "art").exists()
    json.dumps(r.to_json(), allow_nan=False)


def test_one_pixel_changed_hugely_is_no_verdict(rendered, tmp_path):
    """No verdict from a single pixel: it is counted and reported, not failed."""
    px = _read8(rendered[1])
    ys, xs = np.nonzero((px == px[0, 0]).all(axis=2))  # a background pixel
    x, y = int(xs[len(xs) // 2]), int(ys[len(ys) // 2])
    px[y, x] = 255
    r = compare_images(rendered, [rendered[0], _write8(tmp_path / "f1.png", px)], TOL, tmp_path / "art")
    assert r.outcome is Outcome.PASS and r.metrics["violations_max"] == 1 and r.series["violations"] == [0, 1]
    assert "1 violating pixel(s)" in r.message


def test_a_visible_blob_fails_naming_it(rendered, tmp_path):
    """A 5 x 5 white blob on the background (25 pixels > the limit of max(8, 0.2 % of 64 x 64))."""
    px = _read8(rendered[1])
    bg = (px == px[0, 0]).all(axis=2)
    ys, xs = np.nonzero(bg[:-4, :-4] & bg[4:, 4:] & bg[4:, :-4] & bg[:-4, 4:])
    x, y = int(xs[0]), int(ys[0])
    expected_rgb = px[y + 2, x + 2].tolist()
    px[y : y + 5, x : x + 5] = 255
    got = [rendered[0], _write8(tmp_path / "f1.png", px)]
    r = compare_images(rendered, got, TOL, tmp_path / "art", frames=[10, 11], relative_to=tmp_path)
    assert r.outcome is Outcome.FAIL and r.metrics["violations_max"] == 25, r.message
    d = r.first_difference
    assert d["frame"] == 11 and x <= d["pixel"][0] < x + 5 and y <= d["pixel"][1] < y + 5
    assert d["got"] == [255, 255, 255] and d["expected"] == expected_rgb
    assert "25 pixel(s) differ" in r.message and "limit 8 pixels" in r.message
    assert set(r.artefacts) == {"frame11_expected", "frame11_got", "frame11_diff"}
    for rel in r.artefacts.values():
        assert not Path(rel).is_absolute() and (tmp_path / rel).is_file()
    assert np.array_equal(_read8(tmp_path / r.artefacts["frame11_got"]), px)
    assert np.array_equal(_read8(tmp_path / r.artefacts["frame11_expected"]), _read8(rendered[1]))
    assert r.series["psnr"][0] == 100.0 and r.series["psnr"][1] < 100.0


def test_small_uniform_noise_passes_and_a_small_uniform_shift_warns(rendered, tmp_path):
    rng = np.random.default_rng(5)
    noisy, shifted = [], []
    for i, p in enumerate(rendered):
        px = _read8(p).astype(np.int16)
        noisy.append(_write8(tmp_path / f"n{i}.png", np.clip(px + rng.integers(-1, 2, size=px.shape), 0, 255)))
        shifted.append(_write8(tmp_path / f"s{i}.png", np.clip(px + 2, 0, 255)))
    # +-1 code of noise on every channel (8-bit rounding of another float pipeline) is no difference
    r = compare_images(rendered, noisy, TOL, tmp_path / "art")
    assert r.outcome is Outcome.PASS and r.metrics["violations_max"] == 0, r.message
    # 2 codes brighter everywhere: under abs_tol (4 codes) per pixel, but a uniform shift of about
    # two thirds of a just-noticeable difference (3 codes of a mid-grey are about 1 L* unit) -> QualityWarning
    r = compare_images(rendered, shifted, TOL, tmp_path / "art")
    assert r.outcome is Outcome.QUALITY_WARNING, r.message
    assert 0.45 < r.metrics["interior_deltae_mean_max"] < 0.75 and r.metrics["violations_max"] == 0
    assert r.first_difference["frame"] == 0 and len(r.first_difference["pixel"]) == 2
    assert Path(r.artefacts["frame0_diff"]).is_absolute() and Path(r.artefacts["frame0_diff"]).is_file()
    loose = ImageTolerances.from_dict(TOL, {"interior_deltae_warn_mean": 0.7})
    assert compare_images(rendered, shifted, loose, tmp_path / "art2").outcome is Outcome.PASS
    # 3 codes: about one just-noticeable difference, visible -> Fail, never hidden in a warning
    three = [
        _write8(tmp_path / f"t{i}.png", np.clip(_read8(p).astype(np.int16) + 3, 0, 255)) for i, p in enumerate(rendered)
    ]
    r = compare_images(rendered, three, TOL, tmp_path / "art3")
    assert r.outcome is Outcome.FAIL and "interior ΔE2000 mean" in r.message, r.message


def test_large_colour_shift_fails(rendered, tmp_path):
    got = [_write8(tmp_path / f"s{i}.png", np.clip(_read8(p).astype(int) + 40, 0, 255)) for i, p in enumerate(rendered)]
    r = compare_images(rendered, got, TOL, tmp_path / "art", max_artefact_frames=1)
    assert r.outcome is Outcome.FAIL and r.metrics["frames_failing"] == 2
    assert len(r.artefacts) == 3  # artefacts capped at one frame


def _disc(cx: float, cy: float, radius: float, size: int = 48, n: int = 16) -> np.ndarray:
    """A bright disc on a dark background, sRGB-encoded 8-bit, with its coverage integrated
    analytically enough (n x n samples per pixel): the ideal image of a sharp silhouette."""
    o = (np.arange(size * n) + 0.5) / n
    X, Y = np.meshgrid(o, o)
    inside = ((X - cx) ** 2 + (Y - cy) ** 2 <= radius**2).astype(np.float64)
    cov = inside.reshape(size, n, size, n).mean(axis=(1, 3))
    lin = 0.02 + cov[:, :, None] * np.array([0.8, 0.55, 0.4])
    return encode_srgb8(lin)


@FAST
@given(
    st.floats(18.0, 30.0), st.floats(18.0, 30.0), st.floats(8.0, 15.0), st.sampled_from([1, 2, 3]), st.floats(-0.2, 0.2)
)
def test_silhouettes_any_sampler_passes_and_a_one_pixel_shift_fails(tmp_path_factory, cx, cy, r, n, jitter):
    """The per-pixel rule on an analytic silhouette: the same disc sampled with 1 x 1 to 3 x 3
    samples at a sub-pixel offset of the pattern (any faithful anti-aliasing) stays within the
    rule... except 1 x 1, which aliases (no anti-aliasing is below the 2 x 2 bound), and the disc
    moved by one whole pixel fails."""
    d = tmp_path_factory.mktemp("disc")
    golden = _write8(d / "g.png", _disc(cx, cy, r))
    other = _write8(d / "o.png", _disc(cx + jitter / max(n, 2), cy - jitter / max(n, 2), r, n=n))
    shifted = _write8(d / "s.png", _disc(cx + 1.0, cy, r))
    verdict = compare_images([golden], [other], TOL, d / "a").outcome
    if n >= 2:
        assert verdict is Outcome.PASS
    assert compare_images([golden], [shifted], TOL, d / "b").outcome is Outcome.FAIL


def test_float_exr_output_matching_the_png_passes(rendered, tmp_path):
    got = [write_exr(tmp_path / f"f{i}.exr", read_linear_rgb(p)) for i, p in enumerate(rendered)]
    assert compare_images(rendered, got, TOL, tmp_path / "art").outcome is Outcome.PASS


def test_image_size_mismatch_missing_and_garbage_fail(rendered, tmp_path):
    small = _write8(tmp_path / "small.png", _read8(rendered[0])[:32])
    r = compare_images(rendered[:1], [small], TOL, tmp_path / "art")
    assert r.outcome is Outcome.FAIL and "height expected 64, got 32" in r.message
    assert r.first_difference["what"] == "size"
    rgba = _write8(tmp_path / "rgba.png", np.concatenate([_read8(rendered[0]), np.full((64, 64, 1), 255)], axis=2))
    assert "channels expected 3, got 4" in compare_images(rendered[:1], [rgba], TOL, tmp_path / "a").message
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 20)
    r = compare_images(rendered[:1], [junk], TOL, tmp_path / "art")
    assert r.outcome is Outcome.FAIL and r.first_difference["what"] == "unreadable" and "junk.png" in r.message
    trunc = tmp_path / "trunc.png"
    trunc.write_bytes(rendered[0].read_bytes()[:200])
    assert compare_images(rendered[:1], [trunc], TOL, tmp_path / "art").outcome is Outcome.FAIL
    r = compare_images(rendered, [rendered[0], tmp_path / "absent.png"], TOL, tmp_path / "art")
    assert r.outcome is Outcome.FAIL and r.first_difference["frame"] == 1
    assert r.series["psnr"][0] == 100.0 and np.isnan(r.series["psnr"][1]) and np.isnan(r.series["deltae_mean"][1])
    r = compare_images(rendered, rendered[:1], TOL, tmp_path / "art")
    assert r.outcome is Outcome.FAIL and r.first_difference["what"] == "missing"
    r = compare_images(rendered[:1], rendered, TOL, tmp_path / "art")
    assert r.outcome is Outcome.FAIL and r.first_difference["what"] == "image count"
    r = compare_images([tmp_path / "no-golden.png"], rendered[:1], TOL, tmp_path / "art")
    assert r.outcome is Outcome.ERROR


# ----------------------------------------------------------------------------- report contract
def test_stage_results_fit_the_run_report_schema(rendered, tmp_path):
    import jsonschema  # noqa: PLC0415 (test-only dependency)

    schema_path = Path(__file__).resolve().parents[2] / "harness" / "data" / "run-report.schema.json"
    schema = json.loads(schema_path.read_text("utf-8"))
    stage_schema = {"$defs": schema["$defs"], "$ref": "#/$defs/stage"}

    def nan_as_text(x):  # what the report writer does with non-finite numbers
        if isinstance(x, float) and not np.isfinite(x):
            return "NaN" if np.isnan(x) else ("Infinity" if x > 0 else "-Infinity")
        if isinstance(x, dict):
            return {k: nan_as_text(v) for k, v in x.items()}
        if isinstance(x, list):
            return [nan_as_text(v) for v in x]
        return x

    e = random_frames(3, 4)
    g = e.copy()
    g.values[e.status != FREE] += 1
    results = [
        compare_faps(e, g, text_output=True),
        compare_faps(e, e.select(slice(0, 2)), text_output=False),
        compare_vertices(_verts(), _verts(1), max_tol=0.1, rms_tol=0.1),
        compare_vertices(_verts(), _verts()[:, :3], max_tol=0.1, rms_tol=0.1),
        compare_images(rendered, [rendered[0], tmp_path / "absent.png"], TOL, tmp_path / "art"),
    ]
    for r in results:
        jsonschema.validate(nan_as_text(r.to_json()), stage_schema)


def test_plane_times_are_compared_for_npz_output_only():
    exp = synthetic_sequence(12, 25.0, visemes=False, expressions=False)
    got = exp.copy()
    got.time_ms = got.time_ms.copy()
    got.time_ms[5:] += 40.0  # a skipped frame not accounted for in the times
    r = compare_faps(exp, got, text_output=False)
    assert r.outcome.value == "Fail"
    assert r.first_difference["frame"] == 5 and r.first_difference["what"] == "time_ms"
    got.time_ms[5:] -= 40.0 - 0.2  # within the 0.5 ms tolerance
    assert compare_faps(exp, got, text_output=False).outcome.value == "Pass"
    got.time_ms[5:] += 100.0
    assert compare_faps(exp, got, text_output=True).outcome.value == "Pass"


def _player_golden():
    """Three frames at 30 Hz (times 0, 33.33, 66.67 ms): FAP 3 sent in frame 0 and held; FAP 4
    first sent in frame 1 (no value in frame 0); FAP 5 never sent."""
    e = FapFrames.empty(3, 30.0)
    e.status[:, 2] = [SET, RETAINED, RETAINED]
    e.values[:, 2] = 100
    e.status[:, 3] = [FREE, SET, SET]
    e.values[1:, 3] = [40, 50]
    return e


def _player_state(e):
    """What a player writes as .npz: its state, SET wherever a value is held."""
    g = e.copy()
    g.status[e.status != FREE] = SET
    return g


def test_player_npz_state_times_and_presence_are_compared():
    e = _player_golden()
    assert compare_faps(e, _player_state(e), text_output=False, player=True).outcome.value == "Pass"
    late = _player_state(e)
    late.time_ms[2] = 66.0  # truncated to whole ms: 0.67 ms off (tolerance 0.5)
    r = compare_faps(e, late, text_output=False, player=True)
    assert r.outcome.value == "Fail" and r.first_difference["what"] == "time_ms"
    held_early = _player_state(e)
    held_early.status[0, 3] = SET  # a value for FAP 4 before it was ever sent
    r = compare_faps(e, held_early, text_output=False, player=True)
    assert r.outcome.value == "Fail" and r.first_difference["fap"] == 4
    dropped = _player_state(e)
    dropped.status[1, 2] = FREE  # the held FAP 3 left out of the state
    r = compare_faps(e, dropped, text_output=False, player=True)
    fd = r.first_difference
    assert r.outcome.value == "Fail" and (fd["frame"], fd["fap"], fd["what"], fd["expected"], fd["got"]) == (
        1,
        3,
        "missing",
        100,
        None,
    )


@pytest.mark.parametrize("declared, ok", [(2, True), (3, False), (0, False)])
def test_fap_output_header_count_must_match(tmp_path, declared, ok):
    """A decoder's .fap output must declare the frames it holds (readers size by it)."""
    m = " ".join(["0", "0", "1"] + ["0"] * 65)
    p = tmp_path / "out.fap"
    p.write_text(f"2.1 out 25 {declared}\n{m}\n0 10\n{m}\n1 20\n")
    if ok:
        assert list(load_output_faps(p).values[:, 2]) == [10, 20]
    else:
        with pytest.raises(OutputError) as e:
            load_output_faps(p)
        assert e.value.rule == "output-fap-count" and f"says {declared} frame(s)" in str(e.value)
