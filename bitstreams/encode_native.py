"""The encoder's plane payload through the C block coder (``_fastarith``): the same bits as
the pure-Python :class:`~.arith.ArithEncoder` path (``tests/unit/test_native.py``)."""

from __future__ import annotations

import numpy as np

from .arith import NativeSegment, append_bits
from .bitio import BitWriter


def _block_native(nat, w: BitWriter, spec: np.ndarray, pool, values: np.ndarray) -> None:
    """Code one block with the C extension and append it (same bits as ArithEncoder)."""
    if len(values) and np.abs(values).max() >= 2**30:  # cannot happen: symbols were range-checked
        raise ValueError(f"symbol value {int(values[np.abs(values).argmax()])} outside any alphabet")
    st, a, b = nat.encode_block(spec, pool, values.astype(np.int32))
    if st:
        raise ValueError(f"symbol index {b} outside alphabet of {int(spec[a, 0])}")
    append_bits(w, a, b)


def write_payload_native(  # noqa: PLR0913 - the segment's state, as the pure path's method holds it
    nat,
    w: BitWriter,
    plan,
    k: int,
    intra: bool,
    q: int,
    c,
    bounds,
    p_models: dict,
) -> None:
    """The encoder's ``_write_payload`` through the native block coder; p_models holds the segment's NativeSegment."""
    seg = p_models.get(None)
    if seg is None:  # first plane of the segment (p_models is reset at every intra plane)
        seg = p_models[None] = NativeSegment([int(f) for f in np.nonzero(c[2:])[0] + 3], bounds, q)
    if not intra and seg.low_p is None:
        seg.build_p()
    hs = plan.hsym[k]
    src_high = plan.rhigh[k]
    if c[0]:
        if intra:
            _block_native(nat, w, seg.vis_i, None, hs[0:3])
        else:
            _block_native(nat, w, seg.vis_p, seg.vis_pool, hs[0:3])
        w.bit(int(src_high[3]))
    if c[1]:
        if intra:
            _block_native(nat, w, seg.exp_i, None, hs[4:8])
        else:
            _block_native(nat, w, seg.exp_p, seg.exp_pool, hs[4:8])
        w.bit(int(src_high[8]))
        w.bit(int(src_high[9]))
    values = plan.sym[k][seg.idx]
    if intra:
        _block_native(nat, w, seg.low_i, None, values)
    else:
        _block_native(nat, w, seg.low_p, seg.low_pool, values)
