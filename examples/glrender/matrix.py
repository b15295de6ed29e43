#!/usr/bin/env python3
"""The verdict matrix of glrender's variants over every image case of the suites, in-process
(one GL context, each case's FaceState animated once, frames written as PNG and judged by
the harness's own image comparison, ``fbaconf.harness.compare.compare_images``, with the
tolerances of harness/data/tolerances.toml — exactly the image stage of ``fbaconf run``).

    python examples/glrender/matrix.py [--json OUT.json] [VARIANT ...]

Prints one line per variant: Fail count, then per case outcome letter, the largest number
of violating pixels in a frame and the largest interior CIEDE2000 mean.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import glrender


def image_cases():
    from fbaconf.conformance.suite import load_suites

    return [c for s in load_suites() for c in s.cases if "images" in c.stages]


def case_state(case, cache: dict):
    from fbaconf.animation.engine import animate
    from fbaconf.reference.pipeline import load_stream

    scene = case.input_path("scene")
    key = (str(scene), str(case.input_path("fba")))
    if key not in cache:
        cache[key] = animate(load_stream(case.input_path("fba")), scene=scene)
    return cache[key]


def run_case(case, variant: str, out: Path, cache: dict):
    """The image stage's StageResult for ``variant`` rendering ``case``'s compared frames."""
    from fbaconf.harness.compare import ImageTolerances, compare_images
    from fbaconf.rendering.scenario import Scenario

    state = case_state(case, cache)
    sc = Scenario.load(case.input_path("scenario"))
    scene = case.input_path("scene")
    names = case.goldens["images"]
    frames = [int(re.fullmatch(r"frame_(\d+)\.png", n).group(1)) for n in names]
    out.mkdir(parents=True, exist_ok=True)
    r = glrender.GLRenderer(state, sc, variant, scene_dir=scene.parent if scene else None)
    try:
        got = []
        for n, k in zip(names, frames):
            p = out / n
            glrender.write_png(p, r.render_srgb8(k))
            got.append(p)
    finally:
        r.release()
    gdir = case.golden_dir()
    return compare_images([gdir / n for n in names], got, ImageTolerances.defaults(), out / "art", frames=frames)


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--json", type=Path)
    ap.add_argument("variants", nargs="*")
    a = ap.parse_args(argv)
    variants = a.variants or list(glrender.VARIANTS)
    cases = image_cases()
    cache: dict = {}
    table = {}
    with tempfile.TemporaryDirectory() as tmp:
        for v in variants:
            t0 = time.perf_counter()
            cells, row = [], {}
            for c in cases:
                try:
                    r = run_case(c, v, Path(tmp) / v / c.suite / c.id, cache)
                except glrender.NotSupported as e:
                    print(f"{v:18s} not supported: {e}", flush=True)
                    row = None
                    break
                m = r.metrics
                row[c.full_id] = {
                    "outcome": r.outcome.value,
                    "message": r.message,
                    **{k: m[k] for k in sorted(m) if isinstance(m[k], (int, float))},
                }
                cells.append(
                    f"{c.id}:{r.outcome.value[0]}{int(m.get('violations_max', -1))}"
                    f"/{m.get('interior_deltae_mean_max', float('nan')):.2f}"
                )
            table[v] = row
            if row is None:
                continue
            fails = sum(x["outcome"] == "Fail" for x in row.values())
            print(
                f"{v:18s} fails {fails:2d}/{len(cases)} ({time.perf_counter() - t0:.1f}s)  " + " ".join(cells),
                flush=True,
            )
    if a.json:
        a.json.write_text(json.dumps(table, indent=1, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
