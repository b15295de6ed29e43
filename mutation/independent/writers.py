"""Independent mutants: the decoder's output writers, written from the spec notes alone.

The ``.fap`` text writer (header fields, rate formatting, masks, which values are written,
frame numbers), the ``.npz`` writer (arrays, dtypes, statuses, frame numbers, times) and what
a player writes as its FAP output (its state). Each changes what a checker reading the output
sees.
"""

from __future__ import annotations

from fbaconf.mutation.core import Mutant

_W = "fbaconf.bitstreams.faptext:write_fap"
_RATE = "fbaconf.bitstreams.faptext:_format_rate"
_NPZ = "fbaconf.bitstreams.frames:FapFrames.to_npz_bytes"
_S7 = "spec notes §7 (.fap text), writer"
_OUT = "decoder output (.npz FapFrames)"
_ARR = "arrays = {f.name: getattr(self, f.name) for f in fields(self) if isinstance(getattr(self, f.name), np.ndarray)}"
_HIGH = """if mask[0]:
            data.extend(str(int(v)) for v in frames.high[k, 0:4])
        if mask[1]:
            data.extend(str(int(v)) for v in frames.high[k, 4:10])"""
_LOW = "data.extend(str(int(v)) for v in frames.values[k, 2:][mask[2:]])"


def _src(name, where, description, old, new, rule=_S7, **kw):
    return Mutant(
        name=name, where=where, description=description, old=old, new=new, family="independent", rule=rule, **kw
    )


