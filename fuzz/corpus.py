"""The seed corpus: the conformance suites' streams, short prefixes, generated streams and scenes."""

from __future__ import annotations

import random
from pathlib import Path

from fbaconf.bitstreams.bitedit import end_stream
from fbaconf.conformance.suite import suites_root

from .choosers import RandomChooser
from .inputs import Entry, InputKind, gen_valid
from .scenes import gen_scene


def suite_files(suffix: str, kind: InputKind, root: Path | None = None, max_bytes: int | None = None) -> list[Entry]:
    """The built suites' ``*/*.<suffix>`` files (up to ``max_bytes`` each) as seeds of ``kind``;
    empty when no suites are built."""
    root = Path(root) if root else suites_root()
    out = []
    if root.is_dir():
        for p in sorted(root.glob(f"*/*.{suffix}")):
            if max_bytes is None or p.stat().st_size <= max_bytes:
                out.append(Entry(p.read_bytes(), kind=kind, origin=f"seed:{p.parent.name}/{p.name}"))
    return out


def conformance_seeds(root: Path | None = None) -> list[Entry]:
    """The conformance suites' streams (``*.fba``) as seed corpus; empty when no suites are built."""
    return suite_files("fba", InputKind.STREAM, root)


def scene_seeds(root: Path | None = None, max_bytes: int = 20_000) -> list[Entry]:
    """The suites' small BT scenes (the Face family among them: FDP feature points, textures, FIT
    graphs, a FaceDefTables grid) plus generated ones."""
    out = suite_files("bt", InputKind.SCENE, root, max_bytes)
    rng = RandomChooser(random.Random(7))
    out.extend(gen_scene(rng) for _ in range(4))
    return out


def short_prefixes(entries: list[Entry], max_planes: int = 3) -> list[Entry]:
    """Valid short streams: the first 1..max_planes planes of each entry, then the end code."""
    out = []
    for e in entries:
        m = e.get_model()
        if m.error_rule:
            continue
        for k in range(1, min(max_planes, len(m.planes)) + 1):
            if k == len(m.planes):
                break
            out.append(Entry(end_stream(e.data, m.planes[k - 1].end_offset), origin=f"{e.origin}[:{k} planes]"))
    return out


def default_seeds() -> list[Entry]:
    seeds = conformance_seeds()
    if not seeds:
        ch = RandomChooser(random.Random(1))
        seeds = [gen_valid(ch) for _ in range(12)]
    return seeds
