"""Binary BIFS encoder: a BT scene to a BIFSConfig plus one ReplaceScene access unit."""

from __future__ import annotations

import math
import re
import struct

import numpy as np

from fbaconf.bitstreams.bitio import BitWriter
from fbaconf.scenes import bt

from .bifs_tables import F32_MAX, MAX_NAME_BYTES, MF_VEC, SF_VEC, BifsEncodeError, BifsField, tables


class BifsWriter(BitWriter):
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


def node_path(path: str, ntype: str, sf: bool) -> str:
    """A node's path as the BT reader names it (top-level list items as ``[i]Type``)."""
    if not path or _TOP_ITEM.match(path):
        return f"{path}{ntype}"
    return f"{path}.{ntype}" if sf else path


def _count_bits(n: int) -> int:
    return int(n).bit_length()


class _Encoder:
    def __init__(self, scene: bt.Scene, use_names: bool) -> None:
        self.t = tables()
        self.w = BifsWriter()
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
            raise self.err(
                f"a {v.type} node cannot be coded inline where the node data type is {ndt} "
                f"(DEF it where it belongs and USE it here)",
                "bifs-ndt",
                path,
            )
        if allowed is not None and v.type not in allowed:
            raise self.err(f"a {v.type} node is not allowed here", "bifs-node-type", path)
        npath = node_path(path, v.type, sf)
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

    def string_item(self, t: str, s: str, path: str) -> None:
        """An MFString item, or an MFURL item (D10): isOD(1), then a 10-bit object descriptor
        ID for ``od:N`` or the URL as an SFString."""
        if t == "MFURL":
            m = OD_URL.match(s) if isinstance(s, str) else None
            if m and int(m.group(1)) < 1024:
                self.w.bit(1)
                self.w.write(int(m.group(1)), 10)
                return
            self.w.bit(0)
        self.sf("SFString", s, path)

    def sf(self, t: str, v, path: str) -> None:
        w = self.w
        try:
            if t == "SFBool":
                if not isinstance(v, (bool, np.bool_)):
                    raise TypeError
                w.bit(1 if v else 0)
            elif t == "SFInt32":
                iv = int(v)
                if isinstance(v, (bool, float)) or not -(2**31) <= iv < 2**31:
                    raise ValueError(f"{v!r} is not an SFInt32")
                w.write(iv & 0xFFFFFFFF, 32)
            elif t == "SFFloat":
                w.write_bytes(self.floats([v], path))
            elif t == "SFTime":
                x = float(v)
                if not math.isfinite(x):
                    raise ValueError(f"{v!r} is not finite")
                w.write_bytes(struct.pack(">d", x))
            elif t in SF_VEC:
                vals = list(v)
                if len(vals) != SF_VEC[t]:
                    raise ValueError(f"{t} needs {SF_VEC[t]} numbers")
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
        if a.size and (not np.all(np.isfinite(a)) or np.abs(a).max() > F32_MAX):
            raise self.err("a float is not finite or outside the float32 range", "bifs-value", path)
        return a.astype(">f4").tobytes()

    def mf_items(self, n: int, write_item) -> None:
        """An MF field's ``n`` values: reserved(1) = 0, then the cheaper of the list form
        (isList 1, endFlag 0 before each value, endFlag 1) and the vector form (isList 0,
        nbBits(5), count(nbBits), the values). The values cost the same in both, so the list
        wins exactly when its n + 1 flag bits are fewer than the vector's 5 + nbBits."""
        w = self.w
        nb = _count_bits(n)
        w.bit(0)  # reserved
        if n + 1 < 5 + nb:
            w.bit(1)
            for i in range(n):
                w.bit(0)
                write_item(i)
            w.bit(1)
        else:
            w.bit(0)
            w.write(nb, 5)
            w.write(n, nb)
            for i in range(n):
                write_item(i)

    def mf(self, bf: BifsField, val, path: str, allowed) -> None:
        t = bf.type
        if t == "MFNode":
            items = list(val)
            self.mf_items(
                len(items), lambda i: self.node(items[i], bf.ndt, f"{path}[{i}]", allowed, sf=False, allow_null=False)
            )
            return
        if t in ("MFString", "MFURL"):
            items = list(val)
            self.mf_items(len(items), lambda i: self.string_item(t, items[i], path))
            return
        arr = np.asarray(val)
        if t == "MFInt32":
            if arr.size and (arr.dtype.kind not in "iu" or arr.min() < -(2**31) or arr.max() >= 2**31):
                raise self.err("MFInt32 values must be integers in the int32 range", "bifs-value", path)
            raw = arr.reshape(-1).astype(">i4").tobytes()
            per = 4
        elif t == "MFFloat":
            raw = self.floats(arr.reshape(-1), path)
            per = 4
        elif t in MF_VEC:
            k = MF_VEC[t]
            if arr.size % k:
                raise self.err(f"{t} needs a multiple of {k} numbers", "bifs-value", path)
            raw = self.floats(arr.reshape(-1), path)
            per = 4 * k
        else:
            raise self.err(f"field type {t} is not supported", "bifs-field-type", path)
        self.mf_items(len(raw) // per, lambda i: self.w.write_bytes(raw[i * per : (i + 1) * per]))


OD_URL = re.compile(r"od:(\d+)\Z")


def encode(scene: bt.Scene, *, use_names: bool = True) -> bytes:
    """The ``.bifs`` bytes of a scene model (raises :class:`BifsEncodeError`)."""
    t = tables()
    enc = _Encoder(scene, use_names)
    w = enc.w
    # BIFSConfig (v1)
    if enc.id_bits > 31:
        raise BifsEncodeError("too many DEF nodes", rule="bifs-node-id")
    w.write(enc.id_bits, 5)  # nodeIDbits
    w.write(0, 5)  # routeIDbits (no routes)
    w.bit(1)  # isCommandStream
    w.bit(0)  # pixelMetric
    w.bit(0)  # hasSize
    w.align()
    # access unit: one ReplaceScene command
    w.write(t.raw["command"]["replace_scene"], 2)
    w.write(0, 6)  # reserved
    w.bit(1 if use_names else 0)  # useNames
    w.bit(0)  # protoList: no PROTOs (D10: GPAC writes and always reads it)
    top = bt.Node("OrderedGroup", {"children": list(scene.nodes)})
    ndt = t.ndts["SFTopNode"]
    w.bit(0)  # isReused
    w.write(ndt.code("OrderedGroup"), ndt.bits)
    w.bit(0)  # isUpdateable
    bn = t.nodes["OrderedGroup"]
    w.bit(1)  # masked description
    for bf in bn.defs:
        if bf.name == "children":
            w.bit(1)
            enc.mf(bf, top.fields["children"], "", None)
            continue
        w.bit(0)
    w.bit(0)  # hasROUTEs
    w.bit(0)  # no further command
    w.align()
    return w.getvalue()
