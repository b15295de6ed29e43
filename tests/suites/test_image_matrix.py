"""The image stage against renderers it has never seen: every faithful renderer —
whatever its sampler — passes every image case without a QualityWarning, and every wrong
renderer (a realistic player bug each) fails at least one case, so it cannot certify.

The renderers are the reference rasteriser with one thing changed (tests/suites/image_variants.py);
the OpenGL ones are in tests/suites/test_glrender.py."""

from __future__ import annotations

import pytest
from image_variants import FAITHFUL, WRONG, image_cases, run_variant, shared_cases

from fbaconf.conformance.suite import load_suites
from fbaconf.harness.results import Outcome


@pytest.fixture(scope="module")
def cases():
    cs = image_cases()
    assert len(cs) >= 39  # 13 Calibration/Predictable cases x 3 scenarios
    return cs


@pytest.fixture(scope="module")
def states():
    return {}


def test_every_calibration_and_predictable_case_compares_images_under_three_scenarios(cases):
    decode = [
        c
        for s in load_suites()
        if s.claim.split("@")[0] in ("calibration", "predictable")
        for c in s.cases
        if c.kind == "decode" and "faps" in c.stages
    ]
    assert decode and all("images" in c.stages for c in decode)
    ids = {(c.suite, c.id) for c in cases}
    for c in decode:
        assert {(c.suite, c.id), (c.suite, f"{c.id}-three-quarter"), (c.suite, f"{c.id}-flat-culled")} <= ids
        assert len(c.goldens["images"]) >= 3  # first, middle, last (+ the extreme frame)


# ss2 renders every case: in three parts, so that the workers share it
PARTS = [(v, part, 3 if v == FAITHFUL[0] else 1) for v in FAITHFUL for part in range(3 if v == FAITHFUL[0] else 1)]


@pytest.mark.parametrize(("variant", "part", "parts"), PARTS, ids=[f"{v}-{p + 1}of{n}" for v, p, n in PARTS])
def test_faithful_renderers_pass_the_image_cases(variant, part, parts, cases, states, tmp_path):
    """ss2 passes every image case; ss3, ss4, rgss4 and msaa8 a quarter each, in turn
    (image_variants.shared_cases): every case by two sampling patterns."""
    bad = {}
    for c in shared_cases(FAITHFUL, variant, cases)[part::parts]:
        r = run_variant(c, variant, tmp_path / c.suite / c.id, states)
        if r.outcome is not Outcome.PASS:
            bad[c.full_id] = r.message
    assert not bad, bad


@pytest.mark.parametrize("variant", WRONG)
def test_wrong_renderers_fail(variant, cases, states, tmp_path):
    # the textured cases first: texture bugs show only there
    order = sorted(cases, key=lambda c: "limits" not in c.id)
    for c in order:
        r = run_variant(c, variant, tmp_path / c.suite / c.id, states)
        if r.outcome is Outcome.FAIL:
            return
    pytest.fail(f"{variant} passes every image case")
