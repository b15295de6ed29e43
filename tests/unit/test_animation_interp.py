import numpy as np
import pytest

from fbaconf.animation import engine
from fbaconf.animation.highlevel import apply_high_level, default_tables, high_level_weights
from fbaconf.animation.interp import FitGraph, lr_fill
from fbaconf.bitstreams.frames import DERIVED, FREE, RETAINED, SET, FapFrames
from fbaconf.bitstreams.tables import fap_by_name, left_right_pairs
from fbaconf.errors import SceneError
from fbaconf.scenes import bt


def _fit(faps, graph, ne=(), de=(), ni=(), nt=(), dt=(), nc=(), dc=()):
    """FitGraph.from_fields with the function fields in the order the FIT node lists them."""
    return FitGraph.from_fields(
        faps,
        graph,
        {
            "numeratorExp": ne,
            "denominatorExp": de,
            "numeratorImpulse": ni,
            "numeratorTerms": nt,
            "denominatorTerms": dt,
            "numeratorCoefs": nc,
            "denominatorCoefs": dc,
        },
    )


def blank(n=1):
    return np.zeros((n, 68)), np.zeros((n, 68), np.uint8), np.zeros((n, 10), np.int64)


def test_lr_fill():
    v, s, _ = blank(3)
    v[0, 5], s[0, 5] = 120, SET  # FAP 6 set, FAP 7 free -> copied
    v[1, 6], s[1, 6] = -40, RETAINED  # FAP 7 retained, FAP 6 free -> copied
    v[2, 5], s[2, 5] = 10, SET  # both set: untouched
    v[2, 6], s[2, 6] = 20, SET
    v2, s2 = lr_fill(v, s)
    assert v2[0, 6] == 120 and s2[0, 6] == DERIVED and s2[0, 5] == SET
    assert v2[1, 5] == -40 and s2[1, 5] == DERIVED
    assert v2[2, 5] == 10 and v2[2, 6] == 20 and s2[2, 6] == SET
    # nothing else touched
    assert (s2[0] != FREE).sum() == 2
    assert (19, 20) in left_right_pairs() and (6, 7) in left_right_pairs()


def test_default_tables_shape():
    vis, exp = default_tables()
    assert vis.shape == (15, 68) and exp.shape == (7, 68)
    assert not vis[0].any() and not exp[0].any()
    assert all(vis[k].any() for k in range(1, 15)) and all(exp[k].any() for k in range(1, 7))
    joy, sad = exp[1], exp[2]
    n = lambda name: fap_by_name(name).number - 1
    assert joy[n("raise_l_cornerlip")] > 0 and joy[n("lift_l_cheek")] > 0
    assert sad[n("raise_l_i_eyebrow")] > 0 and sad[n("raise_l_cornerlip")] < 0
    assert exp[6][n("open_jaw")] > 0 and exp[3][n("squeeze_l_eyebrow")] > 0


def test_blending_and_free_only():
    vis, exp = default_tables()
    v, s, h = blank(2)
    s[:, 0] = SET
    s[:, 1] = SET
    h[0, :4] = (10, 13, 21, 0)  # viseme 10 * 21/63 + viseme 13 * 42/63
    h[0, 4:8] = (1, 63, 0, 0)  # joy full
    h[1, 4:8] = (6, 31, 2, 10)
    jaw = 2
    v[0, 3], s[0, 3] = 7, SET  # lower_t_midlip SET: must stay
    v2, s2 = apply_high_level(v, s, h)
    expect = vis[10] * (21 / 63) + vis[13] * (42 / 63) + exp[1]
    assert v2[0, jaw] == pytest.approx(expect[jaw]) and s2[0, jaw] == DERIVED
    assert v2[0, 3] == 7 and s2[0, 3] == SET
    exp2 = exp[6] * 31 / 63 + exp[2] * 10 / 63 + vis[0]
    m = exp2 != 0
    np.testing.assert_allclose(v2[1, m], exp2[m])
    assert (s2[1, m] == DERIVED).all() and (s2[1, ~m][2:] == FREE).all()
    # FAP 1/2 FREE: no effect
    s[:, :2] = FREE
    v3, s3 = apply_high_level(v, s, h)
    assert (s3 == s).all()


def test_weights_ignore_out_of_range():
    _, s, h = blank(1)
    s[:, :2] = SET
    h[0, :3] = (31, 0, 63)
    wv, we = high_level_weights(h, s)
    assert not wv.any() and not we.any()


