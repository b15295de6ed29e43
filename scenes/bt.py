"""BT text (BIFS text, the syntax GPAC's MP4Box reads) for the Face node family and the
VRML geometry nodes a face model needs.

Syntax handled: ``[DEF name] NodeType { field value ... }``, ``USE name``, ``NULL``,
MF values in ``[ ... ]`` (or a single value without brackets), SFVec2f/SFVec3f/SFColor as
2/3 numbers, SFRotation as 4, SFBool ``TRUE``/``FALSE``, strings in double quotes with
``\\"`` and ``\\\\`` escapes (an MFURL item also as MP4Box dumps it: ``od:N`` unquoted), ``#``
comments to the end of the line; commas are whitespace.
A file is a sequence of top-level nodes. DEF names must be unique in a file (a second
DEF of a name is an error); ``USE`` may name a node only after its closing brace. Field tables come
from ``data/bt_nodes.toml``
(plus the FAP node's 66 SFInt32 fields from the FAP table).

Scene model: :class:`Node` (``type``, ``fields`` = only the fields written in the file, in
file order; ``def_name``), :class:`Use` (a ``USE name`` reference) and :class:`Scene`
(top-level nodes). Values: SFInt32 int, SFFloat/SFTime float, SFBool bool, SFString str,
SFVec2f/SFVec3f/SFColor/SFRotation tuple of floats, SFNode Node/Use/None, MFInt32
int64[n], MFFloat float64[n], MFVec2f float64[n, 2], MFVec3f/MFColor float64[n, 3],
MFRotation float64[n, 4], MFString list[str], MFNode list[Node | Use].
Text -> model -> text -> model gives an identical model (floats are written with Python's
shortest round-trip repr).

Errors raise :class:`TextFormatError` with line:column and the node path, e.g.
``Face.fdp.FDP.faceDefTables[2].faceDefMesh[0].coordIndex`` (an SFNode field adds
``.field.Type``, an MFNode field ``.field[i]``). The reader is bounded: a file of at most
:data:`MAX_FILE_BYTES` (a regular file: never a FIFO that blocks), tokens of at most
:data:`MAX_TOKEN` characters, and an error quotes at most the first 40 characters of a token.
"""

from __future__ import annotations

import bisect
import re
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from fbaconf.bitstreams.tables import fap_table
from fbaconf.errors import FbaconfInputError, TextFormatError
from fbaconf.safefs import read_regular

FAP_NOT_SET = -2147483648  # FAP node field default 0x80000000
MAX_DEPTH = 100  # node nesting limit of the reader (a deeper file is rejected, never a RecursionError)
MAX_TOKEN = 1 << 20  # characters of one token (a name, a number, a quoted string)
MAX_FILE_BYTES = 64 << 20  # a scene file (the default head is about 1 MB)
_VEC_SIZES = {"SFVec2f": 2, "SFVec3f": 3, "SFColor": 3, "SFRotation": 4}
_MF_VEC = {"MFVec2f": 2, "MFVec3f": 3, "MFColor": 3, "MFRotation": 4}
SF_TYPES = {"SFInt32", "SFFloat", "SFTime", "SFBool", "SFString", "SFNode", *_VEC_SIZES}
MF_TYPES = {"MFInt32", "MFFloat", "MFString", "MFNode", *_MF_VEC}


@dataclass(frozen=True)
class FieldSpec:
    name: str
    type: str
    default: Any
    allowed: tuple[str, ...] | None = None  # node types an SFNode/MFNode field accepts (None = any)


@lru_cache(maxsize=1)
def node_specs() -> dict[str, dict[str, FieldSpec]]:
    """Node type -> field name -> FieldSpec (from data/bt_nodes.toml + the FAP table)."""
    raw = tomllib.loads(resources.files("fbaconf.scenes").joinpath("data", "bt_nodes.toml").read_text("utf-8"))
    out: dict[str, dict[str, FieldSpec]] = {}
    for ntype, flds in raw.items():
        specs = {}
        for fname, entry in flds.items():
            ftype, default = entry[0], entry[1]
            allowed = tuple(entry[2]) if len(entry) > 2 else None
            if ftype not in SF_TYPES | MF_TYPES:
                raise RuntimeError(f"bt_nodes.toml: {ntype}.{fname} has unknown type {ftype}")
            specs[fname] = FieldSpec(fname, ftype, _convert_default(ftype, default), allowed)
        out[ntype] = specs
    for f in fap_table()[2:]:
        out["FAP"][f.bifs_name] = FieldSpec(f.bifs_name, "SFInt32", FAP_NOT_SET)
    return out


