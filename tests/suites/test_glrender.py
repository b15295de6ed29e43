"""The image stage against real OpenGL renderers (examples/glrender): faithful GL renderers
(supersampling, multisampling) pass every image case, and every wrong one — a realistic player
bug each, rendered by the same GL program — fails at least one case.

Skipped (with the reason) when moderngl is not installed or no OpenGL 3.3 context can be made
(headless EGL; on Debian: libegl1 libegl-mesa0 libgl1-mesa-dri, then ``pip install moderngl``).
The software counterparts (the reference rasteriser with one thing changed) are in
tests/suites/test_image_matrix.py."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from image_variants import shared_cases

from fbaconf.rendering.scenario import Scenario

GLDIR = Path(__file__).resolve().parents[2] / "examples" / "glrender"

moderngl = pytest.importorskip("moderngl", reason="moderngl is not installed (pip install moderngl)")
sys.path.insert(0, str(GLDIR))
import glrender  # noqa: E402
import matrix  # noqa: E402

from fbaconf.harness.results import Outcome  # noqa: E402

# Faithful GL renderers that fail the comparison, with why (measured; see the README's matrix).
# None today: plain MSAA (no centroid) failed the textured cases until their texture lost its
# seams. Not strict: a renderer listed here that passes is reported as XPASS.
KNOWN_FAITHFUL_FAILS: dict[str, str] = {}


@pytest.fixture(scope="module")
def ctx():
    try:
        return glrender.gl_context()
    except glrender.NotSupported as e:
        pytest.skip(f"no OpenGL context: {e}")


@pytest.fixture(scope="module")
def cases():
    cs = matrix.image_cases()
    assert len(cs) >= 39
    return cs


@pytest.fixture(scope="module")
def states():
    return {}


def _faithful_params():
    """(variant, part, parts): the first (coarsest) renders every case, in two parts the workers share."""
    out = []
    for v in glrender.FAITHFUL:
        n = 2 if v == glrender.FAITHFUL[0] else 1
        marks = [pytest.mark.xfail(reason=KNOWN_FAITHFUL_FAILS[v], strict=False)] if v in KNOWN_FAITHFUL_FAILS else []
        out += [pytest.param(v, p, n, marks=marks, id=f"{v}-{p + 1}of{n}") for p in range(n)]
    return out


def test_camera_fit_is_the_documented_one(ctx, cases, states):
    """glrender fits the camera itself (docs/rendering.md); it must agree with the scenario's rule."""
    for c in cases[::3]:
        st = matrix.case_state(c, states)
        sc = Scenario.load(c.input_path("scenario"))
        ref = sc.resolve_camera(st.vertices[0])
        eye, target, _, near, far = glrender.fit_camera(st.vertices[0], sc, sc.camera.fov_deg)
        assert np.allclose(eye, ref.position, rtol=1e-9, atol=1e-9), c.full_id
        assert np.allclose(target, ref.look_at, rtol=1e-9, atol=1e-9), c.full_id
        assert near == pytest.approx(ref.near) and far == pytest.approx(ref.far)


@pytest.mark.parametrize(("variant", "part", "parts"), _faithful_params())
def test_faithful_gl_renderers_pass_the_image_cases(variant, part, parts, ctx, cases, states, tmp_path):
    """ssaa2 passes every image case; the other faithful GL renderers a share each, in turn
    (image_variants.shared_cases): every case by two sampling patterns."""
    bad = {}
    for c in shared_cases(glrender.FAITHFUL, variant, cases)[part::parts]:
        try:
            r = matrix.run_case(c, variant, tmp_path / c.suite / c.id, states)
        except glrender.NotSupported as e:
            pytest.skip(str(e))
        if r.outcome is Outcome.FAIL:
            bad[c.full_id] = r.message
    assert not bad, bad


@pytest.mark.parametrize("variant", glrender.WRONG)
def test_wrong_gl_renderers_fail(variant, ctx, cases, states, tmp_path):
    # textured cases first (texture bugs show only there), then the three-quarter view
    # (asymmetric lighting), then the rest
    order = sorted(cases, key=lambda c: ("limits" not in c.id, "three-quarter" not in c.id))
    seen = []
    for c in order:
        r = matrix.run_case(c, variant, tmp_path / c.suite / c.id, states)
        if r.outcome is Outcome.FAIL:
            return
        seen.append(f"{c.id}: {r.outcome.value}")
    pytest.fail(f"{variant} fails no image case: " + "; ".join(seen))


@pytest.mark.parametrize("variant,expect", [("ssaa2", "Pass"), ("texture-flipped", "Fail")])
def test_manifest_runs_through_the_harness(variant, expect, ctx, tmp_path):
    """The decoder manifest as a user runs it: fbaconf run in a subprocess (sandboxed when
    bubblewrap is available), one textured image case."""
    out = tmp_path / "run"
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "fbaconf",
            "run",
            "--no-progress",
            "--decoder",
            str(GLDIR / "manifests" / f"{variant}.toml"),
            "--suite",
            "predictable-l1-stress",
            "--case",
            "grid-limits-l1",
            "-o",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode in (0, 1), p.stdout + p.stderr
    report = json.loads((out / "report.json").read_text())
    (res,) = [r for r in report["results"] if r["case_id"].endswith("/grid-limits-l1")]
    images = [s for s in res["stages"] if s["stage"] == "images"]
    assert images and images[0]["outcome"] == expect, res["message"]
    assert {s["stage"]: s["outcome"] for s in res["stages"]}.get("vertices") == "Pass"
