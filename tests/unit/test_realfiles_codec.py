"""Issue acceptance on the real .fap files of ../shared/data/fap (skipped when absent)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import real_fap_files

from fbaconf.bitstreams import tables
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.faptext import read_fap_file
from fbaconf.bitstreams.frames import SET, first_difference
from fbaconf.errors import EncodeError

QP = tables.quant_steps()
FILES = real_fap_files()
pytestmark = pytest.mark.skipif(not FILES, reason="../shared/data/fap is not present (external suite)")


@pytest.mark.parametrize("path", FILES, ids=[f"{p.parent.name}/{p.name}" for p in FILES])
@pytest.mark.parametrize("quant", [1, 2, 8, 31])
def test_quantised_round_trip(path, quant):
    frames, _, _ = read_fap_file(path)
    res = encode(frames, EncoderOptions(fap_quant=quant))
    got = decode(res.data).frames
    assert first_difference(res.recon, got) is None
    coded = frames.status == SET
    coded[:, :2] = False
    step = np.broadcast_to(QP * quant, frames.values.shape)
    err = np.abs(got.values.astype(np.int64) - frames.values)
    assert (err[coded] <= step[coded] // 2).all()
    np.testing.assert_array_equal(got.frame_number, frames.frame_number)


@pytest.mark.parametrize("path", FILES, ids=[f"{p.parent.name}/{p.name}" for p in FILES])
def test_lossless_exact_or_refused(path):
    frames, _, _ = read_fap_file(path)
    coded = frames.status == SET
    coded[:, :2] = False
    too_big = coded & (np.abs(frames.values.astype(np.int64)) > 1860)
    if not too_big.any():
        got = decode(encode(frames, EncoderOptions(fap_quant=0)).data).frames
        assert np.array_equal(got.values[coded], frames.values[coded])
        return
    k, f = map(int, np.argwhere(too_big)[0])
    with pytest.raises(EncodeError) as e:
        encode(frames, EncoderOptions(fap_quant=0))
    err = e.value
    assert err.rule == "value-range"
    assert (err.fap, err.frame, err.value) == (f + 1, int(frames.frame_number[k]), int(frames.values[k, f]))
    assert f"FAP {f + 1}" in str(err) and str(int(frames.values[k, f])) in str(err)
