"""What a case's input contains that a decoder may trip on, and the edit that takes it out.

A *trigger* is a feature of one input a decoder can mishandle: a CRLF line end, a fractional
frame rate, frames numbered from one, a viseme_def field, a skipped frame... Each comes with an
edit that derives the same input without it (a ``.fap`` by text edits or through fbaconf's
writer; a binary stream re-encoded by fbaconf's encoder from what the reference decodes), so a
cause can be confirmed: the decoder passes the variant. The features of binary streams are the
coverage points (``conformance/data/coverage.toml``, computed from each case's content); the
features of ``.fap`` text are read here from the text, since the form of the text (line ends,
comments, header) is what a text player trips on and no coverage point sees all of it.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fbaconf.bitstreams.faptext import FapFileHeader, read_fap_text, write_fap
from fbaconf.bitstreams.frames import RETAINED, SET, FapFrames

from . import edits

# inner/outer lip FAP pairs (FAP table: the inner lip FAP n and the outer lip FAP of the same point)
LIP_PAIRS = ((52, 5), (58, 11), (57, 10), (51, 4), (56, 9), (55, 8), (53, 6), (54, 7), (59, 12), (60, 13))
HEAD_ROTATION = (48, 49, 50)  # head_pitch, head_yaw, head_roll: angles, in 1e-5 rad
_COMMENT = re.compile(r"#[^\r\n]*")


@dataclass(frozen=True)
class TextInput:
    """A ``.fap`` case's text and what fbaconf reads from it (None: it does not read)."""

    text: str
    frames: FapFrames | None
    header: FapFileHeader | None

    @classmethod
    def of(cls, data: bytes) -> TextInput:
        text = data.decode("utf-8", errors="replace")
        try:
            frames, header, _ = read_fap_text(text)
        except Exception:  # noqa: BLE001 - an invalid file has only its form triggers
            return cls(text, None, None)
        return cls(text, frames, header)


@dataclass(frozen=True)
class Trigger:
    """One feature of a ``.fap`` input: ``present`` says whether an input has it; ``edit`` gives
    the input without it (None where it cannot). ``form``: a feature of the text's form, which
    fbaconf's writer normalises; ``rewrites``: the edit rewrites the frames with that writer (so it
    takes out every form trigger too), else it is a text edit that keeps everything else. ``refines``:
    the broader trigger this one is a case of (it goes first among equally ranked features)."""

    id: str
    what: str
    concerns: str  # the rule or decision it concerns
    present: Callable[[TextInput], bool]
    edit: Callable[[TextInput], str | None]
    form: bool
    rewrites: bool = False
    refines: str = ""


def _without_comments(text: str) -> str:
    """The text without its comments: a line that held only a comment goes (a blank line left in its
    place is a trigger of its own for a reader of line pairs), a comment after tokens is cut."""
    out = []
    for line in text.splitlines(keepends=True):
        body = line.rstrip("\r\n")
        if "#" not in body:
            out.append(line)
        elif body.split("#", 1)[0].strip():
            out.append(body.split("#", 1)[0].rstrip() + line[len(body) :])
    return "".join(out)


def _header_line(text: str) -> int | None:
    for i, line in enumerate(text.splitlines(keepends=True)):
        if _COMMENT.sub("", line).strip():
            return i
    return None


def _with_header(t: TextInput, **change: object) -> str | None:
    """The text with its header line rewritten (one-word name, given fields changed)."""
    i = _header_line(t.text)
    h = t.header
    if i is None or h is None:
        return None
    lines = t.text.splitlines(keepends=True)
    end = lines[i][len(lines[i].rstrip("\r\n")) :]
    f = {"version": h.version, "name": "_".join(h.name.split()) or "fbaconf", "count": h.declared_frames}
    f.update(change)
    rate = h.frame_rate
    rate_s = str(int(rate)) if float(rate).is_integer() else repr(float(rate))
    lines[i] = f"{f['version']} {f['name']} {rate_s} {f['count']}{end or chr(10)}"
    return "".join(lines)


def _rewrite(t: TextInput, change: edits.Change) -> str | None:
    if t.frames is None:
        return None
    fr = t.frames.copy()
    change(fr)
    fr.time_ms = fr.frame_number * 1000.0 / fr.frame_rate
    return write_fap(fr, name="variant")