MUTANTS_LIST: list[Mutant] = [
    # ---------------------------------------------------------------- .fap header
    _src(
        "ind-wr-rate-int",
        _RATE,
        "the frame rate is written as an integer (12.5 -> 12)",
        "return str(int(r)) if r.is_integer() else repr(r)",
        "return str(int(r))",
    ),
    # killed since: the header rate is held to 0.02 % too, and 0.4995 (0.5 x 1000/1001)
    # written as 0.50 loses the 1000/1001 factor (rate-offset-sixteenths)
    _src(
        "ind-wr-rate-2dp",
        _RATE,
        "a fractional frame rate is written with two decimals (29.97002997 -> 29.97)",
        "return str(int(r)) if r.is_integer() else repr(r)",
        """return str(int(r)) if r.is_integer() else f"{r:.2f}\"""",
    ),
    _src(
        "ind-wr-count-last-plus1",
        _W,
        "the header frame count is last frame number + 1 instead of the number of frames",
        """out = [f"{version} {name} {_format_rate(rate)} {n}"]""",
        """out = [f"{version} {name} {_format_rate(rate)} {int(fnums[-1]) + 1 if n else 0}"]""",
    ),
    # ---------------------------------------------------------------- .fap masks / values
    _src(
        "ind-wr-mask-not-free",
        _W,
        "every FAP holding a value (SET or RETAINED) is written as masked",
        "masks = frames.status == SET",
        "masks = frames.status != FREE",
        equivalent="the .fap format can only say 'set' or 'keep' (docs/fap-text.md): a held value written "
        "again as set is the same state, and text outputs are compared on values",
    ),
    _src(
        "ind-wr-mask-nonzero",
        _W,
        "only FAPs with a non-zero value are written (a FAP set to 0, and FAP1/FAP2, are dropped)",
        "masks = frames.status == SET",
        "masks = (frames.status == SET) & (frames.values != 0)",
    ),
    _src(
        "ind-wr-values-all",
        _W,
        "all 66 low-level values are written on every data line, not only the masked ones",
        _LOW,
        "data.extend(str(int(v)) for v in frames.values[k, 2:])",
    ),
    _src(
        "ind-wr-expression-first",
        _W,
        "the FAP2 (expression) fields are written before the FAP1 (viseme) fields",
        _HIGH,
        """if mask[1]:
            data.extend(str(int(v)) for v in frames.high[k, 4:10])
        if mask[0]:
            data.extend(str(int(v)) for v in frames.high[k, 0:4])""",
    ),
    _src(
        "ind-wr-high-as-low",
        _W,
        "FAP1/FAP2 written as one (low-level) value each instead of their 4 / 6 fields",
        _HIGH + "\n        " + _LOW,
        "data.extend(str(int(v)) for v in frames.values[k][mask])",
    ),
    _src(
        "ind-wr-frame-index",
        _W,
        "the row index is written as the frame number (skipped frames / offsets lost)",
        "data = [str(int(fnums[k]))]",
        "data = [str(k)]",
    ),
    _src(
        "ind-wr-frame-one-based",
        _W,
        "frame numbers written 1-based (frame number + 1)",
        "data = [str(int(fnums[k]))]",
        "data = [str(int(fnums[k]) + 1)]",
        equivalent="real .fap files number frames from 0 or from 1, so a text output may count from either "
        "(one offset for the whole file, harness/compare/faps.py); a constant +1 is that offset",
    ),
    # ---------------------------------------------------------------- .npz
    _src(
        "ind-wr-npz-time-rounded",
        _NPZ,
        "times written rounded to whole milliseconds",
        _ARR,
        _ARR + '; arrays["time_ms"] = np.round(arrays["time_ms"])',
        rule=_OUT + ", times",
        equivalent="rounding moves a time by at most 0.5 ms, which is the plane-time tolerance itself "
        "([faps] time_tol_ms = 0.5 in tolerances.toml): a decoder keeping whole milliseconds "
        "is within it by design",
    ),
    _src(
        "ind-wr-npz-status-mask",
        _NPZ,
        "status written as the mask of sent FAPs (bool) instead of the status codes",
        _ARR,
        _ARR + '; arrays["status"] = arrays["status"] == SET',
        rule=_OUT + ", statuses",
    ),
    _src(
        "ind-wr-npz-values-int16",
        _NPZ,
        "values written as int16 (large values wrap)",
        _ARR,
        _ARR + '; arrays["values"] = arrays["values"].astype(np.int16)',
        rule=_OUT + ", dtypes",
    ),
    _src(
        "ind-wr-npz-rate-int",
        _NPZ,
        "frame rate written as an integer",
        "frame_rate=np.float64(self.frame_rate)",
        "frame_rate=np.int64(self.frame_rate)",
        rule=_OUT + ", frame rate",
    ),
    _src(
        "ind-wr-npz-frame-index",
        _NPZ,
        "frame numbers written as 0..n-1 (row index) instead of the decoded frame numbers",
        _ARR,
        _ARR + '; arrays["frame_number"] = np.arange(len(self), dtype=np.int64)',
        rule=_OUT + ", frame numbers",
    ),
    # ---------------------------------------------------------------- player state
    _src(
        "ind-wr-player-state-off",
        "fbaconf.reference.pipeline:reference_outputs",
        "a .fap player writes the file's statuses (RETAINED) instead of its state (held = SET)",
        "save_faps(state_of(frames) if player_state else frames, faps_out)",
        "save_faps(frames, faps_out)",
        rule="decoder output, player state of .fap input",
    ),
    _src(
        "ind-wr-player-state-free",
        "fbaconf.reference.pipeline:state_of",
        "the player state marks every FAP SET, also the FREE ones never sent",
        "np.isin(out.status, (RETAINED, DERIVED))",
        "np.isin(out.status, (RETAINED, DERIVED, 0))",
        rule="decoder output, player state of .fap input",
    ),
    _src(
        "ind-wr-player-state-always",
        "fbaconf.reference.pipeline:is_fap_text",
        "a bitstream (.fba) input is also written as a player state (RETAINED -> SET)",
        """return path is not None and Path(path).suffix.lower() == ".fap\"""",
        "return path is not None",
        rule="decoder output, player state only for .fap input",
    ),
]
