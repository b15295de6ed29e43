"""Independent mutants: timing (see the package docstring).

Frame timing of decision D6 and spec notes §1.2: frame rate (frame_rate + seconds/16,
x 1000/1001 with frequency_offset), the default rate, time codes, number_of_frames_to_skip,
frame numbers and plane times, including the frames of a DCT plane group. Written from the
spec notes and the reference source only; each is one plausible misreading.
"""

from __future__ import annotations

from fbaconf.bitstreams import syntax
from fbaconf.mutation.core import Mutant

DEC = "fbaconf.bitstreams.decoder:_Decoder"
DCT = "fbaconf.bitstreams.dct:decode_group"


def _m(name, where, description, old, new, rule, **kw) -> Mutant:
    return Mutant(
        name=name, where=where, description=description, old=old, new=new, family="independent", rule=rule, **kw
    )


def _p(name, where, description, patch, rule, **kw) -> Mutant:
    return Mutant(name=name, where=where, description=description, patch=patch, family="independent", rule=rule, **kw)


# ---------------------------------------------------------------------------- frame rate patches
def _set_rate(fn) -> None:
    syntax.FrameRateCode.rate = property(fn)


def _patch_rate_offset_ignored() -> None:
    """frequency_offset read but never applied."""
    _set_rate(lambda self: self.frame_rate + self.seconds / 16.0)


def _patch_rate_offset_inverted() -> None:
    """frequency_offset multiplies by 1001/1000 (rate raised, period x 1000/1001)."""
    _set_rate(
        lambda self: (self.frame_rate + self.seconds / 16.0) * (1001.0 / 1000.0 if self.frequency_offset else 1.0)
    )


def _patch_rate_offset_integer_part() -> None:
    """The 1000/1001 factor applied to the integer frame_rate only, the sixteenths added after."""
    _set_rate(
        lambda self: (
            (self.frame_rate * 1000.0 / 1001.0 if self.frequency_offset else self.frame_rate) + self.seconds / 16.0
        )
    )


def _patch_rate_seconds_ignored() -> None:
    """The 4-bit 'seconds' field (sixteenths of a Hz) is read but dropped."""
    _set_rate(lambda self: self.frame_rate * 1000.0 / 1001.0 if self.frequency_offset else float(self.frame_rate))


def _patch_rate_seconds_tenths() -> None:
    """The 4-bit 'seconds' field read as tenths of a Hz (decimal fraction) instead of sixteenths."""
    _set_rate(
        lambda self: (self.frame_rate + self.seconds / 10.0) * (1000.0 / 1001.0 if self.frequency_offset else 1.0)
    )


def _patch_default_rate_30() -> None:
    """S1 decoder's default: 30 Hz when no frame rate was ever signalled (D6 says 25)."""
    syntax.DEFAULT_FRAME_RATE = 30.0


