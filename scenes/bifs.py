"""Binary BIFS (ISO/IEC 14496-1 scene description) for the Face node family and the VRML
geometry nodes of fbaconf's scenes: encoder, decoder and bit trace.

The codec maps exactly the scene model of :mod:`fbaconf.scenes.bt` (``Scene``, ``Node``,
``Use``) to a BIFS version 1 command stream and back:

* ``.bifs`` file = BIFSConfig (nodeIDbits, routeIDbits, isCommandStream = 1, pixelMetric,
  hasSize) padded with 0 bits to a byte boundary, then one access unit: a command frame
  holding one ReplaceScene command (reserved(6), useNames(1), the top node as SFTopNode,
  hasROUTEs(1) = 0), continue bit 0, padded to a byte boundary (fbaconf framing, provisional).
* The scene's list of top-level nodes travels as the ``children`` of an ``OrderedGroup`` top
  node (a node type no BT scene of the subset can hold, so the wrapper is unambiguous); a
  foreign stream whose top node is a ``Group`` decodes to a scene with that one Group.
* SFNode: isReused(1) [nodeID] | localNodeType(NDT bits) isUpdateable(1) [nodeID, name]
  MaskAccess(1) masked (one bit per defID field) or list (endFlag(1), defID, value ...)
  description. NULL is a reused nodeID of all ones. DEF names travel as null-terminated
  UTF-8 (useNames = 1), so a scene round-trips with its names. The model keeps the fields a
  file sets, in file order: the encoder uses the masked description when that order is
  defID order (and cheaper), the list description otherwise.
* MF fields: reserved(1) = 0, isList(1); list: endFlag(1) + value per item; vector:
  nbBits(5), count(nbBits), values (the encoder picks the cheaper form).
* SF values: SFBool 1 bit, SFInt32 32 bits, SFFloat 32-bit IEEE (vectors/colours/rotations
  2/3/4 of them), SFTime 64-bit IEEE, SFString nbBits(5) length(nbBits) then UTF-8 bytes.
* No field is quantised: fbaconf never sends a QuantizationParameter node (it is not in the
  subset; a stream containing one is refused as an unsupported node). Floats are coded as
  float32; the decoder returns each as the shortest decimal that rounds to the same float32,
  so BT -> BIFS -> BT is exact for integers, booleans and strings and within float32
  rounding for floats, and BIFS -> BT -> BIFS is bit-identical.

Every table (NDTs and node codes, field lists, defIDs, quantisation categories) lives in
``data/bifs_nodes.toml`` with its provenance. Bad input raises :class:`BifsError` (a
:class:`BitstreamError`) with the bit offset, the rule broken and the node path; counts and
lengths are checked against the bits left before anything is allocated, nesting is limited,
and every loop consumes input, so no input can crash, hang or exhaust memory.

The coder lives in :mod:`.bifs_tables` (node and field tables, errors),
:mod:`.bifs_encoder` and :mod:`.bifs_decoder`; this module is its public face (the names
below), the CLI glue of ``fbaconf encode|decode`` for scenes, and scene comparison.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from fbaconf._atomic import atomic_write_bytes, atomic_write_text
from fbaconf.errors import FbaconfInputError
from fbaconf.scenes import bt

from .bifs_decoder import TraceEntry, decode, format_trace, is_bifs_path, load_scene, read
from .bifs_encoder import BifsWriter, encode
from .bifs_tables import BIFS_SUFFIXES, MAX_DEPTH, MF_VEC, SF_VEC, BifsEncodeError, BifsError, tables

__all__ = [
    "BIFS_SUFFIXES",
    "MAX_DEPTH",
    "MF_VEC",
    "SF_VEC",
    "BifsEncodeError",
    "BifsError",
    "BifsWriter",
    "TraceEntry",
    "decode",
    "encode",
    "format_trace",
    "is_bifs_path",
    "load_scene",
    "read",
    "tables",
]


def cmd_encode_scene(args) -> int:
    """``fbaconf encode S.bt -o S.bifs``."""
    src, out = Path(args.input), Path(args.output)
    if not is_bifs_path(out):
        raise FbaconfInputError(f"a BT scene encodes to a .bifs file, not {out.name}", rule="io", file=str(out))
    if not src.is_file():
        raise FbaconfInputError(f"no such file: {src}", rule="io", file=str(src))
    scene = bt.read(src)
    try:
        data = encode(scene)
    except FbaconfInputError as e:
        e.file = e.file or str(src)
        raise
    atomic_write_bytes(out, data)
    if getattr(args, "json", False):
        print(
            json.dumps({"input": str(src), "output": str(out), "bt_bytes": src.stat().st_size, "bifs_bytes": len(data)})
        )
    else:
        print(f"encoded scene {src} ({src.stat().st_size} bytes of BT) -> {out}: {len(data)} bytes of BIFS")
    return 0


def cmd_decode_scene(args) -> int:
    """``fbaconf decode S.bifs [-o S.bt] [--trace]``."""
    src = Path(args.input)
    out = Path(args.output) if args.output else None
    trace = bool(getattr(args, "trace", False))
    if out is None and not trace:
        raise FbaconfInputError("give -o OUT.bt and/or --trace", rule="usage", file=str(src))
    if out is not None and out.suffix.lower() != ".bt":
        raise FbaconfInputError(f"a BIFS scene decodes to a .bt file, not {out.name}", rule="io", file=str(out))
    try:
        data = src.read_bytes()
    except OSError as e:
        raise FbaconfInputError(f"cannot read {src}: {e.strerror or e}", rule="io", file=str(src)) from None
    entries: list | None = [] if trace else None
    try:
        scene = decode(data, file=str(src), trace=entries)
    finally:
        if trace:
            print(format_trace(entries))
    if out is not None:
        atomic_write_text(out, bt.write(scene))
        if not trace:
            print(f"decoded scene {src} ({len(data)} bytes of BIFS) -> {out}")
    return 0


def same_scene(a: bt.Scene, b: bt.Scene) -> bool:
    """True when two scene models are equal with every float compared as float32 (the BIFS
    round-trip criterion: exact for integers, booleans, strings, names and structure)."""
    return isinstance(a, bt.Scene) and isinstance(b, bt.Scene) and _same(a.nodes, b.nodes)


def _f32(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float64).astype(np.float32)


def _same(a, b, rel: float = 0.0) -> bool:
    if isinstance(a, bt.Node) or isinstance(b, bt.Node):
        return (
            isinstance(a, bt.Node)
            and isinstance(b, bt.Node)
            and a.type == b.type
            and a.def_name == b.def_name
            and list(a.fields) == list(b.fields)
            and all(_same(a.fields[k], b.fields[k], rel) for k in a.fields)
        )
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        if (
            not (isinstance(a, np.ndarray) and isinstance(b, np.ndarray))
            or a.shape != b.shape
            or a.dtype.kind != b.dtype.kind
        ):
            return False
        if a.dtype.kind == "f":
            return _floats(a, b, rel)
        return bool(np.array_equal(a, b))
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y, rel) for x, y in zip(a, b))
    if isinstance(a, tuple) and isinstance(b, tuple):
        return len(a) == len(b) and _floats(a, b, rel)
    if isinstance(a, float) and isinstance(b, float):
        return _floats(a, b, rel)
    return type(a) is type(b) and a == b


def _floats(a, b, rel: float) -> bool:
    """Equal as float32, or (``rel`` > 0) within ``rel`` of each other relative to the larger."""
    fa, fb = _f32(a), _f32(b)
    if rel <= 0:
        return bool(np.array_equal(fa, fb))
    fa, fb = fa.astype(np.float64), fb.astype(np.float64)
    return bool(np.all(np.abs(fa - fb) <= rel * np.maximum(np.abs(fa), np.abs(fb))))


def equivalent_scene(a: bt.Scene, b: bt.Scene, rel: float = 0.0) -> bool:
    """Equal as scenes, whatever the encoder's choices: :func:`same_scene` after every node's
    fields are put in table order with the omitted ones at their defaults, and every USE is
    replaced by the node it names (field order, omitted defaults and so where a shared node
    is DEFined are valid encoder choices; MP4Box makes all three differently). ``rel`` > 0
    compares floats to that relative precision (text written with fewer digits)."""
    if not (isinstance(a, bt.Scene) and isinstance(b, bt.Scene)):
        return False
    da, db = a.defs(), b.defs()
    return _same([_full(n, da) for n in a.nodes], [_full(n, db) for n in b.nodes], rel)


def _full(v, defs, depth: int = 0):
    if depth > 200:  # a USE of an ancestor: not a tree; compare no deeper
        return None
    if isinstance(v, bt.Use):
        v = defs.get(v.name, v)
        if isinstance(v, bt.Use):
            return v
    if isinstance(v, bt.Node):
        specs = bt.node_specs()[v.type]
        fields = {
            name: _full(v.fields[name] if name in v.fields else spec.default, defs, depth + 1)
            for name, spec in specs.items()
        }
        return bt.Node(v.type, fields, v.def_name)
    if isinstance(v, list):
        return [_full(x, defs, depth + 1) for x in v]
    return v


def interop_view(scene: bt.Scene) -> bt.Scene:
    """``scene`` without what GPAC's MP4Box refuses though the seed defines it (D10): the
    ``faceSceneGraphNode`` of every FaceDefMesh (a USE of an IndexedFaceSet, where GPAC types
    the field SF3DNode). What interop tests with MP4Box compare ("mesh references aside")."""

    def strip(v):
        if isinstance(v, bt.Node):
            fields = {
                k: strip(x) for k, x in v.fields.items() if not (v.type == "FaceDefMesh" and k == "faceSceneGraphNode")
            }
            return bt.Node(v.type, fields, v.def_name)
        if isinstance(v, list):
            return [strip(x) for x in v]
        return v

    return bt.Scene([strip(n) for n in scene.nodes], scene.file)