def _convert_default(ftype: str, d):
    if ftype == "SFNode":
        return None
    if ftype in _VEC_SIZES:
        return tuple(float(x) for x in d)
    if ftype == "SFFloat" or ftype == "SFTime":
        return float(d)
    if ftype in MF_TYPES:
        return _empty_mf(ftype)
    return d


def _empty_mf(ftype: str):
    if ftype == "MFInt32":
        return np.zeros(0, np.int64)
    if ftype == "MFFloat":
        return np.zeros(0, np.float64)
    if ftype in _MF_VEC:
        return np.zeros((0, _MF_VEC[ftype]), np.float64)
    return []


# ---------------------------------------------------------------------------------- model
@dataclass(eq=False)
class Use:
    name: str

    def __eq__(self, other) -> bool:
        return isinstance(other, Use) and other.name == self.name

    def __repr__(self) -> str:
        return f"Use({self.name!r})"


@dataclass(eq=False)
class Node:
    type: str
    fields: dict[str, Any] = field(default_factory=dict)
    def_name: str | None = None

    def get(self, name: str):
        """A field's value, or its default when the file does not set it."""
        if name in self.fields:
            return self.fields[name]
        spec = node_specs()[self.type].get(name)
        if spec is None:
            raise KeyError(f"{self.type} has no field {name!r}")
        d = spec.default
        return d.copy() if isinstance(d, (np.ndarray, list)) else d

    def __eq__(self, other) -> bool:
        return (
            isinstance(other, Node)
            and self.type == other.type
            and self.def_name == other.def_name
            and list(self.fields) == list(other.fields)
            and all(_value_eq(self.fields[k], other.fields[k]) for k in self.fields)
        )

    def __repr__(self) -> str:
        d = f"DEF {self.def_name} " if self.def_name else ""
        return f"Node({d}{self.type}, {list(self.fields)})"


def _value_eq(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (
            isinstance(a, np.ndarray)
            and isinstance(b, np.ndarray)
            and a.dtype.kind == b.dtype.kind
            and a.shape == b.shape
            and bool(np.array_equal(a, b))
        )
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_value_eq(x, y) for x, y in zip(a, b))
    if type(a) is not type(b) and not (
        isinstance(a, (int, float))
        and isinstance(b, (int, float))
        and not isinstance(a, bool)
        and not isinstance(b, bool)
    ):
        return False
    return a == b


@dataclass(eq=False)
class Scene:
    """A scene as read (or built): not changed once a reader or builder returns it — its DEF
    table is computed at the first :meth:`defs` or :meth:`resolve` and kept (a USE resolved
    per lookup walked the whole tree: quadratic on the level-limit scenes)."""

    nodes: list = field(default_factory=list)  # top-level Node / Use
    file: str | None = None
    _defs: dict | None = field(default=None, init=False, repr=False)
    _defs_of: tuple = field(default=(), init=False, repr=False)

    def __eq__(self, other) -> bool:
        return isinstance(other, Scene) and _value_eq(self.nodes, other.nodes)

    def defs(self) -> dict[str, Node]:
        """DEF name -> the first node written with it (read-only: the table is kept)."""
        key = (id(self.nodes), len(self.nodes), *map(id, self.nodes))  # a top-level change is seen
        if self._defs is None or self._defs_of != key:
            out: dict[str, Node] = {}
            for node, _ in self.walk():
                if node.def_name and node.def_name not in out:
                    out[node.def_name] = node
            self._defs, self._defs_of = out, key
        return self._defs

    def resolve(self, v):
        """Node for a Node/Use value (None for None)."""
        if isinstance(v, Use):
            try:
                return self.defs()[v.name]
            except KeyError:
                raise KeyError(f"USE {v.name}: no such DEF") from None
        return v

    def walk(self) -> Iterator[tuple[Node, str]]:
        """Every Node written in the scene (USE references not followed), with its path."""

        def rec(node, path):
            yield node, path
            specs = node_specs()[node.type]
            for fname, v in node.fields.items():
                t = specs[fname].type
                if t == "SFNode" and isinstance(v, Node):
                    yield from rec(v, f"{path}.{fname}.{v.type}")
                elif t == "MFNode":
                    for i, c in enumerate(v):
                        if isinstance(c, Node):
                            yield from rec(c, f"{path}.{fname}[{i}]")

        for i, n in enumerate(self.nodes):
            if isinstance(n, Node):
                yield from rec(n, n.type if len(self.nodes) == 1 else f"[{i}]{n.type}")

    def find(self, node_type: str) -> list[tuple[Node, str]]:
        return [(n, p) for n, p in self.walk() if n.type == node_type]


