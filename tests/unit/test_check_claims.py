"""Claims: reference-encoder streams for every profile@level check clean against that claim;
the same stream exceeding exactly one limit (bitrate, frame rate, a tool outside the
profile, a scene size) gives exactly the expected code."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest

from fbaconf import rules as R
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.profiles.checker import LIMIT_CODES, SceneSummary, analyse, check_stream, summarize_scene
from fbaconf.profiles.model import Claim, load_profiles
from fbaconf.profiles.sample_streams import make_stream, smooth_frames
from fbaconf.scenes import bt

# stream parameters per level: clean, over the bitrate limit only, over the frame-rate limit only
STREAMS = {
    1: {
        "clean": dict(n=60, rate=30.0, faps=range(3, 40)),
        "bitrate": dict(n=60, rate=30.0, faps=range(3, 69), intra_period=10),
        "frame_rate": dict(n=120, rate=60.0, faps=range(3, 15)),
    },
    2: {
        "clean": dict(n=120, rate=60.0, faps=range(3, 30)),
        "bitrate": dict(n=120, rate=60.0, faps=range(3, 69), intra_period=10),
        "frame_rate": dict(n=240, rate=120.0, faps=range(3, 15)),
    },
}

_cache: dict = {}


def stream(level: int, kind: str) -> bytes:
    key = (level, kind)
    if key not in _cache:
        _cache[key] = make_stream(**STREAMS[level][kind])
    return _cache[key]


def scene_for(claim: Claim) -> SceneSummary | None:
    """A scene using every scene tool of the claimed profile, each size exactly at its limit."""
    ps = load_profiles()
    prof = ps.profiles[claim.profile]
    tools = sorted(t for t in prof.tools if ps.tools[t].source == "scene")
    if not tools:
        return None
    s = SceneSummary(faces=1, tools={t: f"Face.fdp.FDP/{t}" for t in tools})
    for lim in ps.limits_for(claim):
        if lim.bounds == "scene":
            s.measure(lim.id, lim.value(claim.level), f"Face.fdp.FDP/{lim.id}")
    return s


CLAIMS = [str(c) for c in load_profiles().claims()]


@pytest.mark.parametrize("claim", CLAIMS)
def test_reference_streams_check_clean_against_their_claim(claim):
    c = Claim.parse(claim)
    rep = analyse(stream(c.level, "clean"), claim=c, scene=scene_for(c))
    assert rep.diagnostics == []
    assert rep.fits[claim]


@pytest.mark.parametrize("claim", CLAIMS)
@pytest.mark.parametrize("kind,code", [("bitrate", R.LEVEL_BITRATE), ("frame_rate", R.LEVEL_FRAME_RATE)])
def test_one_stream_limit_exceeded_gives_exactly_its_code(claim, kind, code):
    c = Claim.parse(claim)
    ds = check_stream(stream(c.level, kind), claim=c, scene=scene_for(c))
    assert [d.code for d in ds] == [code], [str(d) for d in ds]
    assert "provisional" in ds[0].message


@pytest.mark.parametrize("claim", CLAIMS)
def test_one_scene_limit_exceeded_gives_exactly_its_code(claim):
    c = Claim.parse(claim)
    ps = load_profiles()
    base = scene_for(c)
    for lim in ps.limits_for(c):
        if lim.bounds != "scene":
            continue
        s = scene_for(c)
        s.measures[lim.id] = (lim.value(c.level) + 1, "Face.fdp.FDP/over")
        ds = check_stream(stream(c.level, "clean"), claim=c, scene=s)
        assert [d.code for d in ds] == [LIMIT_CODES[lim.id]], (lim.id, [str(d) for d in ds])
        assert ds[0].location.node_path == "Face.fdp.FDP/over"
    s = base or SceneSummary()
    s.faces = int(ps.limits["faces"].value(c.level)) + 1
    ds = check_stream(stream(c.level, "clean"), claim=c, scene=s)
    assert [d.code for d in ds] == [R.LEVEL_FACES]


@pytest.mark.parametrize(
    "claim,tool",
    [
        ("simple@1", "fit"),
        ("simple@2", "fdp_feature_points"),
        ("calibration@1", "downloaded_model"),
        ("calibration@2", "downloaded_model"),
    ],
)
def test_tool_outside_the_profile_gives_exactly_profile_code(claim, tool):
    c = Claim.parse(claim)
    s = scene_for(c) or SceneSummary(faces=1)
    s.tools[tool] = "Face.fdp.FDP"
    ds = check_stream(stream(c.level, "clean"), claim=c, scene=s)
    assert [d.code for d in ds] == [R.PROFILE_TOOL]
    assert tool in ds[0].message and ds[0].location.node_path == "Face.fdp.FDP"


@pytest.mark.parametrize(
    "level,kind,expected",
    [
        (1, "clean", "simple@1"),
        (1, "bitrate", "simple@2"),
        (1, "frame_rate", "simple@2"),
        (2, "clean", "simple@2"),
        (2, "bitrate", None),
        (2, "frame_rate", None),
    ],
)
def test_smallest_claim(level, kind, expected):
    rep = analyse(stream(level, kind), smallest_claim=True)
    assert rep.summary["smallest_claim"] == expected
    assert {d.code for d in rep.diagnostics} == (set() if expected else {R.CLAIM_NONE})


def test_smallest_claim_with_scene_tools():
    s = SceneSummary(faces=1, tools={"fit": "Face.fit.FIT"})
    s.measure("fit_nodes", 20, "Face.fit.FIT.FAPs")  # over L1 (16), within L2 (64)
    assert analyse(stream(1, "clean"), scene=s).summary["smallest_claim"] == "calibration@2"
    s.tools["downloaded_model"] = "Face.fdp.FDP.faceSceneGraph[0]"
    assert analyse(stream(1, "clean"), scene=s).summary["smallest_claim"] == "predictable@2"


def test_claim_ordering_and_parsing():
    ps = load_profiles()
    order = [str(c) for c in ps.claims()]
    assert order == ["simple@1", "simple@2", "calibration@1", "calibration@2", "predictable@1", "predictable@2"]
    assert Claim.parse("Simple@L2") == Claim.parse("simple@2")
    for bad in ("simple", "simple@3", "nope@1", "simple@x", "a@b@c"):
        with pytest.raises(ValueError):
            Claim.parse(bad)


def test_bitrate_window_is_sliding():
    """A burst of intra planes inside one second of an otherwise cheap stream: the window that
    holds the burst, not the average, decides."""
    f = smooth_frames(150, 30.0, range(3, 69))
    data_avg = encode(f, EncoderOptions()).data
    burst = encode(
        f, EncoderOptions(fap_quant_per_frame=np.array([1] * 60 + [1, 2] * 15 + [1] * 60))
    ).data  # every plane intra in seconds 2-3
    ra, rb = analyse(data_avg), analyse(burst)
    assert rb.summary["peak_bitrate_bps"] > 2 * ra.summary["peak_bitrate_bps"]
    assert len(burst) * 8 / 5.0 < rb.summary["peak_bitrate_bps"]  # the peak beats the average


def test_real_scene_file_through_the_bt_reader(tmp_path):
    # 84 points in label order, 3 of them sent (the rest 3.4e38: not sent)
    pts = " ".join("0 0 0" if k < 3 else "3.4e38 3.4e38 3.4e38" for k in range(84))
    text = (
        "Face {\n  fdp FDP {\n    featurePointsCoord Coordinate { point [ " + pts + " ] }\n  }\n"
        "  fit FIT { FAPs [ 3 -1 4 ] Graph [ 0 1 ] numeratorTerms [ 1 ] denominatorTerms [ 0 ]"
        " numeratorExp [ 1 ] numeratorCoefs [ 1.0 ] }\n}\n"
    )
    p = tmp_path / "face.bt"
    p.write_text(text)
    s = summarize_scene(bt.read(p))
    assert set(s.tools) == {"fdp_feature_points", "fit"}
    assert s.measures["fdp_feature_points"][0] == 3 and s.measures["fit_nodes"][0] == 2
    assert s.measures["fit_links"][0] == 1 and s.faces == 1
    ds = check_stream(stream(1, "clean"), scene=str(p), claim="simple@1")
    assert {d.code for d in ds} == {R.PROFILE_TOOL} and len(ds) == 2
    assert all(d.location.node_path for d in ds)
    assert check_stream(stream(1, "clean"), scene=str(p), claim="calibration@1") == []


def test_feature_point_list_must_hold_84_points(tmp_path):
    p = tmp_path / "few.bt"
    p.write_text("Face { fdp FDP { featurePointsCoord Coordinate { point [ 0 0 0, 1 1 1 ] } } }\n")
    ds = check_stream(stream(1, "clean"), scene=str(p), claim="calibration@1")
    assert [d.code for d in ds] == [R.SCENE_INVALID]
    assert ds[0].location.node_path.endswith("featurePointsCoord") and "got 2" in ds[0].message


def test_malformed_scene_file(tmp_path):
    p = tmp_path / "bad.bt"
    p.write_text("Face { fdp FDP { featurePointsCoord Coordinate { point [ 0 0 ] } }\n")
    ds = check_stream(stream(1, "clean"), scene=str(p))
    assert [d.code for d in ds] == [R.SCENE_INVALID]


def _png(path, width: int, height: int) -> None:

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    raw = b"".join(b"\x00" + bytes(width) for _ in range(height))
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(raw))
        + chunk(b"IEND", b"")
    )


@pytest.mark.parametrize("width,codes", [(512, set()), (600, {R.LEVEL_TEXTURE})])
def test_texture_size_from_the_scene_image(tmp_path, width, codes):
    _png(tmp_path / "skin.png", width, 4)
    text = (
        "Face {\n  fdp FDP {\n    textureCoord TextureCoordinate { point [ 0 0, 1 1 ] }\n"
        '    faceSceneGraph [ Shape { appearance Appearance { texture ImageTexture { url "skin.png" } } } ]\n'
        "  }\n}\n"
    )
    p = tmp_path / "tex.bt"
    p.write_text(text)
    ds = check_stream(stream(1, "clean"), scene=str(p), claim="calibration@1")
    assert {d.code for d in ds} == codes
    if codes:
        assert ds[0].location.node_path.endswith("ImageTexture.url") and "600" in ds[0].message
