"""Float goldens and their rounding steps: the margin of a value to its rounding
boundary, and golden verify's fallback to a stated tolerance where regeneration on another
platform is not byte for byte."""

from __future__ import annotations

import numpy as np
import pytest

from fbaconf.conformance import precision
from fbaconf.conformance.golden import canonical_npz, compare_regenerated, verify
from fbaconf.conformance.suite import sha256_file
from fbaconf.rendering.images import openimageio, srgb_to_linear, write_png


def test_vertex_margins_by_hand():
    # -112.0234375 = -112 - 3/128 exactly: x / 1e-6 = -112023437.5, on the half-step boundary
    # 1.25 sits mid-step: 0.5e-6 from both boundaries, ulp(1.25) = 2^-52
    u = precision.vertex_ulps_to_flip(np.array([-112.0234375, 1.25, 0.0]))
    assert u[0] == 0.0
    assert u[1] == pytest.approx(0.5e-6 / 2.0**-52, rel=1e-6)
    assert u[2] > 1e300  # zero is infinitely far (in ulps) from +-0.5e-6


def test_image_margins_by_hand():
    # 0.3 x 255 + 0.5 = 77 (the three-quarter scenario's background): on the floor boundary;
    # 0.2 x 255 + 0.5 = 51.5: half a level from both
    u = precision.image_ulps_to_flip(np.array([0.3, 0.2, 0.0]))
    assert u[0] < 4
    assert u[1] == pytest.approx(0.5 / 255 / np.spacing(0.2), rel=1e-6)
    assert u[2] > 1e300


def _npz(path, **arrays):
    np.savez(path, format=np.array("fbaconf.FaceState/1"), **arrays)
    canonical_npz(path)
    return path


def test_npz_within_one_rounding_step(tmp_path):
    v = np.array([[1.0000004, 150.000001], [2.5, -3.25]])
    a = _npz(tmp_path / "a.npz", vertices=v, extra_fap_values=np.array([0.12345649]), time_ms=np.array([40.0]))
    # one step apart after rounding (another platform's value on the other side of a boundary):
    # 0.12345649 -> 0.123456, 0.12345651 -> 0.123457
    b = _npz(
        tmp_path / "b.npz",
        vertices=v + [[1e-6, 0.0], [0, 0]],
        extra_fap_values=np.array([0.12345651]),
        time_ms=np.array([40.0]),
    )
    assert sha256_file(a) != sha256_file(b)
    assert precision.within_tolerance(a, b) == "2 value(s) differ, each by at most one rounding step (1e-06)"
    far = _npz(
        tmp_path / "c.npz",
        vertices=v + [[3e-6, 0.0], [0, 0]],
        extra_fap_values=np.array([0.12345649]),
        time_ms=np.array([40.0]),
    )
    assert precision.within_tolerance(a, far) is None
    exact = _npz(
        tmp_path / "d.npz", vertices=v, extra_fap_values=np.array([0.12345649]), time_ms=np.array([40.0000001])
    )
    assert precision.within_tolerance(a, exact) is None  # time_ms is exact arithmetic: no tolerance


def test_png_within_one_level(tmp_path):
    level = lambda n: srgb_to_linear(np.array(n / 255.0))  # linear value encoded as 8-bit level n
    lin = np.full((4, 4, 3), level(124))
    a = write_png(tmp_path / "a.png", lin)
    one = lin.copy()
    one[0, 0, 1] = level(125)
    assert precision.within_tolerance(a, write_png(tmp_path / "b.png", one)) == "1 channel value(s) differ by 1 of 255"
    two = lin.copy()
    two[0, 0, 1] = level(126)
    assert precision.within_tolerance(a, write_png(tmp_path / "c.png", two)) is None
    # the same pixels in other bytes (another PNG encoder or compression level)
    oiio = openimageio()
    buf = oiio.ImageBuf(str(a))
    buf.specmod().attribute("png:compressionLevel", 1)
    other = tmp_path / "d.png"
    assert buf.write(str(other))
    assert sha256_file(a) != sha256_file(other)
    assert precision.within_tolerance(a, other) == "pixel-identical, other bytes"


def test_verify_names_a_file_within_tolerance_and_refuses_one_beyond(tmp_path):
    committed, regen = tmp_path / "golden", tmp_path / "regen"
    for d in (committed, regen):
        (d / "s" / "c").mkdir(parents=True)
    v = np.array([[10.0000004, 20.0]])
    _npz(committed / "s" / "c" / "vertices.npz", vertices=v)
    _npz(regen / "s" / "c" / "vertices.npz", vertices=v + [[1e-6, 0.0]])
    _npz(committed / "s" / "c" / "faps.npz", values=np.array([1, 2]))
    _npz(regen / "s" / "c" / "faps.npz", values=np.array([1, 3]))
    files = {r: sha256_file(committed / r) for r in ("s/c/vertices.npz", "s/c/faps.npz")}
    regen_files = {r: sha256_file(regen / r) for r in files}
    problems, near = compare_regenerated(files, committed, regen_files, regen)
    assert near == ["s/c/vertices.npz: 1 value(s) differ, each by at most one rounding step (1e-06)"]
    assert problems == ["regenerating s/c/faps.npz does not reproduce it (not even within one rounding step)"]


def test_verify_of_one_suite_still_checks_every_digest_and_names_an_unknown_suite():
    said = []
    assert verify(only=["no-such-suite"], log=said.append) == ["no suite named no-such-suite"]
    assert any(s.startswith("digests: ") and int(s.split()[1]) > 200 for s in said), said
