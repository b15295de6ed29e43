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
"""
from __future__ import annotations

import math
import re
import struct
import tomllib
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path

import numpy as np

from fbaconf.scenes import bt
from fbaconf.errors import SceneError

from fbaconf.bitstreams.bitio import BitWriter
from fbaconf.errors import BitstreamError, FbaconfInputError

BIFS_SUFFIXES = (".bifs", ".bif")
MAX_DEPTH = bt.MAX_DEPTH
MAX_NAME_BYTES = 1024
_F32_MAX = float(np.finfo(np.float32).max)
_VEC = {"SFVec2f": 2, "SFVec3f": 3, "SFColor": 3, "SFRotation": 4}
_MF_VEC = {"MFVec2f": 2, "MFVec3f": 3, "MFColor": 3, "MFRotation": 4}
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_\-.]*\Z")
_ITEM_BITS = {"MFInt32": 32, "MFFloat": 32, **{t: 32 * k for t, k in _MF_VEC.items()}}


# ---------------------------------------------------------------------------------- errors
class BifsError(BitstreamError):
    """A binary BIFS scene violates the syntax or the subset fbaconf reads."""

    rule = "bifs"

    def __init__(self, message: str, *, bit_offset: int, rule: str, node_path: str | None = None,
                 file: str | None = None) -> None:
        super().__init__(message, bit_offset=bit_offset, rule=rule, file=file)
        self.node_path = node_path

    def location(self) -> str:
        base = super().location()
        return f"{base}, {self.node_path}" if self.node_path else base

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["node_path"] = self.node_path
        return d


class BifsEncodeError(SceneError):
    """A scene model cannot be coded as BIFS (a node outside its field's node data type, a
    value outside its field type, a USE before its DEF); located by node path."""

    rule = "bifs-encode"


# ---------------------------------------------------------------------------------- tables
@dataclass(frozen=True)
class BifsField:
    name: str
    event: str          # field | exposedField | eventIn | eventOut
    type: str           # SFInt32, MFNode, ...
    ndt: str | None     # node data type of SFNode/MFNode fields
    quant: int          # quantisation category (documentation; never applied, see module doc)
    def_id: int | None  # index among field/exposedField entries (None for events)


@dataclass(frozen=True)
class BifsNode:
    name: str
    provenance: str
    fields: tuple[BifsField, ...]   # all fields in table order
    defs: tuple[BifsField, ...]     # the defID fields, in defID order
    by_name: dict

    @property
    def def_bits(self) -> int:
        return (len(self.defs) - 1).bit_length() if self.defs else 0


@dataclass(frozen=True)
class Ndt:
    name: str
    bits: int
    nodes: tuple[str, ...]  # code = index + 1 (0 reserved)
    provenance: str

    def code(self, node_type: str) -> int | None:
        try:
            return self.nodes.index(node_type) + 1
        except ValueError:
            return None


@dataclass(frozen=True)
class Tables:
    raw: dict
    ndts: dict
    nodes: dict


@lru_cache(maxsize=1)
def tables() -> Tables:
    """The BIFS tables of ``data/bifs_nodes.toml`` (checked against the BT field tables)."""
    raw = tomllib.loads(resources.files("fbaconf.scenes").joinpath("data", "bifs_nodes.toml").read_text("utf-8"))
    ndts = {}
    for name, e in raw["ndt"].items():
        nodes = tuple(e["nodes"])
        bits = int(e["bits"])
        if bits != math.ceil(math.log2(len(nodes) + 1)):
            raise RuntimeError(f"bifs_nodes.toml: NDT {name} has {len(nodes)} nodes but {bits} bits")
        ndts[name] = Ndt(name, bits, nodes, e["provenance"])
    nodes = {}
    for name, e in raw["node"].items():
        flds, defs = [], []
        for f in e["fields"]:
            is_def = f["event"] in ("field", "exposedField")
            bf = BifsField(f["name"], f["event"], f["type"], f.get("ndt"), int(f.get("quant", 0)),
                           len(defs) if is_def else None)
            if bf.ndt is not None and bf.ndt not in ndts:
                raise RuntimeError(f"bifs_nodes.toml: {name}.{bf.name} names unknown NDT {bf.ndt}")
            flds.append(bf)
            if is_def:
                defs.append(bf)
        nodes[name] = BifsNode(name, e["provenance"], tuple(flds), tuple(defs), {f.name: f for f in defs})
    specs = bt.node_specs()
    for ntype, fs in specs.items():  # the BIFS tables must cover the scene model exactly
        bn = nodes.get(ntype)
        if bn is None:
            raise RuntimeError(f"bifs_nodes.toml lacks node {ntype}")
        for fname, spec in fs.items():
            bf = bn.by_name.get(fname)
            if bf is None or bf.type != spec.type:
                raise RuntimeError(f"bifs_nodes.toml: {ntype}.{fname} missing or not {spec.type}")
    return Tables(raw, ndts, nodes)


# ---------------------------------------------------------------------------------- bit writer
class _Writer(BitWriter):
    def write_bytes(self, b: bytes) -> None:
        """Append whole bytes at the current (possibly unaligned) bit position."""
        if not b:
            return
        if self._nacc == 0:
            self._buf += b
            return
        n = len(b) * 8
        keep = self._nacc
        v = (self._acc << n) | int.from_bytes(b, "big")
        self._buf += (v >> keep).to_bytes(len(b), "big")
        self._acc = v & ((1 << keep) - 1)

    def align(self) -> None:
        if self._nacc:
            self.write(0, 8 - self._nacc)


_TOP_ITEM = re.compile(r"\[\d+\]\Z")


def _node_path(path: str, ntype: str, sf: bool) -> str:
    """A node's path as the BT reader names it (top-level list items as ``[i]Type``)."""
    if not path or _TOP_ITEM.match(path):
        return f"{path}{ntype}"
    return f"{path}.{ntype}" if sf else path


