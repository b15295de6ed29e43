"""Binary BIFS: constants, typed errors and the node/field tables of scenes/data/bifs_nodes.toml
(checked against the BT field tables)."""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

import numpy as np

from fbaconf.errors import BitstreamError, SceneError
from fbaconf.scenes import bt

BIFS_SUFFIXES = (".bifs", ".bif")
MAX_DEPTH = bt.MAX_DEPTH
MAX_NAME_BYTES = 1024
F32_MAX = float(np.finfo(np.float32).max)
SF_VEC = {"SFVec2f": 2, "SFVec3f": 3, "SFColor": 3, "SFRotation": 4}
MF_VEC = {"MFVec2f": 2, "MFVec3f": 3, "MFColor": 3, "MFRotation": 4}
NAME_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_\-.]*\Z")
ITEM_BITS = {"MFInt32": 32, "MFFloat": 32, **{t: 32 * k for t, k in MF_VEC.items()}}


class BifsError(BitstreamError):
    """A binary BIFS scene violates the syntax or the subset fbaconf reads."""

    rule = "bifs"

    def __init__(
        self, message: str, *, bit_offset: int, rule: str, node_path: str | None = None, file: str | None = None
    ) -> None:
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


@dataclass(frozen=True)
class BifsField:
    name: str
    event: str  # field | exposedField | eventIn | eventOut
    type: str  # SFInt32, MFNode, ...
    ndt: str | None  # node data type of SFNode/MFNode fields
    quant: int  # quantisation category (documentation; never applied, see module doc)
    def_id: int | None  # index among field/exposedField entries (None for events)


@dataclass(frozen=True)
class BifsNode:
    name: str
    provenance: str
    fields: tuple[BifsField, ...]  # all fields in table order
    defs: tuple[BifsField, ...]  # the defID fields, in defID order
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
            bf = BifsField(
                f["name"], f["event"], f["type"], f.get("ndt"), int(f.get("quant", 0)), len(defs) if is_def else None
            )
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
            if bf is None or (bf.type != spec.type and (bf.type, spec.type) != ("MFURL", "MFString")):
                raise RuntimeError(f"bifs_nodes.toml: {ntype}.{fname} missing or not {spec.type}")
    return Tables(raw, ndts, nodes)
