"""The ``fbaconf animate`` verb: FAP frames (+ BT or BIFS scene) -> vertices per frame (.npz)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from fbaconf.bitstreams.fapio import load_faps


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "animate",
        help="reference animation: FAPs (+ scene) -> vertices per frame (.npz)",
        description="Animate the scene's face (or, without --scene, the bundled default head) with the FAP "
        "frames: FIT, left/right fill, visemes/expressions, FaceDefTables, Transforms. Writes a "
        "FaceState .npz (vertices float64[frames, vertices, 3], parts, triangles, effective FAPs).",
    )
    p.add_argument(
        "--scene",
        type=Path,
        default=None,
        help="scene file: BT text, or binary BIFS by its .bifs/.bif extension (default: the bundled default head)",
    )
    p.add_argument("--faps", type=Path, required=True, help="FAP frames: .npz (FapFrames) or .fap text")
    p.add_argument("-o", "--output", type=Path, required=True, help="output .npz")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    p.set_defaults(func=run_animate)


def run_animate(args: argparse.Namespace) -> int:
    from .engine import animate
    from .stateio import save_npz

    frames = load_faps(args.faps)[0]
    state = animate(frames, scene=args.scene)
    save_npz(state, args.output)
    if args.json:
        print(
            json.dumps(
                {
                    "output": str(args.output),
                    "frames": state.n_frames,
                    "vertices": int(state.vertices.shape[1]),
                    "parts": [p.name for p in state.parts],
                }
            )
        )
    else:
        print(f"wrote {state.n_frames} frame(s) x {state.vertices.shape[1]} vertices to {args.output}")
    return 0
