"""BIFS and BT that GPAC's MP4Box reads and writes (decision D10).

The expected values come from GPAC, not from fbaconf: ``tests/data/gpac/`` holds binary BIFS
and BT dumps MP4Box wrote (from commit ``gpac_commit`` of its MANIFEST.json, built outside the
repository; ``tests/data/gpac/make.py`` remakes them). Always: each GPAC stream decodes in
fbaconf to the scene it was made from, and each GPAC BT dump reads back to it. With MP4Box
present (``FBACONF_MP4BOX`` or ``MP4Box`` on PATH): MP4Box reads every shipped ``.bt`` file and
decodes every fbaconf-encoded shipped scene to the same scene — FaceDefMesh references aside,
which MP4Box refuses (D10; ``fbaconf check`` warns FAP-SCENE-003), as a test shows.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from fbaconf.scenes import bifs, bt

HERE = Path(__file__).resolve().parents[1]  # tests/
ROOT = HERE.parent
DATA = HERE / "data" / "gpac"
MANIFEST = json.loads((DATA / "MANIFEST.json").read_text())
ENTRIES = [e for e in MANIFEST["entries"] if "bifs" in e]
TEXT_DIGITS = 1e-5  # MP4Box prints floats with 6 significant digits (%g of the float32)

FACE_FAMILY = {"Face", "FAP", "Viseme", "Expression", "FDP", "FIT", "FaceDefTables", "FaceDefMesh", "FaceDefTransform"}


def source(e) -> bt.Scene:
    return bifs.interop_view(bt.read(ROOT / e["source"]))


def test_the_evidence_covers_every_shipped_scene_every_face_node_and_field_type():
    shipped = {str(p.relative_to(ROOT)) for p in (ROOT / "conformance" / "suites").glob("*/*.bt")}
    shipped.add("animation/data/models/default-head.bt")
    assert shipped <= {e["source"] for e in ENTRIES}
    assert not [e for e in MANIFEST["entries"] if "refused" in e]
    types, ftypes = set(), set()
    for e in ENTRIES:
        for node, _path in source(e).walk():
            types.add(node.type)
            specs = bt.node_specs()[node.type]
            ftypes |= {specs[f].type for f in node.fields}
    assert FACE_FAMILY <= types
    every = {s.type for specs in bt.node_specs().values() for s in specs.values()}
    assert every <= ftypes, sorted(every - ftypes)
    assert len(MANIFEST["gpac_commit"]) == 40


@pytest.mark.parametrize("e", ENTRIES, ids=[e["name"] for e in ENTRIES])
def test_gpac_bifs_decodes_to_its_scene(e):
    data = (DATA / e["bifs"]).read_bytes()
    assert hashlib.sha256(data).hexdigest() == e["bifs_sha256"]
    got = bifs.decode(data)
    want = source(e)
    assert bifs.equivalent_scene(got, want)
    assert _perturbed(got) and not bifs.equivalent_scene(got, want)  # the comparison is not blind


def _perturbed(scene: bt.Scene) -> bool:
    """Change the first plain value of the scene (walk order) by one unit."""
    for node, _path in scene.walk():
        for f, v in node.fields.items():
            if isinstance(v, bool):
                node.fields[f] = not v
            elif isinstance(v, (int, float)):
                node.fields[f] = v + 1
            elif isinstance(v, np.ndarray) and v.size:
                v = v.copy()
                v.flat[0] += 1
                node.fields[f] = v
            else:
                continue
            return True
    return False


DUMPS = [e for e in ENTRIES if "dump" in e]


@pytest.mark.parametrize("e", DUMPS, ids=[e["name"] for e in DUMPS])
def test_mp4box_bt_dump_reads_back(e):
    """BT as MP4Box writes it: an InitialObjectDescriptor block, one OrderedGroup top node,
    lowercase booleans, floats at 6 significant digits, fields in table order, defaults left out."""
    text = (DATA / e["dump"]).read_text()
    assert text.lstrip().startswith("InitialObjectDescriptor")
    assert bifs.equivalent_scene(bt.parse(text), source(e), rel=TEXT_DIGITS)


def test_mp4box_od_urls_read_to_the_scene_of_their_bifs():
    """MFURL as MP4Box dumps it: object descriptor URLs unquoted (od:5, od:1023) and the empty URL as
    od:0. The dump reads to the scene GPAC's own BIFS decodes to (URL strings, "od:N", "")."""
    (e,) = [e for e in ENTRIES if e["name"] == "hand-od-urls"]
    text = (DATA / e["dump"]).read_text()
    assert 'url ["face.jpg" od:5 od:0]' in text and "url [od:1023]" in text and "url [od:0]" in text
    from_dump, from_bifs = bt.parse(text), bifs.decode((DATA / e["bifs"]).read_bytes())
    urls = [n.fields["url"] for n, _ in from_bifs.find("ImageTexture")]
    assert urls == [["face.jpg", "od:5", ""], ["od:1023"], [""]]
    assert bifs.equivalent_scene(from_dump, from_bifs, rel=TEXT_DIGITS)
    # fbaconf writes them quoted ("od:5", the form MP4Box reads as object descriptor 5) and reads that back
    again = bt.write(from_dump)
    assert '["face.jpg" "od:5" ""]' in again and bifs.equivalent_scene(bt.parse(again), from_bifs)