# ---------------------------------------------------------------------------------- reader
_TOKEN = re.compile(
    r'(?P<ws>[\s,]+)|(?P<comment>#[^\n]*)|(?P<str>"(?:[^"\\]|\\.)*")|(?P<punct>[{}\[\]])|'
    r'(?P<word>[^\s,{}\[\]"#]+)|(?P<bad>.)',
    re.S,
)
_INT = re.compile(r"[+-]?(?:0[xX][0-9a-fA-F]+|[0-9]+)\Z")
_FLOAT = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\Z")
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_\-.]*\Z")
# An object-descriptor URL as GPAC's MP4Box dumps an MFURL item: unquoted ``od:N`` (``url [od:5]``;
# the empty URL, which BIFS codes as an empty string, is dumped as ``od:0``). Fields named ``url``
# are MFURL in BIFS (docs/bifs.md, D10).
_OD_WORD = re.compile(r"od:([0-9]{1,10})\Z")
URL_FIELDS = frozenset({"url"})


TOP_GROUP = "OrderedGroup"  # the top node that carries a scene's top-level list


class _Reader:
    def __init__(self, text: str, file: str | None) -> None:
        self.file = file
        self.text = text
        self.line_starts = [0] + [m.end() for m in re.finditer("\n", text)]
        self.toks: list[tuple[str, str, int]] = []
        for m in _TOKEN.finditer(text):
            kind = m.lastgroup
            if kind in ("ws", "comment"):
                continue
            if m.end() - m.start() > MAX_TOKEN:  # measured before the token is copied
                raise self.error(
                    f"a token of {m.end() - m.start()} characters ({text[m.start() : m.start() + 40]!r}…), "
                    f"longer than the reader's limit of {MAX_TOKEN}",
                    m.start(),
                    "bt-token-size",
                )
            if kind == "bad":
                raise self.error(
                    "unterminated string" if m.group() == '"' else f"unexpected character {m.group()!r}",
                    m.start(),
                    "bt-token",
                )
            self.toks.append((kind, m.group(), m.start()))
        self.i = 0
        self.depth = 0
        self.defs: dict[str, Node] = {}
        self.pending: set[str] = set()

    def pos(self, offset: int) -> tuple[int, int]:
        ln = bisect.bisect_right(self.line_starts, offset)
        return ln, offset - self.line_starts[ln - 1] + 1

    def error(self, msg, offset, rule, path=None):
        ln, col = self.pos(offset)
        return TextFormatError(msg, line=ln, column=col, rule=rule, file=self.file, node_path=path)

    def peek(self):
        return self.toks[self.i] if self.i < len(self.toks) else ("eof", "", len(self.text))

    def next(self, path=None, what="a token"):
        if self.i >= len(self.toks):
            raise self.error(f"unexpected end of file, expected {what}", len(self.text), "bt-eof", path)
        t = self.toks[self.i]
        self.i += 1
        return t

    def expect(self, value, path):
        kind, v, off = self.next(path, repr(value))
        if v != value or kind != "punct":
            raise self.error(f"expected {_clip(value)}, got {_clip(v)}", off, "bt-syntax", path)

    # nodes -----------------------------------------------------------------------
    def scene(self) -> Scene:
        self._skip_descriptor()
        kind, v, _off = self.peek()
        if kind == "word" and v == TOP_GROUP:
            nodes = self._top_group()
            kind, v, off = self.peek()
            if kind != "eof":
                raise self.error(f"nothing may follow the top {TOP_GROUP} (got {_clip(v)})", off, "bt-syntax")
            return Scene(nodes, self.file)
        nodes = []
        while self.peek()[0] != "eof":
            nodes.append(self.node_or_use(None, allow_null=False))
        return Scene(nodes, self.file)

    def _skip_descriptor(self) -> None:
        """MP4Box's dumps start with the scene's ``InitialObjectDescriptor { ... }``: systems
        information (ES descriptors, BIFSConfig), not part of the scene; skipped."""
        kind, v, _off = self.peek()
        if kind != "word" or v != "InitialObjectDescriptor":
            return
        self.next()
        self.expect("{", "InitialObjectDescriptor")
        depth = 1
        while depth:
            kind, v, _off = self.next("InitialObjectDescriptor", "'}'")
            if kind == "punct" and v in "{[":
                depth += 1
            elif kind == "punct" and v in "}]":
                depth -= 1

    def _top_group(self) -> list:
        """The one top node MP4Box wants, ``OrderedGroup { children [ ... ] }``: its children
        are the scene's top-level nodes (as in binary BIFS, scenes/bifs.py)."""
        self.next()
        self.expect("{", TOP_GROUP)
        nodes = []
        kind, v, off = self.next(TOP_GROUP, "children or '}'")
        if kind == "word" and v == "children":
            self.expect("[", f"{TOP_GROUP}.children")
            while self.peek()[1] != "]" or self.peek()[0] != "punct":
                nodes.append(self.node_or_use(f"{TOP_GROUP}.children", allow_null=False))
            self.next()
            kind, v, off = self.next(TOP_GROUP, "'}'")
        if kind != "punct" or v != "}":
            raise self.error(f"the top {TOP_GROUP} carries only children (got {_clip(v)})", off, "bt-syntax", TOP_GROUP)
        return nodes

    def node_or_use(self, path, allow_null=True, sf=False, allowed=None):
        kind, v, off = self.next(path, "a node")
        self.depth += 1
        try:
            return self._node_or_use(path, allow_null, sf, kind, v, off, allowed)
        finally:
            self.depth -= 1

    def _check_type(self, ntype, allowed, off, path):
        if allowed is not None and ntype not in allowed:
            ok = ", ".join(allowed) if allowed else "no node (NULL only)"
            raise self.error(f"a {ntype} node is not allowed here (allowed: {ok})", off, "bt-node-type", path)

    def _node_or_use(self, path, allow_null, sf, kind, v, off, allowed):
        if self.depth > MAX_DEPTH:
            raise self.error(f"nodes nested deeper than {MAX_DEPTH}", off, "bt-depth", path)
        if kind != "word":
            raise self.error(f"expected a node, got {_clip(v)}", off, "bt-syntax", path)
        if v == "NULL" and allow_null:
            return None
        if v == "USE":
            kind, name, off2 = self.next(path, "a DEF name")
            if kind != "word" or name not in self.defs:
                raise self.error(
                    f"USE {_clip(name)}: no node was DEFined with this name before", off2, "bt-use-undefined", path
                )
            self._check_type(self.defs[name].type, allowed, off2, path)
            return Use(name)
        def_name = None
        if v == "DEF":
            kind, def_name, off2 = self.next(path, "a DEF name")
            if kind != "word" or not _NAME.match(def_name) or def_name in ("USE", "DEF", "NULL"):
                raise self.error(f"bad DEF name {_clip(def_name)}", off2, "bt-def-name", path)
            if def_name in self.defs or def_name in self.pending:
                raise self.error(f"DEF {def_name} is defined twice", off2, "bt-def-duplicate", path)
            self.pending.add(def_name)
            kind, v, off = self.next(path, "a node type")
        specs = node_specs().get(v)
        if specs is None:
            raise self.error(f"unknown node type {_clip(v)}", off, "bt-unknown-node", path)
        self._check_type(v, allowed, off, path)
        npath = v if path is None else (f"{path}.{v}" if sf else path)
        node = Node(v, {}, def_name)
        self.expect("{", npath)
        while True:
            kind, fname, foff = self.next(npath, "a field name or '}'")
            if kind == "punct" and fname == "}":
                break
            if kind != "word":
                raise self.error(f"expected a field name, got {_clip(fname)}", foff, "bt-syntax", npath)
            spec = specs.get(fname)
            if spec is None:
                raise self.error(f"{v} has no field {_clip(fname)}", foff, "bt-unknown-field", npath)
            if fname in node.fields:
                raise self.error(f"field {_clip(fname)} given twice", foff, "bt-duplicate-field", npath)
            node.fields[fname] = self.value(spec, f"{npath}.{fname}")
        if def_name is not None:
            self.pending.discard(def_name)
            self.defs[def_name] = node  # usable by USE after the node's closing brace
        return node

    # values ------------------------------------------------------------------------
    def number(self, path, integer: bool):
        kind, v, off = self.next(path, "a number")
        if kind != "word":
            raise self.error(f"expected a number, got {_clip(v)}", off, "bt-number", path)
        if integer:
            if not _INT.match(v):
                raise self.error(f"expected an integer, got {_clip(v)}", off, "bt-number", path)
            if len(v.lstrip("+-").lstrip("0")) > 12:  # beyond SFInt32 by its length alone (no huge int())
                raise self.error(
                    f"integer {v[:20]}... ({len(v)} characters) out of SFInt32 range", off, "bt-number", path
                )
            n = int(v, 10) if not v.lstrip("+-").startswith(("0x", "0X")) else int(v, 16)
            if n > 0xFFFFFFFF or n < -2147483648:
                raise self.error(f"integer {_clip(v)} out of SFInt32 range", off, "bt-number", path)
            if n > 2147483647:  # hex written unsigned (0x80000000)
                n -= 1 << 32
            return n
        if not _FLOAT.match(v):
            raise self.error(f"expected a number, got {_clip(v)}", off, "bt-number", path)
        x = float(v)
        if not np.isfinite(x):
            raise self.error(f"number {_clip(v)} out of range", off, "bt-number", path)
        return x

    def sf(self, t, path):
        if t == "SFInt32":
            return self.number(path, True)
        if t in ("SFFloat", "SFTime"):
            return self.number(path, False)
        if t in _VEC_SIZES:
            return tuple(self.number(path, False) for _ in range(_VEC_SIZES[t]))
        if t == "SFBool":
            kind, v, off = self.next(path, "TRUE or FALSE")
            if v not in ("TRUE", "FALSE", "true", "false") or kind != "word":  # MP4Box dumps lowercase
                raise self.error(f"expected TRUE or FALSE, got {_clip(v)}", off, "bt-bool", path)
            return v in ("TRUE", "true")
        if t == "SFString":
            kind, v, off = self.next(path, "a string")
            if kind != "str":
                raise self.error(f"expected a quoted string, got {_clip(v)}", off, "bt-string", path)
            return re.sub(r"\\(.)", r"\1", v[1:-1], flags=re.S)
        raise AssertionError(t)

    def url_item(self, path) -> str:
        """An MFURL item: a quoted string, or MP4Box's unquoted ``od:N`` (read as the string
        ``"od:N"``, which the BIFS coder writes as object descriptor N; ``od:0`` is the empty URL)."""
        kind, v, off = self.peek()
        if kind == "word":
            m = _OD_WORD.match(v)
            if m is None:
                raise self.error(f"expected a quoted string or od:N, got {_clip(v)}", off, "bt-string", path)
            self.next(path)
            n = int(m.group(1))
            return f"od:{n}" if n else ""
        return self.sf("SFString", path)

    def value(self, spec, path):
        t = spec.type
        if t == "SFNode":
            return self.node_or_use(path, sf=True, allowed=spec.allowed)
        if t in SF_TYPES:
            return self.sf(t, path)
        # MF
        bracket = self.peek()[0] == "punct" and self.peek()[1] == "["
        if bracket:
            self.next(path)
        items = []
        while True:
            if bracket and self.peek()[0] == "punct" and self.peek()[1] == "]":
                self.next(path)
                break
            if bracket and self.peek()[0] == "eof":
                raise self.error("unterminated '['", len(self.text), "bt-eof", path)
            if t == "MFNode":
                n = self.node_or_use(f"{path}[{len(items)}]", allow_null=False, allowed=spec.allowed)
                items.append(n)
            elif t == "MFString":
                items.append(self.url_item(path) if spec.name in URL_FIELDS else self.sf("SFString", path))
            elif t == "MFInt32":
                items.append(self.number(path, True))
            elif t == "MFFloat":
                items.append(self.number(path, False))
            else:
                items.extend(self.number(path, False) for _ in range(_MF_VEC[t]))
            if not bracket:
                break
        if t == "MFInt32":
            return np.array(items, dtype=np.int64)
        if t == "MFFloat":
            return np.array(items, dtype=np.float64)
        if t in _MF_VEC:
            return np.array(items, dtype=np.float64).reshape(-1, _MF_VEC[t])
        return items


