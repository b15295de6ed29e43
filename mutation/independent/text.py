"""Independent mutants: the ``.fap`` text reader (spec notes §7), written from the notes alone.

Each is one plausible misreading of the text format by someone implementing a .fap player:
header tokenising, comments, line ends, wrapped lines, Greta's 69-entry masks, number syntax,
frame counts and numbers, holding of unsent FAPs, times.
"""

from __future__ import annotations

import re

import numpy as np

from fbaconf.bitstreams import faptext
from fbaconf.bitstreams.frames import FREE, RETAINED, FapFrames
from fbaconf.mutation.core import Mutant

_R = "fbaconf.bitstreams.faptext:_read"
_H = "fbaconf.bitstreams.faptext:_parse_header"
_S7 = "spec notes §7 (.fap text)"


def _src(name, where, description, old, new, rule=_S7, **kw):
    return Mutant(
        name=name, where=where, description=description, old=old, new=new, family="independent", rule=rule, **kw
    )


# ------------------------------------------------------------------ patches
def _patch_crlf():
    """A reader that splits lines on LF only and splits tokens on space/tab/LF: the CR of a
    CRLF line end stays glued to the last token of every line."""
    faptext._LINE_BREAK = re.compile(r"\n")
    faptext._TOKEN = re.compile(r"[^ \t\f\v\n]+")


def _patch_cr_only():
    """Line breaks are LF and CRLF only; a lone CR (classic Mac) does not end a line."""
    faptext._LINE_BREAK = re.compile(r"\r?\n")


def _patch_gap_fill():
    """A player that 'holds' over gaps in the frame numbers by inserting the missing frames
    (copies of the previous frame, every FAP held) instead of keeping the gap."""
    orig = faptext.read_fap_text

    def read_fap_text(text, **kw):
        frames, header, warnings = orig(text, **kw)
        fn = frames.frame_number
        if len(fn) < 2 or np.any(np.diff(fn) <= 0) or np.all(np.diff(fn) == 1):
            return frames, header, warnings
        idx, new_fn, filled = [], [], []
        for k in range(len(fn)):
            if k:
                for g in range(int(fn[k - 1]) + 1, int(fn[k])):
                    idx.append(k - 1)
                    new_fn.append(g)
                    filled.append(True)
            idx.append(k)
            new_fn.append(int(fn[k]))
            filled.append(False)
        out = frames.select(np.array(idx))
        st = out.status.copy()
        fill = np.array(filled)
        st[fill] = np.where(st[fill] == FREE, FREE, RETAINED)
        out.status = st
        out.frame_number = np.array(new_fn, dtype=np.int64)
        out.time_ms = out.frame_number.astype(np.float64) * 1000.0 / header.frame_rate
        return FapFrames(**{f: getattr(out, f) for f in out.__dataclass_fields__}), header, warnings

    faptext.read_fap_text = read_fap_text


_APPEND = """rows_values.append(values)
        rows_status.append(status)
        rows_high.append(high)
        frame_numbers.append(fn)
        last_values, last_high = values, high"""


def _guarded_append(cond: str) -> str:
    body = _APPEND.replace("\n        ", "\n            ")
    return f"if {cond}:\n            {body}"


