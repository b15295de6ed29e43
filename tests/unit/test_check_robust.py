"""The checker never raises and never fails internally, on any input: random bytes, bytes
behind a face_object_start_code, and valid streams with flipped bits, truncations and
spliced pieces (both coding modes)."""

from __future__ import annotations

import json
from importlib import resources

import jsonschema
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from fbaconf import rules as R
from fbaconf.bitstreams.bitedit import flip_bit, splice, truncate_bits
from fbaconf.generators.suite_scenes import make_scene
from fbaconf.profiles.checker import SceneSummary, analyse
from fbaconf.profiles.cli import build_report
from fbaconf.profiles.sample_streams import make_stream
from fbaconf.scenes import bt

SEEDS = [
    make_stream(n=12, faps=range(3, 30), time_codes=True, intra_period=4),
    make_stream(n=12, faps=range(3, 69), plane_start_codes="none"),
    make_stream(n=20, faps=range(3, 20), coding="dct"),
]
VALIDATOR = jsonschema.Draft202012Validator(
    json.loads(resources.files("fbaconf.profiles").joinpath("data", "check-report.schema.json").read_text("utf-8"))
)
SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _ok(data: bytes, **kw) -> None:
    rep = analyse(data, smallest_claim=True, **kw)
    assert all(d.code in R.CODES for d in rep.diagnostics)
    assert R.CHECK_INTERNAL not in {d.code for d in rep.diagnostics}, [str(d) for d in rep.diagnostics]
    doc, status = build_report(rep, file=None, smallest_claim=True)
    assert status in (0, 1, 2)
    VALIDATOR.validate(json.loads(json.dumps(doc)))


@SETTINGS
@given(st.binary(max_size=300))
def test_random_bytes(data):
    _ok(data)


@SETTINGS
@given(st.binary(max_size=300))
def test_random_bytes_after_a_start_code(data):
    _ok(b"\x00\x00\x01\xba" + data, claim="simple@1")


@SETTINGS
@given(st.integers(0, len(SEEDS) - 1), st.lists(st.integers(0, 10**9), min_size=1, max_size=6))
def test_flipped_bits(which, positions):
    data = SEEDS[which]
    for p in positions:
        data = flip_bit(data, p % (len(data) * 8))
    _ok(data)


@SETTINGS
@given(st.integers(0, len(SEEDS) - 1), st.integers(0, 10**9))
def test_truncations(which, cut):
    data = SEEDS[which]
    _ok(truncate_bits(data, cut % (len(data) * 8)))


@SETTINGS
@given(
    st.integers(0, len(SEEDS) - 1),
    st.integers(0, len(SEEDS) - 1),
    st.integers(0, 10**9),
    st.integers(0, 10**9),
    st.integers(0, 10**9),
)
def test_splices(a, b, x, y, z):
    da, db = SEEDS[a], SEEDS[b]
    na, nb = len(da) * 8, len(db) * 8
    cut = x % na
    lo, hi = sorted((y % nb, z % nb))
    _ok(splice((da, 0, cut), (db, lo, hi)))


@pytest.mark.parametrize("scene", [SceneSummary(faces=3, tools={"unknown_tool": "X"}), "/nonexistent/s.bt"])
def test_odd_scenes(scene):
    _ok(SEEDS[0], scene=scene, claim="predictable@2")


def test_non_bytes_input():
    rep = analyse(bytearray(SEEDS[0]))
    assert rep.diagnostics == []


@pytest.mark.parametrize(
    "borders, why",
    [
        ([-100, 0, 0, 100], "strictly increasing"),
        ([-100, 50, 10, 100], "strictly increasing"),
        ([-100, 40, 100], "must be 0"),
    ],
)
def test_scene_interval_borders_are_checked(tmp_path, borders, why):
    """The checker applies the engine's FaceDefMesh border rules (found by the independent mutant
    ind-anim-borders-equal-accepted: the checker passed a scene the engine refuses)."""
    scene, _files = make_scene("grid:equal-borders")
    want = f"intervalBorders [{', '.join(map(str, borders))}]"
    text = bt.write(scene).replace("intervalBorders [-100, 0, 0, 100]", want)
    assert want in text
    p = tmp_path / "s.bt"
    p.write_text(text)
    bad = [d for d in analyse(SEEDS[0], scene=p).diagnostics if d.code == "FAP-SCENE-002"]
    assert bad and why in bad[0].message and "intervalBorders" in str(bad[0].location)