def _set(fr: FapFrames) -> np.ndarray:
    return np.asarray(fr.status == SET)


def _fields(t: TextInput, *faps: int) -> bool:
    return t.frames is not None and bool(_set(t.frames)[:, [f - 1 for f in faps]].any())


def _numbers(t: TextInput) -> np.ndarray:
    return np.asarray(t.frames.frame_number if t.frames is not None else [], dtype=np.int64)


def _mask_lengths(t: TextInput) -> set[int]:
    out = set()
    for line in _COMMENT.sub("", t.text).splitlines():
        toks = line.split()
        if len(toks) >= 60 and set(toks) <= {"0", "1"}:
            out.add(len(toks))
    return out


TEXT_TRIGGERS: tuple[Trigger, ...] = (
    Trigger(
        "text.crlf",
        "CRLF line ends",
        "FAP-TEXT line ends (CR, LF, CRLF all end a line)",
        lambda t: "\r\n" in t.text,
        lambda t: t.text.replace("\r\n", "\n"),
        True,
    ),
    Trigger(
        "text.cr",
        "CR line ends",
        "FAP-TEXT line ends (CR, LF, CRLF all end a line)",
        lambda t: bool(re.search(r"\r(?!\n)", t.text)),
        lambda t: re.sub(r"\r(?!\n)", "\n", t.text),
        True,
    ),
    Trigger(
        "text.comment",
        "a '#' comment",
        "FAP-TEXT comments (from '#' to the end of the line)",
        lambda t: "#" in t.text,
        lambda t: _without_comments(t.text),
        True,
    ),
    Trigger(
        "text.tabs",
        "tabs between tokens",
        "FAP-TEXT whitespace",
        lambda t: "\t" in t.text,
        lambda t: t.text.replace("\t", " "),
        True,
    ),
    Trigger(
        "text.name-spaces",
        "a header name with spaces",
        "FAP-TEXT header (version, name, rate, count: the name may hold spaces)",
        lambda t: t.header is not None and len(t.header.name.split()) != 1,
        lambda t: _with_header(t),
        True,
    ),
    Trigger(
        "text.version",
        "a header version other than 2.1",
        "FAP-TEXT header version (2.0-2.3 read alike)",
        lambda t: t.header is not None and t.header.version != "2.1",
        lambda t: _with_header(t, version="2.1"),
        True,
    ),
    Trigger(
        "text.count",
        "a header frame count other than the frames in the file",
        "FAP-TEXT header frame count (informative)",
        lambda t: t.header is not None and t.frames is not None and t.header.declared_frames != len(t.frames),
        lambda t: _with_header(t, count=len(t.frames) if t.frames is not None else 0),
        True,
    ),
    Trigger(
        "text.mask-69",
        "69-entry mask lines",
        "FAP-TEXT mask line (68 entries)",
        lambda t: 69 in _mask_lengths(t),
        lambda t: _rewrite(t, edits.nothing),
        True,
        rewrites=True,
    ),
    Trigger(
        "text.wrapped",
        "values wrapped over several lines",
        "FAP-TEXT value lines (tokens, not lines)",
        lambda t: (
            t.frames is not None
            and len([ln for ln in _COMMENT.sub("", t.text).splitlines() if ln.strip()]) > 1 + 2 * len(t.frames)
        ),
        lambda t: _rewrite(t, edits.nothing),
        True,
        rewrites=True,
    ),
    Trigger(
        "content.rate-fractional",
        "a fractional frame rate",
        "FAP-TEXT header frame rate (a real number)",
        lambda t: t.header is not None and not float(t.header.frame_rate).is_integer(),
        lambda t: _rewrite(t, edits.rate25),
        False,
        rewrites=True,
        refines="content.rate-not-25",
    ),
    Trigger(
        "content.rate-not-25",
        "a frame rate other than 25 Hz",
        "FAP-TEXT header frame rate",
        lambda t: t.header is not None and float(t.header.frame_rate) != 25.0,
        lambda t: _rewrite(t, edits.rate25),
        False,
        rewrites=True,
    ),
    Trigger(
        "content.numbered-from-nonzero",
        "a first frame numbered above 0",
        "FAP-TEXT frame numbers (a frame's time is its number / rate)",
        lambda t: len(_numbers(t)) > 0 and int(_numbers(t)[0]) != 0,
        lambda t: _rewrite(t, edits.rows),
        False,
        rewrites=True,
    ),
    Trigger(
        "content.frame-gap",
        "frame numbers with gaps (frames held)",
        "FAP-TEXT frame numbers (values hold between frames)",
        lambda t: bool((np.diff(_numbers(t)) > 1).any()),
        lambda t: _rewrite(t, edits.rows),
        False,
        rewrites=True,
    ),
    Trigger(
        "content.frame-past-count",
        "a frame numbered at or past the header's frame count",
        "FAP-TEXT frame numbers (the header's count is informative, not a bound)",
        lambda t: t.header is not None and len(_numbers(t)) > 0 and int(_numbers(t).max()) >= t.header.declared_frames,
        lambda t: _rewrite(t, edits.rows),
        False,
        rewrites=True,
    ),
    Trigger(
        "content.frame-order",
        "frame numbers that repeat or go back",
        "FAP-TEXT frame numbers (FAP-TEXT-010)",
        lambda t: bool((np.diff(_numbers(t)) < 1).any()),
        lambda t: _rewrite(t, edits.rows),
        False,
        rewrites=True,
    ),
    Trigger(
        "content.high-level",
        "FAP 1/2 (viseme, expression) sent",
        "FAP-TEXT FAP 1 = 4 values, FAP 2 = 6 values",
        lambda t: _fields(t, 1, 2),
        lambda t: _rewrite(t, edits.drop(1, 2)),
        False,
        rewrites=True,
    ),
    Trigger(
        "content.viseme_def",
        "a viseme_def or expression_def set",
        "FAP 1/2 fields viseme_def, expression_def",
        lambda t: t.frames is not None and bool(t.frames.high[:, list(edits.DEFS)].any()),
        lambda t: _rewrite(t, edits.no_defs),
        False,
        rewrites=True,
        refines="content.high-level",
    ),
    Trigger(
        "content.held",
        "values held from an earlier frame (FAPs not in a later mask)",
        "FAP-TEXT mask 0: the FAP keeps its value",
        lambda t: t.frames is not None and bool((t.frames.status == RETAINED).any()),
        lambda t: _rewrite(t, edits.keep),
        False,
        rewrites=True,
    ),
    Trigger(
        "content.lip-pair",
        "an inner and an outer lip FAP of one point",
        "FAP table: inner and outer lip FAPs are independent",
        lambda t: any(_fields(t, a) and _fields(t, b) for a, b in LIP_PAIRS),
        lambda t: _rewrite(t, edits.drop(*(a for a, _ in LIP_PAIRS))),
        False,
        rewrites=True,
    ),
    Trigger(
        "content.head-rotation",
        "head rotation FAPs 48-50 set",
        "FAP table: FAPs 48-50 in AU (1e-5 rad)",
        lambda t: _fields(t, *HEAD_ROTATION),
        lambda t: _rewrite(t, edits.drop(*HEAD_ROTATION)),
        False,
        rewrites=True,
    ),
)
TRIGGERS = {t.id: t for t in TEXT_TRIGGERS}


def text_features(data: bytes) -> set[str]:
    """The triggers present in a ``.fap`` input."""
    t = TextInput.of(data)
    out = set()
    for trig in TEXT_TRIGGERS:
        try:
            if trig.present(t):
                out.add(trig.id)
        except Exception:  # noqa: BLE001,S112 - a trigger that cannot read an odd file is absent
            continue
    return out


def text_variant(data: bytes, trigger: str) -> str | None:
    """The input without ``trigger`` (None where the edit does not apply)."""
    t = TextInput.of(data)
    try:
        return TRIGGERS[trigger].edit(t)
    except Exception:  # noqa: BLE001 - an edit that does not apply to this input
        return None


def control_variant(data: bytes) -> str | None:
    """The input rewritten by fbaconf's writer with nothing taken out of its content: what a content
    edit's variant differs from beside the edit (its form normalised)."""
    return _rewrite(TextInput.of(data), lambda fr: None)
