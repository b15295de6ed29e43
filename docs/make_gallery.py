"""Render the reference terminal's gallery into docs/gallery/ (for people to look at).

    python docs/make_gallery.py

The default head neutral, with each of the 6 expressions at full intensity (FAP 2,
expression_intensity1 = 63), with 4 visemes (FAP 1, blend 63), and calibrated to a set of
received feature points (a broader, shorter face). 256x256, the bundled default scenario.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fbaconf.animation import engine
from fbaconf.animation.calibrate import calibrate
from fbaconf.bitstreams import tables
from fbaconf.bitstreams.frames import SET, FapFrames
from fbaconf.rendering.images import write_png
from fbaconf.rendering.render import Renderer
from fbaconf.rendering.scenario import Scenario

OUT = Path(__file__).resolve().parent / "gallery"
VISEMES = (1, 2, 10, 14)  # p b m, f v, A:, U


def frames_for(kind: str, number: int) -> FapFrames:
    f = FapFrames.empty(1)
    if kind == "expression":
        f.status[0, 1] = SET
        f.hl("expression_select1")[0] = number
        f.hl("expression_intensity1")[0] = 63
    elif kind == "viseme":
        f.status[0, 0] = SET
        f.hl("viseme_select1")[0] = number
        f.hl("viseme_blend")[0] = 63
    return f


def render(state, path: Path) -> None:
    r = Renderer(state, Scenario.default())
    write_png(path, r.render(0))


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    render(engine.animate(FapFrames.empty(1)), OUT / "neutral.png")
    for number, name in tables.expressions()[1:]:
        render(engine.animate(frames_for("expression", number)), OUT / f"expression_{number}_{name}.png")
    for v in VISEMES:
        label = tables.visemes()[v][1].replace(" ", "").replace(":", "")
        render(engine.animate(frames_for("viseme", v)), OUT / f"viseme_{v}_{label}.png")
    base = engine.compile_scene(None)
    src = base.feature_points
    c = src.mean(0)
    target = c + (src - c) * np.array([1.18, 0.9, 1.0])  # a broader, shorter face
    cal = calibrate(base, target)
    render(engine.animate_model(FapFrames.empty(1), cal), OUT / "calibrated.png")
    joy = frames_for("expression", 1)
    render(engine.animate_model(joy, cal), OUT / "calibrated_joy.png")
    print(f"wrote {len(list(OUT.glob('*.png')))} images to {OUT}")


if __name__ == "__main__":
    main()
