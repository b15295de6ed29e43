"""Fuzzing players: .fap text inputs (seeds: the suites' sparse .fap files) and their mutators,
line-level (the forms real tools write and break: comments anywhere, CRLF, wrapped and joined
lines, a 69th mask entry, fractional and huge numbers, frame numbers out of order or past the
header's count, header count 0) and byte-level."""

from __future__ import annotations

import random
from pathlib import Path

from .corpus import suite_files
from .inputs import Entry, InputKind
from .mutators import BYTE_MUTATORS


def text_seeds(root: Path | None = None, max_bytes: int = 20000) -> list[Entry]:
    """The suites' sparse ``.fap`` files (up to ``max_bytes`` each)."""
    return suite_files("fap", InputKind.TEXT, root, max_bytes)


_NUMBERS = ("0", "-1", "1.5", "2147483648", "-2147483649", "1e9", "007", "+3", "", "nan", "99999999999999999999")


def _lines(rng: random.Random, lines: list[str]) -> tuple[list[str], str]:
    if not lines:
        return ["2.1 x 25 0"], "empty"
    i = rng.randrange(len(lines))
    op = rng.choice(
        (
            "delete",
            "duplicate",
            "swap",
            "comment",
            "number",
            "join",
            "split",
            "mask69",
            "count0",
            "frame-back",
            "frame-far",
        )
    )
    if op == "delete":
        del lines[i]
    elif op == "duplicate":
        lines.insert(i, lines[i])
    elif op == "swap" and len(lines) > 1:
        j = rng.randrange(len(lines))
        lines[i], lines[j] = lines[j], lines[i]
    elif op == "comment":
        lines.insert(i, rng.choice(("# comment", "#", "   # indented", "#" * 300)))
    elif op == "number":
        toks = lines[i].split(" ")
        toks[rng.randrange(len(toks))] = rng.choice(_NUMBERS)
        lines[i] = " ".join(toks)
    elif op == "join" and i + 1 < len(lines):
        lines[i : i + 2] = [lines[i] + " " + lines[i + 1]]
    elif op == "split":
        toks = lines[i].split(" ")
        k = rng.randrange(len(toks) + 1)
        lines[i : i + 1] = [" ".join(toks[:k]), " ".join(toks[k:])]
    elif op == "mask69" and i:
        lines[i] = lines[i] + " 0"
    elif op == "count0":
        toks = lines[0].split(" ")
        toks[-1] = "0"
        lines[0] = " ".join(toks)
    elif op in ("frame-back", "frame-far") and i:
        toks = lines[i].split(" ")
        toks[0] = "0" if op == "frame-back" else "1000000"
        lines[i] = " ".join(toks)
    return lines, op


def mutate_text(rng: random.Random, e: Entry, corpus: list[Entry]) -> tuple[bytes, str]:
    if rng.random() < 0.25:
        name = rng.choice(list(BYTE_MUTATORS))
        return BYTE_MUTATORS[name](rng, e.data, corpus), name
    text = e.data.decode("utf-8", "replace")
    lines, op = _lines(rng, text.split("\n"))
    sep = "\r\n" if rng.random() < 0.1 else "\n"
    return sep.join(lines).encode("utf-8"), op