def figure7_fit():
    """Seed Figure 7: node 0 = expression, node 1 = inner lip, node 2 = outer lip.
    Outer lip: 1st parent inner lip, 2nd parent expression. Inner lip from expression."""
    faps = [2, -1, 4, 5, -1, 51, 52]
    graph = [1, 2, 0, 1, 0, 2]  # (inner->outer) first, so it is the outer lip's 1st parent
    # link (1->2): F51 = 1.5*F4 ; F52 = F4*F5 / (1 + 0*...) -> 2 parents
    # link (0->1): F4 = 3*E ; F5 = (E^2) / (2)        (E = expression intensity)
    # link (0->2): F51 = 10*E ; F52 = -E
    nt = [1, 1, 1, 1, 1, 1]
    dt = [0, 1, 0, 1, 0, 0]
    nc = [1.5, 1.0, 3.0, 1.0, 10.0, -1.0]
    ne = [1, 0, 1, 1, 1, 2, 1, 1]
    dc = [2.0, 2.0]
    de = [0, 0, 0]
    return _fit(faps, graph, ne, de, [], nt, dt, nc, dc)


def test_fit_figure7():
    g = figure7_fit()
    assert g.nodes == [[2], [4, 5], [51, 52]]
    v, s, h = blank(3)
    # frame 0: only the expression -> inner from expression, then outer from (derived) inner
    s[0, 1] = SET
    h[0, 5] = 40
    # frame 1: inner lip set -> outer from inner
    v[1, 3], v[1, 4] = 100, 6
    s[1, 3] = s[1, 4] = SET
    # frame 2: inner lip half set, expression set -> inner FAP 5 from expression, outer from inner
    s[2, 1] = SET
    h[2, 5] = 10
    v[2, 3], s[2, 3] = 8, SET
    v2, s2 = g.apply(v, s, h)
    assert v2[0, 3] == 120 and v2[0, 4] == 800
    assert v2[0, 50] == 180 and v2[0, 51] == 120 * 800 / 2
    assert s2[0, 3] == s2[0, 50] == DERIVED
    assert v2[1, 50] == 150 and v2[1, 51] == 300 and s2[1, 3] == SET
    assert v2[2, 3] == 8 and s2[2, 3] == SET and v2[2, 4] == 50
    assert v2[2, 50] == 12 and v2[2, 51] == 200
    # nothing available -> nothing derived
    v, s, h = blank(1)
    v2, s2 = g.apply(v, s, h)
    assert (s2 == FREE).all()


def test_fit_second_parent_when_first_unavailable():
    g = figure7_fit()
    v, s, h = blank(1)
    s[0, 1] = SET
    h[0, 5] = 4
    v[0, 3], s[0, 3] = 1, SET  # inner: FAP 4 set, FAP 5 derived from expression (= 8)
    v2, _ = g.apply(v, s, h)
    assert v2[0, 4] == 8 and v2[0, 50] == 1.5


def test_fit_errors():
    with pytest.raises(SceneError) as e:
        _fit([3, -1, 4], [0, 1, 1, 0], [1, 1], [], [], [1, 1], [0, 0], [1, 1], [])
    assert e.value.rule == "fit-cycle"
    with pytest.raises(SceneError) as e:
        _fit([3, -1, 4], [0, 5], [], [], [], [], [], [], [])
    assert e.value.rule == "fit-missing-node"
    with pytest.raises(SceneError) as e:
        _fit([3, -1, 4], [0, 1], [1], [], [], [1], [0], [], [])
    assert e.value.rule == "fit-field-count"
    with pytest.raises(SceneError) as e:
        _fit([3, -1, 4], [0, 1], [1], [0], [], [1], [1], [1], [0.0])
    assert e.value.rule == "fit-division-by-zero"
    # denominator = F3 : zero when F3 == 0 -> typed error naming the frame, never NaN
    g = _fit([3, -1, 4], [0, 1], [0], [1], [], [1], [1], [1.0], [1.0])
    v, s, h = blank(2)
    s[:, 2] = SET
    v[0, 2] = 2
    with pytest.raises(SceneError) as e:
        g.apply(v, s, h)
    assert "frame 1" in str(e.value)
    with pytest.raises(SceneError):
        _fit([3, -1, 1], [0, 1], [0], [], [], [1], [0], [1.0], [])


def test_fit_from_scene_in_engine():
    s = bt.parse("""Face { fit FIT { FAPs [4 -1 51] Graph [0 1] numeratorTerms [1] denominatorTerms [0]
                        numeratorCoefs [2.0] numeratorExp [1] } }""")
    model = engine.compile_scene(s)
    assert model.fit is not None and model.fit.nodes == [[4], [51]]
    fr = FapFrames.empty(2)
    fr.values[1, 3], fr.status[1, 3] = 50, SET
    vals, status = engine.effective_faps(fr, model)
    assert vals[1, 50] == 100 and status[1, 50] == DERIVED
    assert status[0, 50] == FREE
    # FIT before left/right fill: FAP 5 -> nothing; FAP 55/56 untouched; FIT-derived 51 has no pair
    st = engine.animate(fr, s)
    assert st.extras["fap_values"][1, 50] == 100
    bad = bt.parse("Face { fit FIT { FAPs [4 -1 51] Graph [0 1 1 0] } }")
    with pytest.raises(SceneError) as e:
        engine.compile_scene(bad)
    assert e.value.node_path.startswith("Face.fit.FIT")
