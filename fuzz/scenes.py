"""BT scene inputs: generation and mutation for fuzzing the scene reader and scene compilation."""

from __future__ import annotations

import random
import re

from fbaconf.scenes.bt import node_specs

from .choosers import Chooser
from .inputs import Entry, InputKind
from .mutators import BYTE_MUTATORS, _pick

_BT_TOKEN = re.compile(r'"(?:[^"\\]|\\.)*"|#[^\n]*|[\[\]{}]|[^\s\[\]{}"#,]+|\s+|.', re.S)
BT_DICTIONARY = (
    "Face",
    "FDP",
    "FIT",
    "FAP",
    "Viseme",
    "Expression",
    "FaceDefTables",
    "FaceDefMesh",
    "FaceDefTransform",
    "Group",
    "Transform",
    "Shape",
    "IndexedFaceSet",
    "Coordinate",
    "TextureCoordinate",
    "DEF",
    "USE",
    "NULL",
    "TRUE",
    "FALSE",
    "[",
    "]",
    "{",
    "}",
    '"',
    '"\\',
    "fdp",
    "fit",
    "fap",
    "featurePointsCoord",
    "faceDefTables",
    "coordIndex",
    "point",
    "children",
    "numeratorTerms",
    "Graph",
    "FAPs",
    "intervalBorders",
    "displacements",
    "0x7fffffff",
    "-2147483649",
    "99999999999999999999",
    "1e309",
    "-1e-320",
    "nan",
    "inf",
    "-0",
    "0x",
    "1.5.5",
    "+",
    "-",
    "e",
    "\\",
    "\u00e9",
    "\x00",
    "#",
)


def _bt_value(ch: Chooser, ftype: str, allowed, depth: int, defs: list[str]) -> str:
    def num(intlike: bool) -> str:
        if intlike:
            return str(ch.choice((0, 1, -1, 2, 5, 22, 68, ch.int(-300, 300), 2**31 - 1, -(2**31))))
        return repr(ch.choice((0.0, 1.0, -1.0, 0.5, ch.float(-100.0, 100.0), 1e-3, 3.4e38)))

    sizes = {
        "SFVec2f": 2,
        "SFVec3f": 3,
        "SFColor": 3,
        "SFRotation": 4,
        "MFVec2f": 2,
        "MFVec3f": 3,
        "MFColor": 3,
        "MFRotation": 4,
    }
    if ftype == "SFInt32":
        return num(True)
    if ftype in ("SFFloat", "SFTime"):
        return num(False)
    if ftype == "SFBool":
        return ch.choice(("TRUE", "FALSE"))
    if ftype == "SFString":
        return '"' + ch.choice(("", "a", "face.png", 'x\\"y', "\\\\")) + '"'
    if ftype in sizes and ftype.startswith("SF"):
        return " ".join(num(False) for _ in range(sizes[ftype]))
    if ftype == "SFNode":
        if depth > 4 or not allowed or ch.bool(0.2):
            return "NULL" if not defs or ch.bool(0.7) else f"USE {ch.choice(defs)}"
        return _bt_node(ch, ch.choice(allowed), depth + 1, defs)
    n = ch.choice((0, 1, 2, 3, 4, 8))
    if ftype == "MFNode":
        if depth > 4 or not allowed:
            return "[]"
        n = min(n, 2)
        return "[" + " ".join(_bt_node(ch, ch.choice(allowed), depth + 1, defs) for _ in range(n)) + "]"
    if ftype == "MFInt32":
        return "[" + " ".join(num(True) for _ in range(n)) + "]"
    if ftype == "MFFloat":
        return "[" + " ".join(num(False) for _ in range(n)) + "]"
    if ftype in sizes:
        return "[" + ", ".join(" ".join(num(False) for _ in range(sizes[ftype])) for _ in range(n)) + "]"
    if ftype == "MFString":
        return "[" + " ".join('"s"' for _ in range(n)) + "]"
    return "NULL"


