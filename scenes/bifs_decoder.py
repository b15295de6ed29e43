"""Binary BIFS decoder: a BIFSConfig plus ReplaceScene access unit to a BT scene, with a per-field bit
trace; reading .bifs files."""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from fbaconf.errors import BitstreamError, FbaconfInputError
from fbaconf.scenes import bt

from .bifs_encoder import node_path
from .bifs_tables import (
    BIFS_SUFFIXES,
    ITEM_BITS,
    MAX_DEPTH,
    MAX_NAME_BYTES,
    MF_VEC,
    NAME_RE,
    SF_VEC,
    BifsError,
    BifsField,
    tables,
)


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
        return self.err(
            f"stream ends inside {what} ({nbits} bits needed, {self.nbits - self.pos} left)", "bifs-truncated", path
        )

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
            raise self.err(
                f"stream ends inside {what} ({n} bytes declared, {(self.nbits - self.pos) // 8} left)",
                "bifs-truncated",
                path,
            )
        pos = self.pos
        self.pos = pos + 8 * n
        if pos & 7 == 0:
            return self.data[pos >> 3 : (pos >> 3) + n]
        sh = pos & 7
        v = int.from_bytes(self.data[pos >> 3 : (pos >> 3) + n + 1], "big") >> (8 - sh)
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
            raise self.err(
                "BIFSConfig: isCommandStream = 0 (animation-mask streams are not supported)",
                "bifs-config",
                at=self.pos - 1,
            )
        pixel = self.bit("pixelMetric")
        size = self.bit("hasSize")
        wh = None
        if size:
            wh = (self.rd(16, "pixelWidth"), self.rd(16, "pixelHeight"))
        self.align("BIFSConfig")
        self.note(
            p,
            0,
            f"BIFSConfig nodeIDbits={self.id_bits} routeIDbits={route_bits} isCommandStream=1 "
            f"pixelMetric={pixel} hasSize={size}" + (f" size={wh[0]}x{wh[1]}" if wh else ""),
        )
        p = self.pos
        code = self.rd(2, "command code")
        if code != self.t.raw["command"]["replace_scene"]:
            raise self.err(f"command code {code}: only ReplaceScene (3) is supported", "bifs-command", at=p)
        self.rd(6, "reserved")
        self.use_names = bool(self.bit("useNames"))
        pp = self.pos
        if self.bit("protoList"):  # D10: the proto-list flag after useNames
            raise self.err("PROTOs are not supported", "bifs-proto", at=pp)
        idx = self.note(p, 0, f"ReplaceScene useNames={int(self.use_names)} protoList=0")
        top = self.node("SFTopNode", "", 1, None, sf=False, top=True)
        p2 = self.pos
        if self.bit("hasROUTEs"):
            raise self.err("ROUTEs are not supported", "bifs-routes", at=p2)
        p3 = self.pos
        if self.bit("continue"):
            raise self.err(
                "more than one command in the access unit (only one ReplaceScene is supported)", "bifs-command", at=p3
            )
        self.close(idx, p)
        self.align("access unit")
        if self.pos != self.nbits:
            raise self.err(f"{(self.nbits - self.pos) // 8} bytes after the access unit", "bifs-trailing")
        if top is None or isinstance(top, bt.Use):
            raise self.err("the top node is NULL or a USE", "bifs-top", at=p)
        if top.type == "OrderedGroup":
            if top.def_name is not None or set(top.fields) - {"children"}:
                raise self.err(
                    "the top OrderedGroup must carry only children (fbaconf's top-level list)",
                    "bifs-top",
                    "OrderedGroup",
                )
            nodes = list(top.fields.get("children", []))
        else:  # Group
            nodes = [top]
        return bt.Scene(nodes, self.file)

    # nodes
    def node(
        self, ndt_name: str, path: str, depth: int, allowed, *, sf: bool, top: bool = False, allow_null: bool = True
    ):
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
                raise self.err(
                    f"USE of node ID {nid}, which no complete node DEFined before",
                    "bifs-use-undefined",
                    path,
                    at=start + 1,
                )
            name, ntype, _ = d
            if allowed is not None and ntype not in allowed:
                raise self.err(
                    f"USE {name}: a {ntype} node is not allowed here (allowed: {', '.join(allowed) or 'NULL'})",
                    "bifs-node-type",
                    path,
                    at=start,
                )
            self.note(start, depth, lambda: f"{path}: USE {name} (nodeID {nid}, {ntype})")
            return bt.Use(name)
        at = self.pos
        code = self.rd(ndt.bits, f"localNodeType ({ndt_name})", path)
        if code == 0:
            raise self.err(
                f"node code 0 in {ndt_name} (a node of a later BIFS version) is not supported",
                "bifs-node-code",
                path,
                at=at,
            )
        if code > len(ndt.nodes):
            raise self.err(
                f"unknown node code {code} in {ndt_name} ({len(ndt.nodes)} nodes)", "bifs-node-code", path, at=at
            )
        ntype = ndt.nodes[code - 1]
        bn = self.t.nodes.get(ntype)
        if bn is None or (ntype == "OrderedGroup" and not top):
            raise self.err(
                f"node {ntype} (code {code} in {ndt_name}) is outside the subset fbaconf reads",
                "bifs-unsupported-node",
                path,
                at=at,
            )
        if top and ntype not in ("OrderedGroup", "Group"):
            raise self.err(
                f"top node {ntype} is not supported (Group or OrderedGroup)", "bifs-unsupported-node", path, at=at
            )
        if allowed is not None and ntype not in allowed:
            raise self.err(
                f"a {ntype} node is not allowed here (allowed: {', '.join(allowed) or 'NULL'})",
                "bifs-node-type",
                path,
                at=at,
            )
        npath = node_path(path, ntype, sf)
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
            if def_name in self.names or def_name in ("USE", "DEF", "NULL") or not NAME_RE.match(def_name):
                raise self.err(f"bad or duplicate DEF name {def_name!r}", "bifs-def-name", npath, at=at)
            self.names.add(def_name)
            self.defs[nid] = (def_name, ntype, False)
        idx = self.note(
            start,
            depth,
            lambda: f"{npath}: {f'DEF {def_name} (nodeID {nid}) ' if def_name else ''}{ntype} (code {code}/{ndt_name})",
        )
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
                    raise self.err(
                        f"{ntype} has no field with defID {fid} ({len(bn.defs)} fields)",
                        "bifs-field-index",
                        npath,
                        at=at,
                    )
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
        # the shortest decimal of each float32; numpy's legacy print mode (which colour-science
        # turns on when imported) would cut it to 6 digits, so the mode is fixed here
        with np.printoptions(legacy=False):
            return a.astype(np.float32).astype(str).astype(np.float64)

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
        if t in SF_VEC:
            k = SF_VEC[t]
            raw = self.rd_bytes(4 * k, t, path)
            return tuple(_f32_value(raw[4 * i : 4 * i + 4], self, path, at) for i in range(k))
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
            raise self.err(
                "MF field reserved bit is 1 (predictive MF coding is not supported)", "bifs-mf-reserved", path, at=at
            )
        is_list = self.bit("isListDescription", path)
        idx = self.note(start, depth, lambda: f"{path or 'OrderedGroup.children'}: {t}")
        item_bits = ITEM_BITS.get(t, 1)  # a lower bound for MFNode / MFString items
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
                raise self.err(
                    f"{t} count {n} needs at least {n * item_bits} bits, {self.nbits - self.pos} left",
                    "bifs-mf-count",
                    path,
                    at=at,
                )
            if t in ("MFNode", "MFString", "MFURL"):
                for i in range(n):
                    items.append(self.mf_item(t, bf, f"{path}[{i}]", depth + 1, allowed))
            else:
                raw = self.rd_bytes(n * item_bits // 8, t, path)
                if t == "MFInt32":
                    value = np.frombuffer(raw, dtype=">i4").astype(np.int64)
                else:
                    value = self.float32s(raw, path, at)
                    if t in MF_VEC:
                        value = value.reshape(-1, MF_VEC[t])
                self._mf_trace(idx, start, t, n, is_list, value)
                return value
        if t == "MFInt32":
            value = np.array(items, dtype=np.int64)
        elif t == "MFFloat":
            value = np.array(items, dtype=np.float64)
        elif t in MF_VEC:
            value = np.array(items, dtype=np.float64).reshape(-1, MF_VEC[t])
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
        if t == "MFURL":  # D10: isOD(1), then a 10-bit object descriptor ID or the URL string
            if self.bit("isOD", path):
                return f"od:{self.rd(10, 'objectDescriptorID', path)}"
            return self.sf("SFString", path)
        if t == "MFInt32":
            return self.sf("SFInt32", path)
        if t == "MFFloat":
            return self.sf("SFFloat", path)
        if t in MF_VEC:
            return self.sf(
                {"MFVec2f": "SFVec2f", "MFVec3f": "SFVec3f", "MFColor": "SFColor", "MFRotation": "SFRotation"}[t], path
            )
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
    return s if len(s) <= limit else s[: limit - 3] + "..."


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