MUTANTS_LIST: list[Mutant] = [
    # ---------------------------------------------------------------- header
    _src(
        "ind-txt-header-name-one-token",
        _H,
        "header split naively: rate = 3rd token, count = 4th token (a name with spaces breaks it)",
        "(version, vcol), (rate_s, rcol), (count_s, ccol) = toks[0], toks[-2], toks[-1]",
        "(version, vcol), (rate_s, rcol), (count_s, ccol) = toks[0], toks[min(2, len(toks) - 2)], "
        "toks[min(3, len(toks) - 1)]",
    ),
    _src(
        "ind-txt-header-needs-four",
        _H,
        "a header without a name (3 tokens) is rejected instead of read with an empty name",
        "if len(toks) < 3:",
        "if len(toks) < 4:",
    ),
    _src(
        "ind-txt-rate-truncated",
        _H,
        "fractional frame rate truncated to an integer (12.5 -> 12)",
        "rate = float(rate_s)",
        "rate = float(int(float(rate_s)))",
    ),
    _src(
        "ind-txt-rate-integer-only",
        _H,
        "a fractional frame rate (25.0, 29.97) is rejected as not an integer",
        "if not _FLOAT.fullmatch(rate_s):",
        "if not _INT.fullmatch(rate_s):",
    ),
    _src(
        "ind-txt-version-reject",
        _H,
        "an unknown version number is rejected instead of read as 2.x",
        'rep.warn(\n                "fap-text-version",',
        'raise rep.error(\n                "fap-text-version",',
    ),
    _src(
        "ind-txt-version20-scale",
        _R,
        "version 2.0 values divided by 20 (VREng's private convention applied as a rule)",
        """values[fap] = take_int(f"FAP{fap + 1} value", start, _INT32_MIN, _INT32_MAX)[0]""",
        """values[fap] = int(take_int(f"FAP{fap + 1} value", start, _INT32_MIN, _INT32_MAX)[0]"""
        """ / (20 if header.version == "2.0" else 1))""",
    ),
    _src(
        "ind-txt-count-zero-reject",
        _H,
        "a header frame count of 0 is rejected",
        """if not _INT.fullmatch(count_s) or count_s.startswith("-"):""",
        """if not _INT.fullmatch(count_s) or count_s.startswith("-") or not count_s.lstrip("+0"):""",
    ),
    # ---------------------------------------------------------------- frame count / numbers
    _src(
        "ind-txt-stop-at-count",
        _R,
        "reads only as many frames as the header declares (count 0 -> no frames; extra frames ignored)",
        "while pos < ntok:",
        "while pos < ntok and len(frame_numbers) < header.declared_frames:",
    ),
    _src(
        "ind-txt-count-mismatch-error",
        _R,
        "a frame count different from the header's is rejected instead of warned",
        'rep.warn(\n            "fap-text-frame-count", *count_loc,',
        'raise rep.error(\n            "fap-text-frame-count", *count_loc,',
    ),
    _src(
        "ind-txt-beyond-error",
        _R,
        "a frame number past the header's count is rejected instead of warned",
        'rep.warn(\n                "fap-text-frame-beyond",',
        'raise rep.error(\n                "fap-text-frame-beyond",',
    ),
    _src(
        "ind-txt-beyond-drop",
        _R,
        "frames whose number is past the header's count are dropped",
        _APPEND,
        _guarded_append("fn <= header.declared_frames"),
    ),
    _src(
        "ind-txt-late-frame-drop",
        _R,
        "a frame whose number is not above the previous kept one is skipped (S1 encoder style)",
        _APPEND,
        _guarded_append("not frame_numbers or fn > frame_numbers[-1]"),
    ),
    _src(
        "ind-txt-order-error",
        _R,
        "decreasing frame numbers are rejected instead of warned",
        """rep.warn("fap-text-frame-order", fline, fcol,""",
        """raise rep.error("fap-text-frame-order", fline, fcol,""",
    ),
    _src(
        "ind-txt-frame-index",
        _R,
        "the file's frame numbers are ignored: frames are numbered 0, 1, 2... by position",
        "frame_numbers.append(fn)",
        "frame_numbers.append(len(frame_numbers))",
    ),
    Mutant(
        name="ind-txt-gap-fill",
        where="fbaconf.bitstreams.faptext:read_fap_text",
        description="gaps between frame numbers are filled with held copies of the previous frame",
        patch=_patch_gap_fill,
        family="independent",
        rule=_S7 + ", frame numbers / holding",
    ),
    # ---------------------------------------------------------------- times
    _src(
        "ind-txt-time-by-index",
        _R,
        "times from the frame's position in the file instead of its frame number",
        "time_ms = fnum.astype(np.float64) * 1000.0 / header.frame_rate",
        "time_ms = np.arange(len(fnum), dtype=np.float64) * 1000.0 / header.frame_rate",
    ),
    _src(
        "ind-txt-time-one-based",
        _R,
        "frame numbers read as 1-based: time = (frame - 1) / rate",
        "time_ms = fnum.astype(np.float64) * 1000.0 / header.frame_rate",
        "time_ms = (fnum.astype(np.float64) - 1.0) * 1000.0 / header.frame_rate",
    ),
    _src(
        "ind-txt-time-int-ms",
        _R,
        "times truncated to whole milliseconds",
        "time_ms = fnum.astype(np.float64) * 1000.0 / header.frame_rate",
        "time_ms = np.floor(fnum.astype(np.float64) * 1000.0 / header.frame_rate)",
    ),
    # ---------------------------------------------------------------- holding of unsent FAPs
    _src(
        "ind-txt-first-unsent-held",
        _R,
        "FAPs not sent in the first frame count as held (value 0) instead of free",
        "ever_set = np.zeros(NUM_FAPS, bool)",
        "ever_set = np.ones(NUM_FAPS, bool)",
    ),
    _src(
        "ind-txt-unsent-free",
        _R,
        "an unmasked FAP is always free, never held from an earlier frame",
        "status = np.where(mask, SET, np.where(ever_set, RETAINED, FREE))",
        "status = np.where(mask, SET, np.where(ever_set & False, RETAINED, FREE))",
    ),
    _src(
        "ind-txt-unsent-zero",
        _R,
        "an unmasked FAP keeps its held status but its value is reset to 0",
        "values = last_values.copy()",
        "values = np.zeros(NUM_FAPS, np.int32)",
    ),
    _src(
        "ind-txt-high-not-held",
        _R,
        "viseme/expression fields are not held when FAP1/FAP2 is unmasked (reset to 0)",
        "high = last_high.copy()",
        "high = np.zeros(len(HIGH_LEVEL_FIELDS), np.int32)",
    ),
    # ---------------------------------------------------------------- comments / line ends
    _src(
        "ind-txt-comment-line-only",
        _R,
        "'#' starts a comment only at the start of a line; a trailing comment is read as data",
        """content = lines[i].split("#", 1)[0]""",
        """content = "" if lines[i].lstrip().startswith("#") else lines[i]""",
    ),
    _src(
        "ind-txt-comment-body",
        _R,
        "comments are skipped only before the header; a comment line among the frames is data",
        """content = lines[i].split("#", 1)[0]""",
        "content = lines[i]",
    ),
    _src(
        "ind-txt-comment-before-header",
        _H,
        "the header must be the first line: comment lines before it are read as the header",
        """content = raw.split("#", 1)[0]""",
        "content = raw",
    ),
    Mutant(
        name="ind-txt-crlf",
        where=_R,
        description="CRLF line ends: the CR stays glued to the last token of a line",
        patch=_patch_crlf,
        family="independent",
        rule=_S7 + ", whitespace",
    ),
    Mutant(
        name="ind-txt-cr-only",
        where=_R,
        description="a lone CR is not a line break (old Mac line ends)",
        patch=_patch_cr_only,
        family="independent",
        rule=_S7 + ", whitespace",
    ),
    _src(
        "ind-txt-tab-not-space",
        _R,
        "data lines split on spaces only: tab-separated values are not separated",
        "toks = _TOKEN.findall(content) if content else ()",
        """toks = [t for t in content.split(" ") if t.strip()] if content else ()""",
    ),
    _src(
        "ind-txt-wrap-reject",
        _R,
        "a frame's values must all be on the frame number's line (wrapped data lines rejected)",
        "ever_set |= mask",
        """if pos and tl[pos - 1] != fline:
            raise rep.error("fap-text-truncated", tl[pos - 1], tc[pos - 1], "data line wrapped")
        ever_set |= mask""",
    ),
    # ---------------------------------------------------------------- masks
    _src(
        "ind-txt-mask69-any-extra",
        _R,
        "a 69-token mask line always drops its 69th token, even when it is not 0",
        "if _INT.fullmatch(extra) and len(extra) <= _MAX_INT_CHARS and int(extra) == 0:",
        """if extra in ("0", "1"):""",
    ),
    _src(
        "ind-txt-mask69-unsupported",
        _R,
        "no 69-entry masks: the 69th entry is read as the frame number",
        "if tr[pos] == NUM_FAPS + 1:",
        "if False:",
    ),
    _src(
        "ind-txt-mask69-drop-first",
        _R,
        "a 69-entry mask is read as FAP0..FAP68 (first entry dropped instead of the last)",
        'mask[:] = [t == "1" for t in chunk[:NUM_FAPS]]',
        'mask[:] = [t == "1" for t in chunk[width - NUM_FAPS:]]',
    ),
    _src(
        "ind-txt-mask-nonbinary",
        _R,
        "mask entries other than 0/1 are accepted (read as unmasked) instead of rejected",
        "if v not in (0, 1) and not truncated",
        "if (v is None or v < 0) and not truncated",
    ),
    # ---------------------------------------------------------------- numbers
    _src(
        "ind-txt-frac-round",
        _R,
        "fractional numbers accepted and rounded (Python round) instead of rejected",
        "if not _INT.fullmatch(tok):",
        """if len(tok) <= _MAX_INT_CHARS and _FLOAT.fullmatch(tok) and not _INT.fullmatch(tok) \\
                and math.isfinite(float(tok)):
            tok = str(round(float(tok)))
        if not _INT.fullmatch(tok):""",
    ),
    _src(
        "ind-txt-frac-trunc",
        _R,
        "fractional numbers accepted and truncated toward zero instead of rejected",
        "if not _INT.fullmatch(tok):",
        """if len(tok) <= _MAX_INT_CHARS and _FLOAT.fullmatch(tok) and not _INT.fullmatch(tok) \\
                and math.isfinite(float(tok)):
            tok = str(int(float(tok)))
        if not _INT.fullmatch(tok):""",
    ),
    _src(
        "ind-txt-negative-reject",
        _R,
        "numbers checked with str.isdigit(): negative (and +signed) values rejected",
        "if not _INT.fullmatch(tok):",
        "if not tok.isdigit():",
    ),
    # ---------------------------------------------------------------- high-level FAPs
    _src(
        "ind-txt-high-clamp",
        _R,
        "out-of-range viseme/expression fields clamped to their range instead of kept",
        "high[j] = v",
        "high[j] = min(max(v, lo), hi)",
    ),
    _src(
        "ind-txt-expression-order",
        _R,
        "FAP2 fields read as select1 select2 intensity1 intensity2 init def",
        "for fap, sl in ((0, range(0, 4)), (1, range(4, 10))):",
        "for fap, sl in ((0, range(0, 4)), (1, (4, 6, 5, 7, 8, 9))):",
    ),
    _src(
        "ind-txt-high-one-value",
        _R,
        "FAP1/FAP2 take one value each, like low-level FAPs (viseme_select1 / expression_select1)",
        "for fap, sl in ((0, range(0, 4)), (1, range(4, 10))):",
        "for fap, sl in ((0, range(0, 1)), (1, range(4, 5))):",
    ),
]