MUTANTS_LIST: list[Mutant] = [
    # ------------------------------------------------------------------ frame rate (D6)
    _p(
        "ind-time-rate-offset-ignored",
        "fbaconf.bitstreams.syntax:FrameRateCode",
        "frequency_offset is read but the 1000/1001 factor is never applied",
        _patch_rate_offset_ignored,
        "D6 frame rate x 1000/1001",
    ),
    _p(
        "ind-time-rate-offset-inverted",
        "fbaconf.bitstreams.syntax:FrameRateCode",
        "frequency_offset multiplies the rate by 1001/1000 instead of 1000/1001",
        _patch_rate_offset_inverted,
        "D6 frame rate x 1000/1001",
    ),
    _p(
        "ind-time-rate-offset-integer-part",
        "fbaconf.bitstreams.syntax:FrameRateCode",
        "1000/1001 applied to frame_rate only, seconds/16 added unscaled",
        _patch_rate_offset_integer_part,
        "D6 (frame_rate + seconds/16) x 1000/1001",
    ),
    _p(
        "ind-time-rate-seconds-ignored",
        "fbaconf.bitstreams.syntax:FrameRateCode",
        "the 4-bit seconds (sixteenths) of the frame rate are dropped",
        _patch_rate_seconds_ignored,
        "D6 frame_rate + seconds/16",
    ),
    _p(
        "ind-time-rate-seconds-tenths",
        "fbaconf.bitstreams.syntax:FrameRateCode",
        "the 4-bit seconds field is taken as tenths of a Hz (frame_rate + seconds/10)",
        _patch_rate_seconds_tenths,
        "D6 frame_rate + seconds/16",
    ),
    _p(
        "ind-time-default-rate-30",
        "fbaconf.bitstreams.syntax:DEFAULT_FRAME_RATE",
        "a stream that never signals a frame rate is timed at 30 Hz (S1's decoder) instead of 25 Hz",
        _patch_default_rate_30,
        "D6 default 25 Hz",
    ),
    _m(
        "ind-time-rate-first-only",
        f"{DEC}.plane",
        "the frame rate of the first intra plane is kept; a later intra plane's new rate is ignored",
        "self.rate = fr.rate",
        "self.rate = fr.rate if self.rate is None else self.rate",
        "D6 / §1.2 frame rate per intra plane",
    ),
    _m(
        "ind-time-rate-reset-at-intra",
        f"{DEC}.plane",
        "an intra plane without is_frame_rate falls back to the default 25 Hz instead of keeping the last rate",
        'if info.is_intra:\n        if r.bit("is_frame_rate"):',
        'if info.is_intra:\n        self.rate = None\n        if r.bit("is_frame_rate"):',
        "D6 rate persists until signalled again",
    ),
    _m(
        "ind-time-rate-zero-integer-check",
        f"{DEC}.plane",
        "rejects frame_rate 0 even when seconds > 0 (rates below 1 Hz such as 0 + 8/16)",
        "if fr.frame_rate == 0 and fr.seconds == 0:",
        "if fr.frame_rate == 0:",
        "D6 frame rate = frame_rate + seconds/16",
    ),
    # ------------------------------------------------------------------ skip frames, frame numbers, times
    _m(
        "ind-time-first-plane-skip-time-zero",
        f"{DEC}.plane",
        "the first plane is timed at 0 ms even when it skips frames (its frame number still counts them)",
        "self.time_ms = info.skip * 1000.0 / rate",
        "self.time_ms = 0.0",
        "D6 time = previous + (skipped + 1) / rate",
    ),
    _m(
        "ind-time-first-plane-skip-not-counted",
        f"{DEC}.plane",
        "number_of_frames_to_skip of the first plane does not advance the frame number (stream starts at frame 0)",
        "self.frame_number = self.frame_number + info.skip + 1",
        "self.frame_number = self.frame_number + (info.skip if self.planes else 0) + 1",
        "D6 / §1.2 skip_frames",
    ),
    _m(
        "ind-time-frame-number-one-based",
        f"{DEC}.__init__",
        "frame numbers start at 1 (the first plane without skip is frame 1)",
        "self.frame_number = -1",
        "self.frame_number = 0",
        "D6 frame numbering",
    ),
    _m(
        "ind-time-skip-not-in-time",
        f"{DEC}.plane",
        "a plane's time advances by one frame period whatever number_of_frames_to_skip says",
        "self.time_ms = self.time_ms + (info.skip + 1) * 1000.0 / rate",
        "self.time_ms = self.time_ms + 1000.0 / rate",
        "D6 time = previous + (skipped + 1) / rate",
    ),
    _m(
        "ind-time-skip-not-in-frame-number",
        f"{DEC}.plane",
        "frame numbers advance by 1 per plane, skipped frames not counted",
        "self.frame_number = self.frame_number + info.skip + 1",
        "self.frame_number = self.frame_number + 1",
        "D6 / §1.2 skip_frames",
    ),
    _m(
        "ind-time-ms-rounded",
        f"{DEC}.plane",
        "plane times are accumulated in whole milliseconds (S1's integer PTS), so 30 Hz drifts",
        "self.time_ms = self.time_ms + (info.skip + 1) * 1000.0 / rate",
        "self.time_ms = float(round(self.time_ms + (info.skip + 1) * 1000.0 / rate))",
        "D6 real arithmetic",
    ),
    # ------------------------------------------------------------------ time codes
    _m(
        "ind-time-code-hours-ignored",
        f"{DEC}.plane",
        "the hours of a time code are not added (time code = minutes and seconds only)",
        "self.time_ms = (3600.0 * h + 60.0 * m + s) * 1000.0",
        "self.time_ms = (60.0 * m + s) * 1000.0",
        "D6 / §1.2 time code hours",
    ),
    _m(
        "ind-time-code-first-only",
        f"{DEC}.plane",
        "only the first plane's time code sets the time; later time codes are ignored (times accumulate)",
        "if info.time_code is not None:\n        h, m, _, s = info.time_code",
        "if info.time_code is not None and self.time_ms is None:\n        h, m, _, s = info.time_code",
        "D6 time of plane = time code when present",
    ),
    _m(
        "ind-time-code-plus-skip",
        f"{DEC}.plane",
        "the time code is taken as the time of the first skipped frame: time = time code + skip / rate",
        "self.time_ms = (3600.0 * h + 60.0 * m + s) * 1000.0",
        "self.time_ms = (3600.0 * h + 60.0 * m + s) * 1000.0 + info.skip * 1000.0 / rate",
        "D6 time of plane = time code when present",
    ),
    _m(
        "ind-time-code-sets-frame-number",
        f"{DEC}.plane",
        "a time code also resets the frame counter to round(time code x rate)",
        "self.time_ms = (3600.0 * h + 60.0 * m + s) * 1000.0",
        "self.time_ms = (3600.0 * h + 60.0 * m + s) * 1000.0\n"
        "        self.frame_number = int(round(self.time_ms * rate / 1000.0))",
        "D6 frame numbers from skips only",
    ),
    # ------------------------------------------------------------------ DCT plane groups
    _m(
        "ind-time-dct-group-length-not-counted",
        DCT,
        "after a DCT plane group the frame counter stays at the group's first frame (time advances)",
        "d.frame_number, d.time_ms = fn, tm",
        "d.time_ms = tm",
        "D6 / §4 frames of a plane group",
    ),
    _m(
        "ind-time-dct-skip-every-frame",
        DCT,
        "number_of_frames_to_skip is applied between every two frames of a DCT plane group",
        "fn += 1\n            tm = tm + 1000.0 / rate",
        "fn += info.skip + 1\n            tm = tm + (info.skip + 1) * 1000.0 / rate",
        "D6 / §4 frames of a plane group",
    ),
]