def _count_bits(n: int) -> int:
    return int(n).bit_length()


# ---------------------------------------------------------------------------------- encoder
class _Encoder:
    def __init__(self, scene: bt.Scene, use_names: bool) -> None:
        self.t = tables()
        self.w = _Writer()
        self.use_names = use_names
        n_defs = sum(1 for n, _ in scene.walk() if n.def_name)
        self.id_bits = _count_bits(n_defs)  # IDs 0..n-1; all ones = NULL
        self.ids: dict[str, int] = {}
        self.types: dict[str, str] = {}
        self.open: set[str] = set()

    def err(self, msg, rule, path):
        return BifsEncodeError(msg, rule=rule, node_path=path)

    # nodes
    def node(self, v, ndt: str, path: str, allowed, *, sf: bool, allow_null: bool = True) -> None:
        w = self.w
        if v is None:
            if not allow_null:
                raise self.err("NULL is not allowed in an MFNode field", "bifs-null", path)
            w.bit(1)
            w.write((1 << self.id_bits) - 1, self.id_bits)
            return
        if isinstance(v, bt.Use):
            nid = self.ids.get(v.name)
            if nid is None or v.name in self.open:
                raise self.err(f"USE {v.name}: no node was DEFined with this name before", "bifs-use-undefined", path)
            if allowed is not None and self.types[v.name] not in allowed:
                raise self.err(f"USE {v.name}: a {self.types[v.name]} node is not allowed here", "bifs-node-type", path)
            w.bit(1)
            w.write(nid, self.id_bits)
            return
        if not isinstance(v, bt.Node):
            raise self.err(f"expected a node, got {type(v).__name__}", "bifs-node-type", path)
        table = self.t.ndts[ndt]
        code = table.code(v.type)
        bn = self.t.nodes.get(v.type)
        if code is None or bn is None:
            raise self.err(f"a {v.type} node cannot be coded inline where the node data type is {ndt} "
                           f"(DEF it where it belongs and USE it here)", "bifs-ndt", path)
        if allowed is not None and v.type not in allowed:
            raise self.err(f"a {v.type} node is not allowed here", "bifs-node-type", path)
        npath = _node_path(path, v.type, sf)
        w.bit(0)
        w.write(code, table.bits)
        if v.def_name is not None:
            name = v.def_name
            if name in self.ids:
                raise self.err(f"DEF {name} is defined twice", "bifs-def-duplicate", npath)
            nid = len(self.ids)
            self.ids[name] = nid
            self.types[name] = v.type
            self.open.add(name)
            w.bit(1)
            w.write(nid, self.id_bits)
            if self.use_names:
                raw = name.encode("utf-8")
                if b"\0" in raw or len(raw) > MAX_NAME_BYTES:
                    raise self.err(f"DEF name {name!r} cannot be coded", "bifs-def-name", npath)
                w.write_bytes(raw + b"\0")
        else:
            w.bit(0)
        items = []
        specs = bt.node_specs().get(v.type, {})
        for fname, val in v.fields.items():
            bf = bn.by_name.get(fname)
            if bf is None:
                raise self.err(f"{v.type} has no field {fname!r}", "bifs-unknown-field", npath)
            items.append((bf, val))
        ids = [bf.def_id for bf, _ in items]
        ascending = all(a < b for a, b in zip(ids, ids[1:]))
        masked_cost = len(bn.defs)
        list_cost = len(items) * (1 + bn.def_bits) + 1
        if ascending and masked_cost <= list_cost:
            w.bit(1)
            byname = {bf.name: val for bf, val in items}
            for bf in bn.defs:
                if bf.name in byname:
                    w.bit(1)
                    self.field(bf, byname[bf.name], f"{npath}.{bf.name}", specs)
                else:
                    w.bit(0)
        else:
            w.bit(0)
            for bf, val in items:
                w.bit(0)
                w.write(bf.def_id, bn.def_bits)
                self.field(bf, val, f"{npath}.{bf.name}", specs)
            w.bit(1)
        if v.def_name is not None:
            self.open.discard(v.def_name)

    # fields
    def field(self, bf: BifsField, val, path: str, specs) -> None:
        spec = specs.get(bf.name)
        allowed = spec.allowed if spec is not None else None
        t = bf.type
        if t == "SFNode":
            self.node(val, bf.ndt, path, allowed, sf=True)
        elif t.startswith("SF"):
            self.sf(t, val, path)
        else:
            self.mf(bf, val, path, allowed)

    def sf(self, t: str, v, path: str) -> None:
        w = self.w
        try:
            if t == "SFBool":
                if not isinstance(v, (bool, np.bool_)):
                    raise TypeError
                w.bit(1 if v else 0)
            elif t == "SFInt32":
                iv = int(v)
                if isinstance(v, (bool, float)) or not -2**31 <= iv < 2**31:
                    raise ValueError(f"{v!r} is not an SFInt32")
                w.write(iv & 0xFFFFFFFF, 32)
            elif t == "SFFloat":
                w.write_bytes(self.floats([v], path))
            elif t == "SFTime":
                x = float(v)
                if not math.isfinite(x):
                    raise ValueError(f"{v!r} is not finite")
                w.write_bytes(struct.pack(">d", x))
            elif t in _VEC:
                vals = list(v)
                if len(vals) != _VEC[t]:
                    raise ValueError(f"{t} needs {_VEC[t]} numbers")
                w.write_bytes(self.floats(vals, path))
            elif t == "SFString":
                if not isinstance(v, str):
                    raise TypeError
                raw = v.encode("utf-8")
                nb = _count_bits(len(raw))
                if nb > 31:
                    raise ValueError("string too long")
                w.write(nb, 5)
                w.write(len(raw), nb)
                w.write_bytes(raw)
            else:
                raise self.err(f"field type {t} is not supported", "bifs-field-type", path)
        except (TypeError, ValueError, OverflowError) as e:
            raise self.err(f"value {v!r} cannot be coded as {t}: {e}", "bifs-value", path) from None

    def floats(self, vals, path: str) -> bytes:
        a = np.asarray(vals, dtype=np.float64)
        if a.size and (not np.all(np.isfinite(a)) or np.abs(a).max() > _F32_MAX):
            raise self.err("a float is not finite or outside the float32 range", "bifs-value", path)
        return a.astype(">f4").tobytes()

    def mf(self, bf: BifsField, val, path: str, allowed) -> None:
        w = self.w
        t = bf.type
        if t == "MFNode":
            items = list(val)
            n = len(items)
            w.bit(0)  # reserved
            if n + 1 < 5 + _count_bits(n):
                w.bit(1)
                for i, c in enumerate(items):
                    w.bit(0)
                    self.node(c, bf.ndt, f"{path}[{i}]", allowed, sf=False, allow_null=False)
                w.bit(1)
            else:
                w.bit(0)
                nb = _count_bits(n)
                w.write(nb, 5)
                w.write(n, nb)
                for i, c in enumerate(items):
                    self.node(c, bf.ndt, f"{path}[{i}]", allowed, sf=False, allow_null=False)
            return
        if t == "MFString":
            items = list(val)
            n = len(items)
            w.bit(0)
            if n + 1 < 5 + _count_bits(n):
                w.bit(1)
                for s in items:
                    w.bit(0)
                    self.sf("SFString", s, path)
                w.bit(1)
            else:
                w.bit(0)
                nb = _count_bits(n)
                w.write(nb, 5)
                w.write(n, nb)
                for s in items:
                    self.sf("SFString", s, path)
            return
        arr = np.asarray(val)
        if t == "MFInt32":
            if arr.size and (arr.dtype.kind not in "iu" or arr.min() < -2**31 or arr.max() >= 2**31):
                raise self.err("MFInt32 values must be integers in the int32 range", "bifs-value", path)
            raw = arr.reshape(-1).astype(">i4").tobytes()
            per = 4
        elif t == "MFFloat":
            raw = self.floats(arr.reshape(-1), path)
            per = 4
        elif t in _MF_VEC:
            k = _MF_VEC[t]
            if arr.size % k:
                raise self.err(f"{t} needs a multiple of {k} numbers", "bifs-value", path)
            raw = self.floats(arr.reshape(-1), path)
            per = 4 * k
        else:
            raise self.err(f"field type {t} is not supported", "bifs-field-type", path)
        n = len(raw) // per
        item_bits = per * 8
        w.bit(0)
        if n * (1 + item_bits) + 1 < 5 + _count_bits(n) + n * item_bits:
            w.bit(1)
            for i in range(n):
                w.bit(0)
                w.write_bytes(raw[i * per:(i + 1) * per])
            w.bit(1)
        else:
            w.bit(0)
            nb = _count_bits(n)
            w.write(nb, 5)
            w.write(n, nb)
            w.write_bytes(raw)