def parse(text: str, file: str | None = None) -> Scene:
    """Parse BT text into a :class:`Scene` (raises TextFormatError)."""
    r = _Reader(text, file)
    return r.scene()


def read(path) -> Scene:
    """A BT file: a regular file of at most MAX_FILE_BYTES, UTF-8 (TextFormatError otherwise)."""
    p = Path(path)
    try:
        text = read_regular(p, MAX_FILE_BYTES).decode("utf-8")
    except UnicodeDecodeError as e:
        raise TextFormatError(f"not UTF-8 text: {e}", line=1, column=1, rule="bt-encoding", file=str(p)) from None
    except FbaconfInputError as e:  # a FIFO, a device, a link, or too large
        why = e.message.replace("(outputs must be regular files)", "(a scene must be a regular file)")
        raise TextFormatError(f"cannot read the scene: {why}", line=1, column=1, rule="bt-file", file=str(p)) from None
    return parse(text, str(p))


def _clip(token: str, n: int = 40) -> str:
    """A token as an error message quotes it: its first ``n`` characters."""
    return repr(token) if len(token) <= n else repr(token[:n]) + f"… ({len(token)} characters)"


# ---------------------------------------------------------------------------------- writer
def rounded(scene: Scene, decimals: int = 6) -> Scene:
    """A copy of ``scene`` with every float rounded to ``decimals`` decimals (-0 written as 0):
    generated geometry written at a fixed precision does not change with a numpy/libm
    build's last digit."""

    def r(v):
        if isinstance(v, Node):
            return Node(v.type, {k: r(x) for k, x in v.fields.items()}, v.def_name)
        if isinstance(v, list):
            return [r(x) for x in v]
        if isinstance(v, tuple):
            return tuple(r(x) for x in v)
        if isinstance(v, float):
            return round(v, decimals) + 0.0
        if isinstance(v, np.ndarray) and v.dtype.kind == "f":
            return np.round(v, decimals) + 0.0
        return v

    return Scene([r(n) for n in scene.nodes], scene.file)


