"""Make the GPAC interop evidence of binary BIFS written by GPAC's MP4Box from every
shipped scene and from hand-written scenes, committed as test data (tests/integration/test_gpac_interop.py).

    python tests/data/gpac/make.py /path/to/MP4Box [--gpac-commit SHA] [--only NAME ...]

``--only`` remakes the named entries (e.g. ``hand-od-urls``) and keeps the others of MANIFEST.json
as they are (each remade entry records its own ``made`` date).

MP4Box is built outside the repository (../shared/interop/README.md). For each scene the
script writes the BT MP4Box reads (fbaconf's writer: one OrderedGroup top node), runs
``MP4Box -def -mp4`` (DEF names kept), takes the access unit (``MP4Box -raws 1``) and the
BIFSConfig (the DecoderSpecificInfo of the track's esds box, read here) and stores
BIFSConfig + access unit as ``streams/<name>.gpac.bifs`` — fbaconf's ``.bifs`` framing. For
scenes under 100 KB it also keeps MP4Box's own BT dump (``dumps/<name>.gpac.bt``, ``MP4Box
-bt``). FaceDefMesh.faceSceneGraphNode is dropped first (``scenes.bifs.interop_view``): MP4Box
refuses it (D10). MANIFEST.json records every file, its source and the GPAC build.
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from fbaconf.scenes import bifs, bt

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
DUMP_MAX = 100_000


def sources() -> list[tuple[str, Path]]:
    out = []
    for p in sorted((ROOT / "conformance" / "suites").glob("*/*.bt")):
        out.append((f"{p.parent.name}-{p.stem}", p))
    out.append(("model-default-head", ROOT / "animation" / "data" / "models" / "default-head.bt"))
    for p in sorted((HERE / "scenes").glob("*.bt")):
        out.append((f"hand-{p.stem}", p))
    return out


def boxes(data: bytes, start: int = 0, end: int | None = None):
    """(type, payload start, payload end) of the ISO-BMFF boxes in data[start:end]."""
    end = len(data) if end is None else end
    i = start
    while i + 8 <= end:
        size = int.from_bytes(data[i : i + 4], "big")
        kind = data[i + 4 : i + 8].decode("latin-1")
        head = 8
        if size == 1:
            size = int.from_bytes(data[i + 8 : i + 16], "big")
            head = 16
        elif size == 0:
            size = end - i
        yield kind, i + head, i + size
        i += size


def find(data: bytes, path: list[str], start: int = 0, end: int | None = None):
    for kind, s, e in boxes(data, start, end):
        if kind == path[0]:
            s += {"stsd": 8, "mp4s": 8, "esds": 4}.get(kind, 0)  # full-box / sample-entry headers
            if len(path) == 1:
                return s, e
            found = find(data, path[1:], s, e)
            if found:
                return found
    return None


def descriptor(data: bytes, i: int) -> tuple[int, int, int]:
    """(tag, payload start, payload end) of the MPEG-4 descriptor at i (expandable size)."""
    tag = data[i]
    i += 1
    size = 0
    for _ in range(4):
        b = data[i]
        i += 1
        size = (size << 7) | (b & 0x7F)
        if not b & 0x80:
            break
    return tag, i, i + size


def bifs_config(mp4: bytes) -> bytes:
    """The DecoderSpecificInfo (BIFSConfig) of the first track's esds box."""
    s, e = find(mp4, ["moov", "trak", "mdia", "minf", "stbl", "stsd", "mp4s", "esds"])
    tag, p, end = descriptor(mp4, s)
    assert tag == 0x03, "ES_Descriptor expected"
    flags = mp4[p + 2]
    p += 3
    if flags & 0x80:
        p += 2
    if flags & 0x40:
        p += 1 + mp4[p]
    if flags & 0x20:
        p += 2
    tag, p, end = descriptor(mp4, p)
    assert tag == 0x04, "DecoderConfigDescriptor expected"
    tag, p, end = descriptor(mp4, p + 13)
    assert tag == 0x05, "DecoderSpecificInfo expected"
    return mp4[p:end]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mp4box")
    ap.add_argument("--gpac-commit", default="d34570e3d994ede1f7fa84075fea793f8939308e")
    ap.add_argument("--only", nargs="+", metavar="NAME", help="remake only these entries, keep the others")
    a = ap.parse_args()
    old = json.loads((HERE / "MANIFEST.json").read_text()) if a.only else None
    sys.path.insert(0, str(ROOT))
    version = subprocess.run([a.mp4box, "-version"], capture_output=True, text=True)
    (HERE / "streams").mkdir(exist_ok=True)
    (HERE / "dumps").mkdir(exist_ok=True)
    entries = []
    for name, src in sources():
        if a.only and name not in a.only:
            entries.extend(e for e in old["entries"] if e["name"] == name)
            continue
        scene = bt.read(src)
        view = bifs.interop_view(scene)
        with tempfile.TemporaryDirectory() as t:
            t = Path(t)
            (t / "in.bt").write_text(bt.write(view))
            r = subprocess.run(
                [a.mp4box, "-def", "-mp4", str(t / "in.bt"), "-out", str(t / "s.mp4")], capture_output=True, text=True
            )
            if r.returncode != 0:
                print(f"{name}: MP4Box refused it: {r.stderr[-300:]}")
                entries.append({"name": name, "source": str(src.relative_to(ROOT)), "refused": r.stderr[-300:]})
                continue
            subprocess.run([a.mp4box, "-raws", "1", str(t / "s.mp4")], capture_output=True, check=True, cwd=t)
            au = (t / "s_track1_001.bifs").read_bytes()
            blob = bifs_config((t / "s.mp4").read_bytes()) + au
            (HERE / "streams" / f"{name}.gpac.bifs").write_bytes(blob)
            entry = {
                "name": name,
                "source": str(src.relative_to(ROOT)),
                "mesh_references_removed": view != scene,
                "bifs": f"streams/{name}.gpac.bifs",
                "bifs_sha256": hashlib.sha256(blob).hexdigest(),
            }
            if src.stat().st_size < DUMP_MAX:
                subprocess.run(
                    [a.mp4box, "-bt", str(t / "s.mp4"), "-out", str(HERE / "dumps" / f"{name}.gpac.bt")],
                    capture_output=True,
                    check=True,
                )
                entry["dump"] = f"dumps/{name}.gpac.bt"
            if a.only:
                entry["made"] = datetime.date.today().isoformat()
            entries.append(entry)
            print(f"{name}: {len(blob)} bytes")
    doc = {
        "format": "fbaconf.gpac-interop/1",
        "gpac_commit": a.gpac_commit,
        "mp4box_version": (version.stdout + version.stderr).strip().splitlines()[0],
        "made": old["made"] if old else datetime.date.today().isoformat(),
        "command": "MP4Box -def -mp4 S.bt -out S.mp4; MP4Box -raws 1",
        "entries": entries,
    }
    (HERE / "MANIFEST.json").write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