def _bt_node(ch: Chooser, ntype: str, depth: int, defs: list[str]) -> str:
    specs = node_specs().get(ntype, {})
    names = list(specs)
    if ntype == "FAP" and names:
        names = names[:2] + [ch.choice(names[2:]) for _ in range(3)]
    chosen = [n for n in names if ch.bool(0.5)]
    prefix = ""
    if ch.bool(0.15):
        name = f"N{len(defs)}"
        prefix = f"DEF {name} "
        defs.append(name)  # visible to USE after this node (the reader checks order)
    body = " ".join(f"{n} {_bt_value(ch, specs[n].type, specs[n].allowed, depth, defs)}" for n in dict.fromkeys(chosen))
    return f"{prefix}{ntype} {{ {body} }}"


def gen_scene(ch: Chooser) -> Entry:
    """A BT scene from the node tables: a Face (FDP, FIT, FAP, FaceDefTables...) and/or geometry."""
    top = ch.choice(("Face", "Face", "Face", "Group", "Transform", "Shape"))
    if top not in node_specs():
        top = "Face"
    text = "\n".join(_bt_node(ch, top, 0, []) for _ in range(ch.int(1, 2))) + "\n"
    return Entry(text.encode("utf-8"), kind=InputKind.SCENE, origin="generate:scene")


def mutate_scene(rng: random.Random, e: Entry, corpus: list[Entry]) -> tuple[bytes, str]:
    """Token-level mutations of BT text (numbers at extremes, tokens dropped/duplicated/swapped,
    dictionary words inserted, deep nesting, truncation), or byte-level ones."""
    text = e.data.decode("utf-8", "replace")
    toks = [t for t in _BT_TOKEN.findall(text)]
    sig = [i for i, t in enumerate(toks) if not t.isspace()]
    r = rng.random()
    if not sig or r < 0.12:
        name = rng.choice(list(BYTE_MUTATORS))
        return BYTE_MUTATORS[name](rng, e.data, corpus), name
    i = _pick(rng, sig)
    if r < 0.35:
        nums = [j for j in sig if re.match(r"[+-]?[0-9.]", toks[j])] or sig
        j = _pick(rng, nums)
        toks[j] = rng.choice(
            (
                "0",
                "-1",
                "2147483648",
                "-2147483649",
                "1e309",
                "nan",
                "1e-400",
                "0x10",
                "99999999999999999999999",
                "68",
                "69",
                "-2",
                "3.5",
                "1.",
                ".5e",
                "--1",
            )
        )
        what = "bt-number"
    elif r < 0.5:
        del toks[i]
        what = "bt-drop-token"
    elif r < 0.6:
        toks.insert(i, " " + toks[i] + " ")
        what = "bt-dup-token"
    elif r < 0.8:
        toks.insert(i, " " + rng.choice(BT_DICTIONARY) + " ")
        what = "bt-dictionary"
    elif r < 0.87:
        depth = rng.choice((50, 99, 100, 101, 150, 2000))
        toks.insert(i, " Group { children [ " * depth)
        what = "bt-deep-nesting"
    elif r < 0.94:
        toks = toks[:i]
        what = "bt-truncate"
    else:
        j = _pick(rng, sig)
        toks[i], toks[j] = toks[j], toks[i]
        what = "bt-swap"
    return "".join(toks).encode("utf-8", "surrogatepass"), what


def scene_features(scene=None, rule: str | None = None, text: str = "") -> set[str]:
    f: set[str] = set()
    if rule:
        f.add(f"rule:{rule}")
        return f
    f.add("scene:ok")
    for name in ("Face", "FDP", "FIT", "FaceDefTables", "FaceDefMesh", "FaceDefTransform", "FAP", "IndexedFaceSet"):
        if re.search(rf"\b{name}\s*\{{", text):
            f.add(f"scene:{name}")
    if "DEF " in text:
        f.add("scene:DEF")
    if "USE " in text:
        f.add("scene:USE")
    return f