def fmt_float(x: float) -> str:
    r = repr(float(x))
    if r.endswith(".0"):
        r = r[:-2]
    if r == "-0":
        r = "-0.0"
    return r


def _quote(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def write(scene: Scene) -> str:
    """The BT text of a scene (all fields present in the model, in model order), its
    top-level nodes the children of one ``OrderedGroup``: the single top node GPAC's MP4Box
    reads (and binary BIFS codes, scenes/bifs.py)."""
    out: list[str] = [f"{TOP_GROUP} {{\n  children [\n"]
    for n in scene.nodes:
        _write_node(n, 2, out, "")
        out.append("\n")
    out.append("  ]\n}\n")
    return "".join(out)


def _write_node(n, ind, out, prefix):
    pad = "  " * ind
    if n is None:
        out.append(f"{pad}{prefix}NULL")
        return
    if isinstance(n, Use):
        out.append(f"{pad}{prefix}USE {n.name}")
        return
    d = f"DEF {n.def_name} " if n.def_name else ""
    out.append(f"{pad}{prefix}{d}{n.type} {{\n")
    specs = node_specs()[n.type]
    for fname, v in n.fields.items():
        t = specs[fname].type
        fp = "  " * (ind + 1)
        if t == "SFNode":
            _write_node(v, ind + 1, out, f"{fname} ")
            out.append("\n")
        elif t == "MFNode":
            out.append(f"{fp}{fname} [\n")
            for c in v:
                _write_node(c, ind + 2, out, "")
                out.append("\n")
            out.append(f"{fp}]\n")
        else:
            out.append(f"{fp}{fname} {_fmt_value(t, v, fp)}\n")
    out.append(f"{pad}}}")


def _fmt_value(t, v, pad) -> str:
    if t == "SFInt32":
        return str(int(v))
    if t in ("SFFloat", "SFTime"):
        return fmt_float(v)
    if t in _VEC_SIZES:
        return " ".join(fmt_float(x) for x in v)
    if t == "SFBool":
        return "TRUE" if v else "FALSE"
    if t == "SFString":
        return _quote(v)
    if t == "MFString":
        return "[" + " ".join(_quote(s) for s in v) + "]"
    arr = np.asarray(v)
    if t == "MFInt32":
        items = [str(int(x)) for x in arr]
        per = 16
    elif t == "MFFloat":
        items = [fmt_float(x) for x in arr]
        per = 8
    else:
        items = [" ".join(fmt_float(x) for x in row) for row in arr.reshape(-1, _MF_VEC[t])]
        per = 4
    if len(items) <= per:
        return "[" + ", ".join(items) + "]"
    lines = [", ".join(items[i : i + per]) for i in range(0, len(items), per)]
    return "[\n" + ",\n".join(f"{pad}  {ln}" for ln in lines) + f"\n{pad}]"
