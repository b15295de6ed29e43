"""Every FAP visible in the images: a player whose vertices are right but whose picture
ignores one FAP fails an image case, and no scenario colour sits on a rounding tie, so a faithful
float pipeline gets no QualityWarning.

The fap-sweep cases of calibration-l1-core and predictable-l1-core push each FAP in its own frame
group (conformance/data/suites.toml ``sweep``) far enough to move its part by several pixels in
some view (``close-up`` for the small parts: eyelids, irises, pupils, tongue, nostrils). The full
measurement — every FAP dropped in turn, every view, every image case — is
``python tests/suites/image_variants.py --drop`` (minutes); here a sample of the FAPs, each rendered
only in the frame its group occupies (seconds)."""

from __future__ import annotations

import tomllib
from importlib import resources

import numpy as np
import pytest
from image_variants import FLOAT_PIPELINE, image_cases, run_variant

from fbaconf.bitstreams.frames import FREE, FapFrames
from fbaconf.conformance.suite import load_suites
from fbaconf.generators.suites import spec
from fbaconf.harness.results import Outcome
from fbaconf.rendering.images import encode_srgb8, srgb_to_linear
from fbaconf.rendering.scenario import Scenario

SWEEP_SUITES = ("calibration-l1-core", "predictable-l1-core")
VIEWS = ("close-up", None, "three-quarter", "flat-culled")  # None = the case itself (front)
# a sample, split between the two sweeps: the FAPs a drop-one renderer got away with before the
# sweep (lower lip, jaw thrust, tongue tip, nose, left ear), the eyes' smallest parts (lids, iris,
# pupil), a head rotation and the two high-level FAPs
SAMPLE = [("predictable-l1-core", f) for f in (1, 5, 19, 23, 44, 48, 65)] + [
    ("calibration-l1-core", f) for f in (2, 14, 21, 29, 45, 61)
]


def _sweep_groups(suite: str) -> list[list[int]]:
    (c,) = [c for c in spec()["case"] if c["suite"] == suite and c["id"] == "fap-sweep"]
    return c["content"]["sweep"]


@pytest.fixture(scope="module")
def cache():
    """Streams, compiled scenes and animated states shared by the module's tests."""
    return {}


@pytest.fixture(scope="module")
def sweeps():
    cases = {(c.suite, c.id): c for c in image_cases() if c.id.startswith("fap-sweep")}
    return {s: {v: cases[(s, "fap-sweep" if v is None else f"fap-sweep-{v}")] for v in VIEWS} for s in SWEEP_SUITES}


@pytest.mark.parametrize("suite", SWEEP_SUITES)
def test_the_sweep_shows_every_fap_once_in_every_compared_frame(suite, sweeps):
    groups = _sweep_groups(suite)
    faps = sorted(abs(f) for g in groups for f in g)
    assert faps == list(range(1, 69))  # each FAP in exactly one group
    for case in sweeps[suite].values():
        assert case.goldens["images"] == [f"frame_{k:05d}.png" for k in range(len(groups) + 1)]


@pytest.mark.parametrize("suite", SWEEP_SUITES)
def test_each_fap_is_sent_non_zero_in_its_own_frame_only(suite, sweeps):
    """The decoded stream (the golden FAP values): FAP f of group k is non-zero in frame k and 0 in
    every other frame; visemes and expressions are on in frame 1 only."""
    frames = FapFrames.load_npz(sweeps[suite][None].golden_dir() / "faps.npz")
    for k, group in enumerate(_sweep_groups(suite), 1):
        for f in map(abs, group):
            if f <= 2:
                assert np.flatnonzero(frames.status[:, f - 1] != FREE).tolist() == [k], f
            else:
                assert np.flatnonzero(frames.values[:, f - 1]).tolist() == [k], f


@pytest.mark.parametrize(("suite", "fap"), SAMPLE)
def test_a_player_ignoring_one_fap_fails_an_image_case(suite, fap, sweeps, cache, tmp_path):
    """Its vertices right, its picture without FAP ``fap``: rendered only in the frame of the FAP's
    group, one view after the other until one fails."""
    (frame,) = [k for k, g in enumerate(_sweep_groups(suite), 1) if fap in map(abs, g)]
    seen = []
    for view, case in sweeps[suite].items():
        r = run_variant(case, f"drop-fap-{fap}", tmp_path / str(view), cache, only=[frame])
        seen.append((view, r.outcome.value, r.metrics.get("violations_max")))
        if r.outcome is Outcome.FAIL:
            return
    pytest.fail(f"a renderer ignoring FAP {fap} passes frame {frame} of every fap-sweep view: {seen}")


def test_a_float_pipeline_passes_the_sweeps_three_quarter_views(sweeps, cache, tmp_path):
    """The three-quarter scenario's background was on a rounding tie (0.30 x 255 = 76.5): a float32
    encode rounded it one code down over most of the image (a QualityWarning in every such case)."""
    bad = {}
    for suite, views in sweeps.items():
        case = views["three-quarter"]
        r = run_variant(case, FLOAT_PIPELINE, tmp_path / suite, cache, only=[0])
        if r.outcome is not Outcome.PASS:
            bad[case.full_id] = r.message
    assert not bad, bad


def _scenarios():
    data = resources.files("fbaconf.conformance").joinpath("data", "scenarios")
    out = {
        p.name: Scenario.from_dict(tomllib.loads(p.read_text("utf-8")), file=p.name)
        for p in data.iterdir()
        if p.name.endswith(".toml")
    }
    for s in load_suites():
        for c in s.cases:
            p = c.input_path("scenario")
            if p is not None:
                out[f"{s.name}/{p.name}"] = Scenario.load(p)
    return out


def test_no_scenario_colour_on_a_rounding_tie():
    """The background is the one colour an image shows unlit, over large areas: each component x
    255 is at least 0.05 from a half, so a float32 encode gives the reference's 8-bit code."""
    scs = _scenarios()
    assert len(scs) > 50
    for name, sc in scs.items():
        bg = np.asarray(sc.background, np.float64)
        frac = (bg * 255.0) % 1.0
        assert np.all(np.abs(frac - 0.5) >= 0.05), (name, bg * 255.0)
        lin = srgb_to_linear(bg)
        x = lin.astype(np.float32)
        e = np.where(
            x <= np.float32(0.0031308),
            np.float32(12.92) * x,
            np.float32(1.055) * x ** np.float32(1.0 / 2.4) - np.float32(0.055),
        ).astype(np.float32)
        f32 = np.floor(e * np.float32(255.0) + np.float32(0.5)).astype(np.uint8)
        assert f32.tolist() == encode_srgb8(lin).tolist(), name
    # the old three-quarter background: the check is not blind
    assert abs((0.30 * 255.0) % 1.0 - 0.5) < 0.05
