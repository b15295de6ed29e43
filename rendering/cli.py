"""The ``fbaconf render`` verb: FAPs (+ scene) -> one image per frame."""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from pathlib import Path

from fbaconf.bitstreams.fapio import load_faps

from .errors import RenderInputError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "render",
        help="reference images: FAPs (+ scene) -> one PNG/EXR per frame",
        description="Animate the scene's face (or the bundled default head) with the FAPs and render "
        "every frame of the scenario with the deterministic reference rasteriser. Images are "
        "named frame_00000.png ... (or .exr) after the frame index.",
    )
    p.add_argument(
        "--scene",
        type=Path,
        default=None,
        help="scene file with the face model: BT text, or binary BIFS by its .bifs/.bif extension "
        "(default: the bundled default head)",
    )
    p.add_argument("--faps", type=Path, required=True, help="FAP frames: .npz (FapFrames) or .fap text")
    p.add_argument(
        "--scenario", type=Path, default=None, help="scenario TOML (default: the bundled rendering/data/default.toml)"
    )
    p.add_argument("-o", "--output", type=Path, required=True, help="output folder for the images")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    p.set_defaults(func=run_render)


def run_render(args: argparse.Namespace) -> int:
    from .render import render_frames
    from .scenario import Scenario

    scenario = Scenario.load(args.scenario) if args.scenario is not None else Scenario.default()
    if args.scene is not None and not args.scene.is_file():
        raise RenderInputError(f"scene file not found: {args.scene}", file=str(args.scene), rule="scene-missing")
    frames = load_faps(args.faps)[0]
    try:
        engine = importlib.import_module("fbaconf.animation.engine")
        animate = engine.animate
    except (ImportError, AttributeError) as e:
        print(
            f"fbaconf render: error: the animation stage is not available (fbaconf.animation.engine.animate): {e}",
            file=sys.stderr,
        )
        return 2
    state = animate(frames, scene=args.scene)
    scene_dir = args.scene.resolve().parent if args.scene is not None else None
    try:
        paths = render_frames(state, scenario, args.output, scene_dir=scene_dir)
    except OSError as e:
        raise RenderInputError(
            f"cannot write images: {e.strerror or e}", file=str(args.output), rule="output-unwritable"
        ) from None
    if args.json:
        print(
            json.dumps(
                {
                    "images": [str(p) for p in paths],
                    "frames": len(paths),
                    "width": scenario.width,
                    "height": scenario.height,
                    "format": scenario.format,
                }
            )
        )
    else:
        print(f"wrote {len(paths)} {scenario.format.upper()} image(s) to {args.output}")
    return 0
