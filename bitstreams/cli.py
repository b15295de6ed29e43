"""Verbs of the bitstream stage: ``encode``, ``decode`` and ``demo``."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from fbaconf._atomic import atomic_write_bytes
from fbaconf.errors import FbaconfInputError

from .fapio import load_faps, save_faps
from .frames import FapFrames


def _summary(frames: FapFrames, nbytes: int) -> dict:
    dur = (len(frames) / frames.frame_rate) if len(frames) else 0.0
    return {
        "frames": len(frames),
        "frame_rate": frames.frame_rate,
        "bytes": nbytes,
        "kbit_per_s": (nbytes * 8 / dur / 1000.0) if dur else None,
        "intra_planes": int(frames.is_intra.sum()),
    }


def cmd_encode(args) -> int:
    if Path(args.input).suffix.lower() == ".bt":  # a BT scene -> binary BIFS
        from fbaconf.scenes.bifs import cmd_encode_scene

        return cmd_encode_scene(args)
    from .encoder import EncoderOptions, encode

    frames, warnings = load_faps(args.input)
    for w in warnings:
        print(f"warning: {w}", file=sys.stderr)
    opts = EncoderOptions(
        fap_quant=args.quant,
        intra_period=args.intra_every,
        frame_rate=args.frame_rate,
        time_codes=args.time_codes,
        plane_start_codes=args.plane_start_codes,
        ranges=args.ranges,
        partial_mask_type=args.partial_mask_type,
        coding=args.coding,
    )
    try:
        res = encode(frames, opts)
    except FbaconfInputError as e:
        e.file = e.file or str(args.input)
        raise
    atomic_write_bytes(args.output, res.data)
    if args.recon:
        save_faps(res.recon, args.recon)
    s = _summary(res.recon, len(res.data))
    if args.json:
        print(json.dumps(s))
    else:
        print(
            f"encoded {s['frames']} frames at {s['frame_rate']:g} Hz ({s['intra_planes']} intra) -> "
            f"{args.output}: {s['bytes']} bytes, {s['kbit_per_s'] or 0:.2f} kbit/s"
        )
    return 0


def cmd_decode(args) -> int:
    from .decoder import decode

    p = Path(args.input)
    if p.suffix.lower() in (".bifs", ".bif"):  # a binary BIFS scene -> BT text and/or a bit trace
        from fbaconf.scenes.bifs import cmd_decode_scene

        return cmd_decode_scene(args)
    if getattr(args, "trace", False):
        raise FbaconfInputError("--trace is for .bifs scenes", rule="usage", file=str(p))
    if not args.output:
        raise FbaconfInputError("-o/--output is required", rule="usage", file=str(p))
    if not p.exists():
        raise FbaconfInputError(f"no such file: {p}", rule="io", file=str(p))
    res = decode(p.read_bytes(), file=str(p))
    save_faps(res.frames, args.output, name=p.stem)
    s = _summary(res.frames, p.stat().st_size)
    if args.json:
        print(json.dumps(s))
    else:
        print(f"decoded {s['frames']} frames at {s['frame_rate']:g} Hz from {p} -> {args.output}")
    return 0


def cmd_demo(args) -> int:
    """Encode -> decode -> check a bundled synthetic example and say what happened."""
    from .decoder import decode
    from .encoder import EncoderOptions, encode
    from .frames import first_difference
    from .synth import synthetic_sequence

    out = Path(args.output)
    frames = synthetic_sequence(250, 25.0)
    ok = True
    print("fbaconf demo: a 10 s procedural face animation (66 low-level FAPs + visemes + expressions, 25 Hz)")
    for q in (0, 1, 8, 31):
        try:
            res = encode(frames, EncoderOptions(fap_quant=q, intra_period=50))
        except FbaconfInputError as e:  # lossless coding cannot reach the head/eye rotations
            print(f"  fap_quant {q:2d}: refused as expected: {e.message}")
            continue
        atomic_write_bytes(out / f"demo_q{q}.fba", res.data)
        dec = decode(res.data)
        diff = first_difference(res.recon, dec.frames)
        err = np.abs(dec.frames.values[:, 2:].astype(np.int64) - frames.values[:, 2:]).max()
        kbps = len(res.data) * 8 / 10.0 / 1000
        status = "decoded == encoder reconstruction" if diff is None else f"MISMATCH {diff}"
        ok &= diff is None
        print(f"  fap_quant {q:2d}: {len(res.data):6d} bytes ({kbps:5.2f} kbit/s), max |error| {err} FAPU; {status}")
        if q == 1:
            dec.frames.save_npz(out / "demo_q1.npz")
    try:
        from fbaconf.profiles.checker import check_stream
    except ImportError:
        check_stream = None
    if check_stream is not None:
        diags = check_stream((out / "demo_q1.fba").read_bytes(), file="demo_q1.fba")
        errors = [d for d in diags if getattr(d, "severity", "") == "error"]
        print(f"  fbaconf check demo_q1.fba: {len(errors)} errors, {len(diags) - len(errors)} other diagnostics")
        ok &= not errors
    print(f"outputs in {out}/; result: {'OK' if ok else 'FAILED'}")
    return 0 if ok else 1


def register(sub) -> None:
    p = sub.add_parser("encode", help="reference encoder: .fap/.npz FAP sequence -> face object bitstream (.fba)")
    p.add_argument("input", help="FAP sequence (.fap text or fbaconf .npz), or a BT scene (.bt -> .bifs)")
    p.add_argument("-o", "--output", required=True, help="output .fba (.bifs for a .bt scene)")
    p.add_argument("--quant", type=int, default=1, help="fap_quant 0..31 (0 = lossless, default 1)")
    p.add_argument("--coding", choices=("arithmetic", "dct"), default="arithmetic")
    p.add_argument("--intra-every", type=int, default=0, metavar="N", help="an intra plane at least every N planes")
    p.add_argument("--frame-rate", default=None, help="output frame rate, e.g. 25, 29.97 or 30000/1001")
    p.add_argument("--time-codes", action="store_true", help="write a time code in every intra plane")
    p.add_argument("--plane-start-codes", choices=("none", "intra", "all"), default="intra")
    p.add_argument(
        "--ranges",
        choices=("auto", "persist"),
        default="auto",
        help="auto: tight min/max lists in every intra plane; persist: default ranges, lists when needed",
    )
    p.add_argument("--partial-mask-type", type=int, choices=(1, 2), default=None)
    p.add_argument("--recon", help="also write the encoder's reconstruction (.fap or .npz)")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(func=cmd_encode)

    p = sub.add_parser("decode", help="reference decoder: .fba -> FapFrames (.fap text or .npz); .bifs scene -> .bt")
    p.add_argument("input")
    p.add_argument("-o", "--output", help="output .fap or .npz (.bt for a .bifs scene)")
    p.add_argument(
        "--trace", action="store_true", help=".bifs only: print every node and field with its bit offset and width"
    )
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_decode)

    p = sub.add_parser("demo", help="encode -> decode -> check a bundled example and print what happened")
    p.add_argument("-o", "--output", default="fbaconf-demo", help="output folder (default ./fbaconf-demo)")
    p.set_defaults(func=cmd_demo)
