"""Every suite scene's reference rests on well-conditioned systems: the condition
number of each linear system the reference solves to compile a suite scene (calibration's warp
and texture map, animation/rbf.py) is under the documented bound; the worst is printed."""

from __future__ import annotations

from fbaconf.animation.rbf import CONDITION_BOUND
from fbaconf.conformance.suite import load_suites
from fbaconf.generators.suites import reference_conditioning, worst_conditioning


def test_every_suite_scene_is_under_the_conditioning_bound():
    rows = reference_conditioning([c for s in load_suites() for c in s.cases])
    print(worst_conditioning(rows))
    assert {(r[1], r[2]) for r in rows} >= {("fdp-texture-ortho", "texture"), ("fdp-all-points", "warp")}
    worst = max(r[3] for r in rows)
    assert worst < CONDITION_BOUND / 100, worst  # at least two orders of magnitude of margin
