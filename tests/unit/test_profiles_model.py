"""The profiles data file and its loader."""

from __future__ import annotations

from importlib import resources

import pytest

from fbaconf.profiles.model import PROVENANCES, Claim, ProfileDataError, load_profiles, parse_profiles

TEXT = resources.files("fbaconf.profiles").joinpath("data", "profiles.toml").read_text("utf-8")


def test_profiles_are_nested():
    ps = load_profiles()
    s, c, p = (ps.profiles[k] for k in ("simple", "calibration", "predictable"))
    assert s.tools < c.tools < p.tools
    assert c.ancestors == {"simple"} and p.ancestors == {"simple", "calibration"}
    assert {"arithmetic", "dct", "high_level_faps"} <= s.tools  # Simple decodes both coding tools
    assert not ({"fdp_feature_points", "fdp_texture", "fit", "downloaded_model"} & s.tools)
    assert {"fdp_feature_points", "fdp_texture", "fit"} <= c.tools and "downloaded_model" not in c.tools
    assert "downloaded_model" in p.tools


def test_every_limit_has_provenance_unit_and_all_levels():
    ps = load_profiles()
    assert ps.levels == (1, 2)
    expected = {
        "faces",
        "bitrate",
        "coded_frame_rate",
        "decode_rate",
        "render_rate",
        "fdp_feature_points",
        "fit_nodes",
        "fit_links",
        "fit_terms",
        "mesh_vertices",
        "facedeftables_entries",
        "intervals_per_facedefmesh",
        "texture_width",
        "texture_height",
    }
    assert set(ps.limits) == expected
    for lim in ps.limits.values():
        assert lim.provenance in PROVENANCES and lim.unit and set(lim.values) == {1, 2}
    assert ps.limits["bitrate"].values == {1: 16, 2: 32} and ps.limits["bitrate"].unit == "kbit/s"
    assert ps.limits["fdp_feature_points"].provenance == "seed"
    assert ps.limits["decode_rate"].kind == "min" and ps.limits["render_rate"].bounds == "decoder"


def test_indication_codes():
    ps = load_profiles()
    simple = ps.profiles["simple"].indication
    assert simple[1].code == 0x61 and simple[2].code == 0x62
    assert all(i.provenance == "iso-via-implementation" and not i.private for i in simple.values())
    for pid in ("calibration", "predictable"):
        for ind in ps.profiles[pid].indication.values():
            assert ind.private and ind.code > 0xFF and "private" in ind.name


def test_limits_for_claims():
    ps = load_profiles()
    ids = lambda c: {lim.id for lim in ps.limits_for(Claim.parse(c))}
    assert "fit_nodes" not in ids("simple@1") and "fit_nodes" in ids("calibration@1")
    assert "mesh_vertices" not in ids("calibration@2") and "mesh_vertices" in ids("predictable@1")


@pytest.mark.parametrize(
    "old,new,msg",
    [
        (
            'provenance = "provisional"\nvalues = { 1 = 16, 2 = 32 }',
            'provenance = "guess"\nvalues = { 1 = 16, 2 = 32 }',
            "provenance",
        ),
        ('includes = ["simple"]', 'includes = ["predictable"]', "cycle"),
        ('tools = ["downloaded_model"]', 'tools = ["teleport"]', "unknown tool"),
        ("values = { 1 = 16, 2 = 32 }", "values = { 1 = 16 }", "every level"),
        ("values = { 1 = 16, 2 = 32 }", "values = { 1 = 32, 2 = 16 }", "decrease"),
        ('format = "fbaconf.profiles/1"', 'format = "x"', "format"),
    ],
)
def test_malformed_data_is_refused(old, new, msg):
    assert old in TEXT
    with pytest.raises(ProfileDataError, match=msg):
        parse_profiles(TEXT.replace(old, new, 1), "test")