def encode(scene: bt.Scene, *, use_names: bool = True) -> bytes:
    """The ``.bifs`` bytes of a scene model (raises :class:`BifsEncodeError`)."""
    t = tables()
    enc = _Encoder(scene, use_names)
    w = enc.w
    # BIFSConfig (v1)
    if enc.id_bits > 31:
        raise BifsEncodeError("too many DEF nodes", rule="bifs-node-id")
    w.write(enc.id_bits, 5)       # nodeIDbits
    w.write(0, 5)                 # routeIDbits (no routes)
    w.bit(1)                      # isCommandStream
    w.bit(0)                      # pixelMetric
    w.bit(0)                      # hasSize
    w.align()
    # access unit: one ReplaceScene command
    w.write(t.raw["command"]["replace_scene"], 2)
    w.write(0, 6)                 # reserved
    w.bit(1 if use_names else 0)  # useNames
    top = bt.Node("OrderedGroup", {"children": list(scene.nodes)})
    ndt = t.ndts["SFTopNode"]
    w.bit(0)                      # isReused
    w.write(ndt.code("OrderedGroup"), ndt.bits)
    w.bit(0)                      # isUpdateable
    bn = t.nodes["OrderedGroup"]
    w.bit(1)                      # masked description
    for bf in bn.defs:
        if bf.name == "children":
            w.bit(1)
            enc.mf(bf, top.fields["children"], "", None)
            continue
        w.bit(0)
    w.bit(0)                      # hasROUTEs
    w.bit(0)                      # no further command
    w.align()
    return w.getvalue()