# ------------------------------------------------------------------ with MP4Box
def mp4box() -> str:
    exe = os.environ.get("FBACONF_MP4BOX") or shutil.which("MP4Box")
    if not exe or not Path(exe).exists():
        pytest.skip(
            "MP4Box not available (build it outside the repository: ../shared/interop/README.md; set FBACONF_MP4BOX)"
        )
    return exe


SHIPPED = sorted(str(p.relative_to(ROOT)) for p in (ROOT / "conformance" / "suites").glob("*/*.bt")) + [
    "animation/data/models/default-head.bt"
]
IOD = """InitialObjectDescriptor {
 objectDescriptorID 1
 esDescr [
  ES_Descriptor {
   ES_ID 1
   decConfigDescr DecoderConfigDescriptor { objectTypeIndication 1 streamType 3 }
   muxInfo MuxInfo { fileName "s.nhml" }
  }
 ]
}
"""
NHML = """<?xml version="1.0" encoding="UTF-8" ?>
<NHNTStream version="1.0" streamType="3" objectTypeIndication="1" timeScale="1000" specificInfoFile="cfg.bin">
<NHNTSample DTS="0" isRAP="yes" mediaFile="au.bin"/>
</NHNTStream>
"""


def gpac_reads(blob: bytes, work: Path) -> tuple[bt.Scene | None, str]:
    """MP4Box's reading of an fbaconf .bifs (imported raw through NHML, dumped as BT)."""
    exe = mp4box()
    cfg = 2  # fbaconf's BIFSConfig without a size: 13 bits, 2 bytes
    (work / "cfg.bin").write_bytes(blob[:cfg])
    (work / "au.bin").write_bytes(blob[cfg:])
    (work / "s.nhml").write_text(NHML)
    (work / "w.bt").write_text(IOD)
    r = subprocess.run([exe, "-mp4", "w.bt", "-out", "w.mp4"], cwd=work, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-500:]
    r = subprocess.run([exe, "-bt", "w.mp4", "-out", "d.bt"], cwd=work, capture_output=True, text=True)
    if not (work / "d.bt").exists():
        return None, r.stderr
    return bt.read(work / "d.bt"), r.stderr


@pytest.mark.parametrize("rel", SHIPPED)
def test_mp4box_loads_every_shipped_bt(rel, tmp_path):
    """The shipped .bt files as they are (one OrderedGroup top node): MP4Box encodes them,
    FaceDefMesh references aside (D10), and its dump is the same scene."""
    exe = mp4box()
    scene = bt.read(ROOT / rel)
    src = tmp_path / "s.bt"
    view = bifs.interop_view(scene)
    src.write_text((ROOT / rel).read_text() if view == scene else bt.write(view))
    r = subprocess.run([exe, "-def", "-mp4", str(src), "-out", str(tmp_path / "s.mp4")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-500:]
    subprocess.run(
        [exe, "-bt", str(tmp_path / "s.mp4"), "-out", str(tmp_path / "d.bt")], capture_output=True, check=True
    )
    assert bifs.equivalent_scene(bt.read(tmp_path / "d.bt"), view, rel=TEXT_DIGITS)


@pytest.mark.parametrize("rel", SHIPPED)
def test_mp4box_decodes_fbaconf_bifs(rel, tmp_path):
    view = bifs.interop_view(bt.read(ROOT / rel))
    got, err = gpac_reads(bifs.encode(view), tmp_path)
    assert got is not None, err[-500:]
    assert bifs.equivalent_scene(bifs.interop_view(got), view, rel=TEXT_DIGITS)


def test_mp4box_reads_fbaconfs_writing_of_its_od_url_dump(tmp_path):
    """The writer's form stays what MP4Box reads: MP4Box's dump (od:N unquoted) read by fbaconf and
    written back (quoted) is encoded by MP4Box to the BIFS it wrote first."""
    exe = mp4box()
    (e,) = [e for e in ENTRIES if e["name"] == "hand-od-urls"]
    (tmp_path / "s.bt").write_text(bt.write(bt.read(DATA / e["dump"])))
    r = subprocess.run([exe, "-def", "-mp4", "s.bt", "-out", "s.mp4"], cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-500:]
    subprocess.run([exe, "-raws", "1", "s.mp4"], cwd=tmp_path, capture_output=True, check=True)
    assert (DATA / e["bifs"]).read_bytes().endswith((tmp_path / "s_track1_001.bifs").read_bytes())


def test_mp4box_refuses_the_seeds_mesh_reference(tmp_path):
    """The one disagreement kept (D10): a FaceDefMesh that USEs the IndexedFaceSet it deforms,
    as the seed defines it, is what MP4Box cannot decode."""
    scene = bt.read(ROOT / "conformance" / "suites" / "predictable-l1-core" / "logo.bt")
    assert bifs.interop_view(scene) != scene
    got, err = gpac_reads(bifs.encode(scene), tmp_path)
    assert got is None and "Unknown BIFS Node" in err