# ---------------------------------------------------------------------------------- decoder
@dataclass
class TraceEntry:
    bit_offset: int
    width: int
    depth: int
    text: str


class _Decoder:
    def __init__(self, data: bytes, file: str | None, trace: list | None) -> None:
        self.t = tables()
        self.data = data
        self.pos = 0
        self.nbits = len(data) * 8
        self.file = file
        self.trace = trace
        self.id_bits = 0
        self.use_names = True
        self.defs: dict[int, tuple[str, str, bool]] = {}  # id -> (name, type, complete)
        self.names: set[str] = set()

    # primitives (own position and bounds checks: the hot path of the decoder)
    def err(self, msg, rule, path=None, at=None):
        return BifsError(msg, bit_offset=self.pos if at is None else at, rule=rule, node_path=path, file=self.file)

    def _truncated(self, nbits: int, what: str, path):
        return self.err(f"stream ends inside {what} ({nbits} bits needed, {self.nbits - self.pos} left)",
                        "bifs-truncated", path)

    def rd(self, nbits: int, what: str, path=None) -> int:
        pos = self.pos
        end = pos + nbits
        if end > self.nbits:
            raise self._truncated(nbits, what, path)
        if nbits == 0:
            return 0
        first = pos >> 3
        last = (end + 7) >> 3
        self.pos = end
        return (int.from_bytes(self.data[first:last], "big") >> ((last << 3) - end)) & ((1 << nbits) - 1)

    def bit(self, what: str, path=None) -> int:
        pos = self.pos
        if pos >= self.nbits:
            raise self._truncated(1, what, path)
        self.pos = pos + 1
        return (self.data[pos >> 3] >> (7 - (pos & 7))) & 1

    def rd_bytes(self, n: int, what: str, path=None) -> bytes:
        if n == 0:
            return b""
        if n * 8 > self.nbits - self.pos:
            raise self.err(f"stream ends inside {what} ({n} bytes declared, {(self.nbits - self.pos) // 8} "
                           f"left)", "bifs-truncated", path)
        pos = self.pos
        self.pos = pos + 8 * n
        if pos & 7 == 0:
            return self.data[pos >> 3:(pos >> 3) + n]
        sh = pos & 7
        v = int.from_bytes(self.data[pos >> 3:(pos >> 3) + n + 1], "big") >> (8 - sh)
        return (v & ((1 << (8 * n)) - 1)).to_bytes(n, "big")

    def note(self, start: int, depth: int, text) -> int | None:
        if self.trace is None:
            return None
        self.trace.append(TraceEntry(start, self.pos - start, depth, text() if callable(text) else text))
        return len(self.trace) - 1

    def close(self, idx, start) -> None:
        if idx is not None:
            self.trace[idx].width = self.pos - start

    def align(self, what: str) -> None:
        n = (-self.pos) % 8
        if n:
            at = self.pos
            if self.rd(n, what) != 0:
                raise self.err(f"{what}: padding bits are not 0", "bifs-padding", at=at)

    # stream
    def stream(self) -> bt.Scene:
        p = self.pos
        self.id_bits = self.rd(5, "nodeIDbits")
        route_bits = self.rd(5, "routeIDbits")
        cmd = self.bit("isCommandStream")
        if not cmd:
            raise self.err("BIFSConfig: isCommandStream = 0 (animation-mask streams are not supported)",
                           "bifs-config", at=self.pos - 1)
        pixel = self.bit("pixelMetric")
        size = self.bit("hasSize")
        wh = None
        if size:
            wh = (self.rd(16, "pixelWidth"), self.rd(16, "pixelHeight"))
        self.align("BIFSConfig")
        self.note(p, 0, f"BIFSConfig nodeIDbits={self.id_bits} routeIDbits={route_bits} isCommandStream=1 "
                        f"pixelMetric={pixel} hasSize={size}" + (f" size={wh[0]}x{wh[1]}" if wh else ""))
        p = self.pos
        code = self.rd(2, "command code")
        if code != self.t.raw["command"]["replace_scene"]:
            raise self.err(f"command code {code}: only ReplaceScene (3) is supported", "bifs-command", at=p)
        self.rd(6, "reserved")
        self.use_names = bool(self.bit("useNames"))
        idx = self.note(p, 0, f"ReplaceScene useNames={int(self.use_names)}")
        top = self.node("SFTopNode", "", 1, None, sf=False, top=True)
        p2 = self.pos
        if self.bit("hasROUTEs"):
            raise self.err("ROUTEs are not supported", "bifs-routes", at=p2)
        p3 = self.pos
        if self.bit("continue"):
            raise self.err("more than one command in the access unit (only one ReplaceScene is supported)",
                           "bifs-command", at=p3)
        self.close(idx, p)
        self.align("access unit")
        if self.pos != self.nbits:
            raise self.err(f"{(self.nbits - self.pos) // 8} bytes after the access unit", "bifs-trailing")
        if top is None or isinstance(top, bt.Use):
            raise self.err("the top node is NULL or a USE", "bifs-top", at=p)
        if top.type == "OrderedGroup":
            if top.def_name is not None or set(top.fields) - {"children"}:
                raise self.err("the top OrderedGroup must carry only children (fbaconf's top-level list)",
                               "bifs-top", "OrderedGroup")
            nodes = list(top.fields.get("children", []))
        else:  # Group
            nodes = [top]
        return bt.Scene(nodes, self.file)

    # nodes
    def node(self, ndt_name: str, path: str, depth: int, allowed, *, sf: bool, top: bool = False,
             allow_null: bool = True):
        start = self.pos
        if depth > MAX_DEPTH + 1:
            raise self.err(f"nodes nested deeper than {MAX_DEPTH}", "bifs-depth", path)
        ndt = self.t.ndts[ndt_name]
        if self.bit("isReused", path):
            nid = self.rd(self.id_bits, "nodeID", path)
            if nid == (1 << self.id_bits) - 1:
                if not allow_null or top:
                    raise self.err("NULL is not allowed here", "bifs-null", path, at=start)
                self.note(start, depth, lambda: f"{path or 'top'}: NULL")
                return None
            d = self.defs.get(nid)
            if d is None or not d[2]:
                raise self.err(f"USE of node ID {nid}, which no complete node DEFined before", "bifs-use-undefined",
                               path, at=start + 1)
            name, ntype, _ = d
            if allowed is not None and ntype not in allowed:
                raise self.err(f"USE {name}: a {ntype} node is not allowed here "
                               f"(allowed: {', '.join(allowed) or 'NULL'})",
                               "bifs-node-type", path, at=start)
            self.note(start, depth, lambda: f"{path}: USE {name} (nodeID {nid}, {ntype})")
            return bt.Use(name)
        at = self.pos
        code = self.rd(ndt.bits, f"localNodeType ({ndt_name})", path)
        if code == 0:
            raise self.err(f"node code 0 in {ndt_name} (a node of a later BIFS version) is not supported",
                           "bifs-node-code", path, at=at)
        if code > len(ndt.nodes):
            raise self.err(f"unknown node code {code} in {ndt_name} ({len(ndt.nodes)} nodes)", "bifs-node-code",
                           path, at=at)
        ntype = ndt.nodes[code - 1]
        bn = self.t.nodes.get(ntype)
        if bn is None or (ntype == "OrderedGroup" and not top):
            raise self.err(f"node {ntype} (code {code} in {ndt_name}) is outside the subset fbaconf reads",
                           "bifs-unsupported-node", path, at=at)
        if top and ntype not in ("OrderedGroup", "Group"):
            raise self.err(f"top node {ntype} is not supported (Group or OrderedGroup)", "bifs-unsupported-node",
                           path, at=at)
        if allowed is not None and ntype not in allowed:
            raise self.err(f"a {ntype} node is not allowed here (allowed: {', '.join(allowed) or 'NULL'})",
                           "bifs-node-type", path, at=at)
        npath = _node_path(path, ntype, sf)
        def_name = None
        nid = None
        if self.bit("isUpdateable", npath):
            at = self.pos
            nid = self.rd(self.id_bits, "nodeID", npath)
            if nid == (1 << self.id_bits) - 1:
                raise self.err(f"nodeID {nid} (all ones) is reserved for NULL", "bifs-node-id", npath, at=at)
            if nid in self.defs:
                raise self.err(f"nodeID {nid} is DEFined twice", "bifs-def-duplicate", npath, at=at)
            def_name = self.name(npath) if self.use_names else f"N{nid}"
            if def_name in self.names or def_name in ("USE", "DEF", "NULL") or not _NAME.match(def_name):
                raise self.err(f"bad or duplicate DEF name {def_name!r}", "bifs-def-name", npath, at=at)
            self.names.add(def_name)
            self.defs[nid] = (def_name, ntype, False)
        idx = self.note(start, depth, lambda: f"{npath}: {f'DEF {def_name} (nodeID {nid}) ' if def_name else ''}"
                                              f"{ntype} (code {code}/{ndt_name})")
        node = bt.Node(ntype, {}, def_name)
        specs = bt.node_specs().get(ntype, {})
        fp = (lambda f: "") if top else (lambda f: f"{npath}.{f}")
        if self.bit("MaskAccess", npath):
            data = self.data
            for bf in bn.defs:
                pos = self.pos  # inlined self.bit("mask bit"): the FAP node has 68 of them
                if pos >= self.nbits:
                    raise self._truncated(1, "mask bit", npath)
                self.pos = pos + 1
                if (data[pos >> 3] >> (7 - (pos & 7))) & 1:
                    node.fields[bf.name] = self.field(bf, fp(bf.name), depth + 1, specs)
        else:
            while True:
                if self.bit("endFlag", npath):
                    break
                at = self.pos
                fid = self.rd(bn.def_bits, "field index", npath)
                if fid >= len(bn.defs):
                    raise self.err(f"{ntype} has no field with defID {fid} ({len(bn.defs)} fields)",
                                   "bifs-field-index", npath, at=at)
                bf = bn.defs[fid]
                if bf.name in node.fields:
                    raise self.err(f"field {bf.name!r} given twice", "bifs-duplicate-field", npath, at=at)
                node.fields[bf.name] = self.field(bf, fp(bf.name), depth + 1, specs)
        if nid is not None:
            self.defs[nid] = (def_name, ntype, True)
        self.close(idx, start)
        return node

    def name(self, path) -> str:
        raw = bytearray()
        while True:
            c = self.rd(8, "DEF name", path)
            if c == 0:
                break
            raw.append(c)
            if len(raw) > MAX_NAME_BYTES:
                raise self.err(f"DEF name longer than {MAX_NAME_BYTES} bytes", "bifs-def-name", path)
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise self.err("DEF name is not UTF-8", "bifs-def-name", path) from None

    # fields
    def field(self, bf: BifsField, path: str, depth: int, specs):
        spec = specs.get(bf.name)
        allowed = spec.allowed if spec is not None else None
        t = bf.type
        start = self.pos
        if t == "SFNode":
            return self.node(bf.ndt, path, depth, allowed, sf=True)
        if t.startswith("SF"):
            v = self.sf(t, path)
            self.note(start, depth, lambda: f"{path}: {t} = {_short(v)}")
            return v
        return self.mf(bf, path, depth, allowed, start)

    def float32s(self, raw: bytes, path, at) -> np.ndarray:
        a = np.frombuffer(raw, dtype=">f4")
        if not np.all(np.isfinite(a)):
            raise self.err("a float is NaN or infinite", "bifs-float", path, at=at)
        return a.astype(np.float32).astype(str).astype(np.float64)  # shortest decimal of each float32

    def sf(self, t: str, path: str):
        at = self.pos
        if t == "SFBool":
            return bool(self.bit("SFBool", path))
        if t == "SFInt32":
            v = self.rd(32, "SFInt32", path)
            return v - (1 << 32) if v & 0x80000000 else v
        if t == "SFFloat":
            return _f32_value(self.rd_bytes(4, "SFFloat", path), self, path, at)
        if t == "SFTime":
            x = struct.unpack(">d", self.rd_bytes(8, "SFTime", path))[0]
            if not math.isfinite(x):
                raise self.err("SFTime is NaN or infinite", "bifs-float", path, at=at)
            return x
        if t in _VEC:
            k = _VEC[t]
            raw = self.rd_bytes(4 * k, t, path)
            return tuple(_f32_value(raw[4 * i:4 * i + 4], self, path, at) for i in range(k))
        if t == "SFString":
            nb = self.rd(5, "SFString length bits", path)
            n = self.rd(nb, "SFString length", path)
            raw = self.rd_bytes(n, "SFString", path)
            try:
                return raw.decode("utf-8")
            except UnicodeDecodeError:
                raise self.err("SFString is not UTF-8", "bifs-string", path, at=at) from None
        raise self.err(f"field type {t} is not supported", "bifs-field-type", path, at=at)

    def mf(self, bf: BifsField, path: str, depth: int, allowed, start: int):
        t = bf.type
        at = self.pos
        if self.bit("MF reserved", path):
            raise self.err("MF field reserved bit is 1 (predictive MF coding is not supported)", "bifs-mf-reserved",
                           path, at=at)
        is_list = self.bit("isListDescription", path)
        idx = self.note(start, depth, lambda: f"{path or 'OrderedGroup.children'}: {t}")
        item_bits = _ITEM_BITS.get(t, 1)  # a lower bound for MFNode / MFString items
        items: list = []
        if is_list:
            node_items = t == "MFNode"
            while not self.bit("endFlag", path):
                items.append(self.mf_item(t, bf, f"{path}[{len(items)}]" if node_items else path, depth + 1, allowed))
            n = len(items)
        else:
            nb = self.rd(5, "MF count bits", path)
            at = self.pos
            n = self.rd(nb, "MF count", path)
            if n * item_bits > self.nbits - self.pos:
                raise self.err(f"{t} count {n} needs at least {n * item_bits} bits, {self.nbits - self.pos} left",
                               "bifs-mf-count", path, at=at)
            if t in ("MFNode", "MFString"):
                for i in range(n):
                    items.append(self.mf_item(t, bf, f"{path}[{i}]", depth + 1, allowed))
            else:
                raw = self.rd_bytes(n * item_bits // 8, t, path)
                if t == "MFInt32":
                    value = np.frombuffer(raw, dtype=">i4").astype(np.int64)
                else:
                    value = self.float32s(raw, path, at)
                    if t in _MF_VEC:
                        value = value.reshape(-1, _MF_VEC[t])
                self._mf_trace(idx, start, t, n, is_list, value)
                return value
        if t == "MFInt32":
            value = np.array(items, dtype=np.int64)
        elif t == "MFFloat":
            value = np.array(items, dtype=np.float64)
        elif t in _MF_VEC:
            value = np.array(items, dtype=np.float64).reshape(-1, _MF_VEC[t])
        else:
            value = items
        self._mf_trace(idx, start, t, n, is_list, value)
        return value

    def _mf_trace(self, idx, start, t, n, is_list, value) -> None:
        if idx is None:
            return
        self.close(idx, start)
        form = "list" if is_list else "vector"
        preview = "" if t == "MFNode" else f" {_short(value)}"
        self.trace[idx].text += f"[{n}] ({form}){preview}"

    def mf_item(self, t: str, bf: BifsField, path: str, depth: int, allowed):
        if t == "MFNode":
            return self.node(bf.ndt, path, depth, allowed, sf=False, allow_null=False)
        if t == "MFString":
            return self.sf("SFString", path)
        if t == "MFInt32":
            return self.sf("SFInt32", path)
        if t == "MFFloat":
            return self.sf("SFFloat", path)
        if t in _MF_VEC:
            return self.sf({"MFVec2f": "SFVec2f", "MFVec3f": "SFVec3f", "MFColor": "SFColor",
                            "MFRotation": "SFRotation"}[t], path)
        raise self.err(f"field type {t} is not supported", "bifs-field-type", path)


def _f32_value(raw: bytes, dec, path, at) -> float:
    """The shortest decimal (as a float) that rounds to the big-endian float32 ``raw``."""
    y = _f32_shortest(raw)
    if y is None:
        raise dec.err("a float is NaN or infinite", "bifs-float", path, at=at)
    return y


@lru_cache(maxsize=4096)
def _f32_shortest(raw: bytes) -> float | None:
    x = struct.unpack(">f", raw)[0]
    if not math.isfinite(x):
        return None
    for p in (6, 7, 8):
        y = float(f"{x:.{p}g}")
        if struct.pack(">f", y) == raw:
            return y
    return float(f"{x:.9g}")


def _short(v, limit: int = 60) -> str:
    if isinstance(v, np.ndarray):
        flat = v.reshape(-1)
        s = " ".join(bt.fmt_float(x) if v.dtype.kind == "f" else str(int(x)) for x in flat[:8])
        s = f"[{s}{' ...' if flat.size > 8 else ''}]"
    elif isinstance(v, bool):
        s = "TRUE" if v else "FALSE"
    elif isinstance(v, float):
        s = bt.fmt_float(v)
    elif isinstance(v, tuple):
        s = " ".join(bt.fmt_float(x) for x in v)
    elif isinstance(v, str):
        s = '"' + v + '"'
    elif isinstance(v, list):
        s = "[" + " ".join('"' + x + '"' for x in v[:8]) + (" ..." if len(v) > 8 else "") + "]"
    else:
        s = str(v)
    return s if len(s) <= limit else s[:limit - 3] + "..."


def decode(data: bytes, *, file: str | None = None, trace: list | None = None) -> bt.Scene:
    """The scene model of ``.bifs`` bytes (raises :class:`BifsError`). With ``trace`` (a
    list), a :class:`TraceEntry` is appended for the config, the command and every node and
    field, also when decoding fails part way."""
    dec = _Decoder(bytes(data), file, trace)
    try:
        return dec.stream()
    except BifsError:
        raise
    except BitstreamError as e:  # a BitReader error not caught above (never expected)
        raise BifsError(e.message, bit_offset=e.bit_offset, rule="bifs-truncated", file=file) from None
    except RecursionError:
        raise dec.err("nodes nested too deep", "bifs-depth") from None


def format_trace(entries: list[TraceEntry]) -> str:
    lines = [f"{'bit':>9} {'width':>7}  element"]
    for e in entries:
        lines.append(f"{e.bit_offset:>9} {e.width:>7}  {'  ' * e.depth}{e.text}")
    return "\n".join(lines)


def is_bifs_path(path) -> bool:
    return Path(path).suffix.lower() in BIFS_SUFFIXES


def read(path) -> bt.Scene:
    """Read a ``.bifs`` file (raises BifsError, or FbaconfInputError if it cannot be read)."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as e:
        raise FbaconfInputError(f"cannot read {p}: {e.strerror or e}", rule="io", file=str(p)) from None
    return decode(data, file=str(p))


def load_scene(path) -> bt.Scene:
    """A scene file by its extension: ``.bifs``/``.bif`` binary BIFS, anything else BT text."""
    return read(path) if is_bifs_path(path) else bt.read(path)


# ---------------------------------------------------------------------------------- CLI glue
def cmd_encode_scene(args) -> int:
    """``fbaconf encode S.bt -o S.bifs``."""
    from fbaconf._atomic import atomic_write_bytes
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
        import json
        print(json.dumps({"input": str(src), "output": str(out), "bt_bytes": src.stat().st_size,
                          "bifs_bytes": len(data)}))
    else:
        print(f"encoded scene {src} ({src.stat().st_size} bytes of BT) -> {out}: {len(data)} bytes of BIFS")
    return 0


def cmd_decode_scene(args) -> int:
    """``fbaconf decode S.bifs [-o S.bt] [--trace]``."""
    from fbaconf._atomic import atomic_write_text
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


__all__ = ["BifsError", "BifsEncodeError", "TraceEntry", "decode", "encode", "format_trace", "is_bifs_path",
           "load_scene", "read", "same_scene", "tables"]


# ---------------------------------------------------------------------------------- comparison
def same_scene(a: bt.Scene, b: bt.Scene) -> bool:
    """True when two scene models are equal with every float compared as float32 (the BIFS
    round-trip criterion: exact for integers, booleans, strings, names and structure)."""
    return isinstance(a, bt.Scene) and isinstance(b, bt.Scene) and _same(a.nodes, b.nodes)


def _f32(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float64).astype(np.float32)


def _same(a, b) -> bool:
    if isinstance(a, bt.Node) or isinstance(b, bt.Node):
        return (isinstance(a, bt.Node) and isinstance(b, bt.Node) and a.type == b.type
                and a.def_name == b.def_name and list(a.fields) == list(b.fields)
                and all(_same(a.fields[k], b.fields[k]) for k in a.fields))
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        if not (isinstance(a, np.ndarray) and isinstance(b, np.ndarray)) or a.shape != b.shape \
                or a.dtype.kind != b.dtype.kind:
            return False
        if a.dtype.kind == "f":
            return bool(np.array_equal(_f32(a), _f32(b)))
        return bool(np.array_equal(a, b))
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, tuple) and isinstance(b, tuple):
        return len(a) == len(b) and bool(np.array_equal(_f32(a), _f32(b)))
    if isinstance(a, float) and isinstance(b, float):
        return bool(_f32(a) == _f32(b))
    return type(a) is type(b) and a == b
