"""Reader and writer for the ASCII FAP file format (``.fap``), spec notes section 7.

Format (whitespace between tokens is free: spaces, tabs, CR, LF, CRLF; values may wrap)::

    # comment (a ``#`` anywhere starts a comment that runs to the end of the line)
    version name frame_rate number_of_frames          <- first non-comment line
    m1 m2 ... m68                                      <- mask of FAP1..FAP68 (0/1)
    frame [vs1 vs2 vblend vdef] [es1 ei1 es2 ei2 init edef] v3 ... v68 (masked only)
    ...

Readings chosen here (see ``docs/fap-text.md``):

* header: version = first token, frame_rate / count = the last two tokens, name = the
  text between (it may contain spaces, as Greta writes it);
* the format keeps unmasked FAPs (group mask type 01 semantics): an unmasked FAP is
  RETAINED with its last value when it was set in an earlier frame, else FREE (value 0);
* a mask is 69 entries wide (Greta's quirk: one extra entry after FAP68, dropped) when the
  physical line on which the mask starts carries exactly 69 tokens from the mask's first
  token to the end of the line and the 69th token is the integer 0; otherwise 68.

Every deviation is reported with ``line:column`` (1-based; columns count characters) and a
rule id from :data:`RULES`: recoverable ones as :class:`TextWarning` (raised as
:class:`TextFormatError` under ``strict=True``), unreadable input always as
:class:`TextFormatError`. No other exception escapes the reader for any text input.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fbaconf import rules as _registry
from fbaconf.errors import EncodeError, TextFormatError

from .._atomic import atomic_write_text
from .frames import FREE, HIGH_LEVEL_FIELDS, RETAINED, SET, FapFrames
from .tables import NUM_FAPS

__all__ = [
    "RULES",
    "KNOWN_VERSIONS",
    "FapFileHeader",
    "TextWarning",
    "check_fap_text",
    "read_fap",
    "read_fap_text",
    "read_fap_file",
    "write_fap",
    "write_fap_file",
]

#: Every rule id the reader can report, with its registry entry (fbaconf/rules.py): warning rules
#: are recoverable (TextWarning, or TextFormatError under strict=True); error rules always raise
#: TextFormatError.
RULES = {r.rule: r for r in _registry.RULES.values() if r.stage == "fap-text"}

KNOWN_VERSIONS = ("2.0", "2.1", "2.2")

# Warnings kept per rule before the rest are summarised in one final warning.
MAX_WARNINGS_PER_RULE = 50

_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1
_FRAME_MAX = 2**31 - 1
_LINE_BREAK = re.compile(r"\r\n|\r|\n")
_TOKEN = re.compile(r"[^ \t\f\v\r\n]+")
_INT = re.compile(r"[+-]?[0-9]+", re.ASCII)
_FLOAT = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?", re.ASCII)
_MAX_INT_CHARS = 40  # longer integer tokens are out of every range (and avoid int() digit limits)
_MAX_COUNT_CHARS = 100

# (low, high) for the 10 high-level fields, in HIGH_LEVEL_FIELDS order.
_HIGH_RANGES = ((0, 14), (0, 14), (0, 63), (0, 1), (0, 6), (0, 63), (0, 6), (0, 63), (0, 1), (0, 1))


@dataclass
class FapFileHeader:
    version: str
    name: str
    frame_rate: float
    declared_frames: int


@dataclass
class TextWarning:
    rule: str
    line: int
    column: int
    message: str
    file: str | None = None

    def __str__(self) -> str:
        prefix = f"{self.file}:" if self.file else ""
        return f"{prefix}{self.line}:{self.column}: {self.message} [rule {self.rule}]"

    def to_dict(self) -> dict:
        return {"rule": self.rule, "line": self.line, "column": self.column, "message": self.message, "file": self.file}


class _Reporter:
    """Collects warnings; raises errors. With ``recover`` (the checker's pass) an error inside a
    frame (a bad mask entry, integer or range) is collected too and reading goes on."""

    def __init__(self, file: str | None, strict: bool, recover: bool = False) -> None:
        self.file = file
        self.strict = strict
        self.recover = recover
        self.errors: list[TextWarning] = []
        self.warnings: list[TextWarning] = []
        self._count: dict[str, int] = {}
        self._first_suppressed: dict[str, tuple[int, int]] = {}

    def error(self, rule: str, line: int, column: int, message: str) -> TextFormatError:
        return TextFormatError(message, line=line, column=column, rule=rule, file=self.file)

    def fail(self, rule: str, line: int, column: int, message: str) -> None:
        """A recoverable error: raised, or (``recover``) kept and reading goes on."""
        if not self.recover:
            raise self.error(rule, line, column, message)
        if len(self.errors) < MAX_WARNINGS_PER_RULE * len(RULES):
            self.errors.append(TextWarning(rule, line, column, message, self.file))

    def warn(self, rule: str, line: int, column: int, message: str) -> None:
        if self.strict:
            raise self.error(rule, line, column, message)
        n = self._count.get(rule, 0) + 1
        self._count[rule] = n
        if n <= MAX_WARNINGS_PER_RULE:
            self.warnings.append(TextWarning(rule, line, column, message, self.file))
        elif n == MAX_WARNINGS_PER_RULE + 1:
            self._first_suppressed[rule] = (line, column)

    def finish(self) -> list[TextWarning]:
        for rule, (line, column) in self._first_suppressed.items():
            more = self._count[rule] - MAX_WARNINGS_PER_RULE
            self.warnings.append(
                TextWarning(
                    rule, line, column, f"{more} further warning(s) of this rule suppressed (first one here)", self.file
                )
            )
        self._first_suppressed.clear()
        return self.warnings


def _clip(tok: str, n: int = 20) -> str:
    return repr(tok if len(tok) <= n else tok[:n] + "...")


def _parse_header(lines: list[str], rep: _Reporter) -> tuple[int, FapFileHeader, tuple[int, int]]:
    """Returns (index of the header line, header, (line, col) of the count token)."""
    for i, raw in enumerate(lines):
        content = raw.split("#", 1)[0]
        toks = [(m.group(), m.start()) for m in _TOKEN.finditer(content)]
        if not toks:
            continue
        lineno = i + 1
        if len(toks) < 3:
            raise rep.error(
                "fap-text-header",
                lineno,
                toks[0][1] + 1,
                f"header needs 'version name frame_rate number_of_frames', found {len(toks)} token(s)",
            )
        (version, vcol), (rate_s, rcol), (count_s, ccol) = toks[0], toks[-2], toks[-1]
        if not _FLOAT.fullmatch(rate_s):
            raise rep.error("fap-text-header", lineno, rcol + 1, f"frame rate {_clip(rate_s)} is not a number")
        rate = float(rate_s)
        if not (math.isfinite(rate) and rate > 0):
            raise rep.error(
                "fap-text-header", lineno, rcol + 1, f"frame rate {_clip(rate_s)} is not a positive finite number"
            )
        if not _INT.fullmatch(count_s) or count_s.startswith("-"):
            raise rep.error(
                "fap-text-header", lineno, ccol + 1, f"frame count {_clip(count_s)} is not a non-negative integer"
            )
        if len(count_s) > _MAX_COUNT_CHARS:
            raise rep.error("fap-text-header", lineno, ccol + 1, f"frame count {_clip(count_s)} is absurdly large")
        count = int(count_s)
        name = content[vcol + len(version) : rcol].strip(" \t\f\v")
        if version not in KNOWN_VERSIONS:
            rep.warn(
                "fap-text-version",
                lineno,
                vcol + 1,
                f"version {_clip(version)} is not one of {', '.join(KNOWN_VERSIONS)}; read as 2.x",
            )
        if not name:
            rep.warn("fap-text-name", lineno, rcol + 1, "name field is empty")
        elif len(toks) > 4:
            rep.warn(
                "fap-text-name",
                lineno,
                toks[1][1] + 1,
                f"name field {_clip(name, 60)} contains whitespace ({len(toks) - 3} tokens); "
                "read as one name (version = first token, rate/count = last two)",
            )
        return i, FapFileHeader(version, name, rate, count), (lineno, ccol + 1)
    last = len(lines)
    raise rep.error(
        "fap-text-header",
        last,
        len(lines[-1]) + 1 if lines else 1,
        "no header line: the file holds no tokens outside comments",
    )


def read_fap_text(
    text: str, *, file: str | None = None, strict: bool = False
) -> tuple[FapFrames, FapFileHeader, list[TextWarning]]:
    """Read the text of a .fap file. Returns (frames, header, warnings); raises
    TextFormatError for unreadable input (and for any warning when ``strict``)."""
    if not isinstance(text, str):
        raise TypeError("read_fap_text expects str; use read_fap_file for paths/bytes")
    return _read(text, _Reporter(file, strict))


def check_fap_text(
    text: str, *, file: str | None = None
) -> tuple[list[TextWarning], FapFrames | None, FapFileHeader | None]:
    """Every rule the text of a .fap file breaks, in file order (line, column): the reader's
    warnings and its errors, with the frames read (complete ones) and the header (None when the
    header is broken). Reading goes on after an error inside a frame (the bad token keeps its
    place: a bad mask entry counts as 0, a bad value as 0); a broken header or the end of the
    file inside a frame ends it. The severity of each finding is its rule's
    (``RULES[rule].severity``). Never raises for any text."""
    if not isinstance(text, str):
        raise TypeError("check_fap_text expects str")
    rep = _Reporter(file, strict=False, recover=True)
    frames = header = None
    try:
        frames, header, _ = _read(text, rep)
    except TextFormatError as e:
        rep.errors.append(TextWarning(e.rule, e.line or 1, e.column or 1, e.message, file))
    found = rep.errors + rep.finish()
    return sorted(found, key=lambda w: (w.line, w.column)), frames, header


def _read(text: str, rep: _Reporter) -> tuple[FapFrames, FapFileHeader, list[TextWarning]]:  # noqa: C901 (one pass)
    if text.startswith("\ufeff"):  # byte order mark: read as whitespace (keeps columns)
        text = " " + text[1:]
    lines = _LINE_BREAK.split(text)
    hidx, header, count_loc = _parse_header(lines, rep)

    # Tokens after the header: text, line, column (1-based), tokens left on the line (incl. itself).
    tt: list[str] = []
    tl: list[int] = []
    tc: list[int] = []
    tr: list[int] = []
    for i in range(hidx + 1, len(lines)):
        content = lines[i].split("#", 1)[0]
        toks = _TOKEN.findall(content) if content else ()
        if not toks:
            continue
        cols = [m.start() + 1 for m in _TOKEN.finditer(content)]
        n = len(toks)
        tt.extend(toks)
        tl.extend([i + 1] * n)
        tc.extend(cols)
        tr.extend(range(n, 0, -1))
    ntok = len(tt)
    if ntok:
        eof_loc = (tl[-1], tc[-1] + len(tt[-1]))
    else:
        eof_loc = (len(lines), len(lines[-1]) + 1)

    pos = 0
    truncated = False  # (recover) the file ended inside the frame being read: it is dropped

    def take_int(
        what: str, frame_start: tuple[int, int], lo: int | None, hi: int | None
    ) -> tuple[int | None, int, int]:
        nonlocal pos, truncated
        if pos >= ntok:
            if not truncated:
                rep.fail(
                    "fap-text-truncated",
                    *eof_loc,
                    f"truncated: end of file where {what} was expected (frame starting at "
                    f"{frame_start[0]}:{frame_start[1]})",
                )
            truncated = True
            return (0 if lo is not None else None), *eof_loc
        tok, line, col = tt[pos], tl[pos], tc[pos]
        pos += 1
        if not _INT.fullmatch(tok):
            rep.fail("fap-text-integer", line, col, f"{what}: {_clip(tok)} is not an integer")
            return (0 if lo is not None else None), line, col
        if len(tok) > _MAX_INT_CHARS:
            if lo is None:
                return None, line, col
            rep.fail("fap-text-value-range", line, col, f"{what}: {_clip(tok)} is out of range")
            return 0, line, col
        v = int(tok)
        if lo is not None and not lo <= v <= hi:
            rep.fail("fap-text-value-range", line, col, f"{what}: {v} is outside {lo}..{hi}")
            return 0, line, col
        return v, line, col

    rows_values: list[np.ndarray] = []
    rows_status: list[np.ndarray] = []
    rows_high: list[np.ndarray] = []
    frame_numbers: list[int] = []
    last_values = np.zeros(NUM_FAPS, np.int32)
    last_high = np.zeros(len(HIGH_LEVEL_FIELDS), np.int32)
    ever_set = np.zeros(NUM_FAPS, bool)
    seen: set[int] = set()
    prev_fn: int | None = None

    def frame_end(p: int, mask_tokens: list[str]) -> int:
        """Where a frame whose mask is ``mask_tokens`` (the rest 0) starting at ``p`` ends."""
        m = [t == "1" for t in mask_tokens[:NUM_FAPS]]
        return p + len(mask_tokens) + 1 + 4 * m[0] + 6 * (len(m) > 1 and m[1]) + sum(m[2:])

    def short_mask(p: int) -> int:
        """The entries of a mask line that is short of 68 entries, or 0. Mask entries are tokens, so
        a wrapped mask is read across lines; but when this line's entries, taken as the whole mask,
        end the frame at a line end and the 68 tokens read across lines do not, the line is a short
        mask: reading on would take the frame number for an entry and shift everything after."""
        k = tr[p]
        if not (k < NUM_FAPS and (p == 0 or tl[p - 1] != tl[p]) and all(t in ("0", "1") for t in tt[p : p + k])):
            return 0

        def ends_line(e: int) -> bool:
            return e == ntok or (e < ntok and tl[e] != tl[e - 1])

        across = tt[p : p + NUM_FAPS]
        whole = len(across) == NUM_FAPS and all(t in ("0", "1") for t in across) and ends_line(frame_end(p, across))
        return k if ends_line(frame_end(p, tt[p : p + k])) and not whole else 0

    while pos < ntok:
        start = (tl[pos], tc[pos])
        width = NUM_FAPS
        short = short_mask(pos)
        if short:
            rep.fail(
                "fap-text-mask-short",
                tl[pos],
                tc[pos + short - 1] + len(tt[pos + short - 1]),
                f"mask line has {short} entries, 68 expected (one per FAP); read as if the missing "
                f"entries were 0, the next line as this frame's values",
            )
        if short:
            mask = np.zeros(NUM_FAPS, bool)
            mask[:short] = [t == "1" for t in tt[pos : pos + short]]
            pos += short
        elif tr[pos] == NUM_FAPS + 1:
            extra = tt[pos + NUM_FAPS]
            if _INT.fullmatch(extra) and len(extra) <= _MAX_INT_CHARS and int(extra) == 0:
                width = NUM_FAPS + 1
                rep.warn(
                    "fap-text-mask-length",
                    tl[pos + NUM_FAPS],
                    tc[pos + NUM_FAPS],
                    f"mask line has {NUM_FAPS + 1} entries (Greta quirk); the extra 69th entry is "
                    f"dropped, entries 1..68 are FAP1..FAP68",
                )
        if short:
            pass
        elif len(chunk := tt[pos : pos + width]) == width and all(t == "0" or t == "1" for t in chunk):  # common
            mask = np.zeros(NUM_FAPS, bool)
            mask[:] = [t == "1" for t in chunk[:NUM_FAPS]]
            pos += width
        else:
            mask = np.zeros(NUM_FAPS, bool)
            for k in range(width):
                what = f"mask entry {k + 1}" + (f" (FAP{k + 1})" if k < NUM_FAPS else " (extra)")
                v, line, col = take_int(what, start, None, None)
                if v not in (0, 1) and not truncated and (v is not None or _INT.fullmatch(tt[pos - 1])):
                    rep.fail(
                        "fap-text-mask-value", line, col, f"{what} is {_clip(tt[pos - 1])}; mask entries must be 0 or 1"
                    )
                if k < NUM_FAPS:
                    mask[k] = v == 1
        fn, fline, fcol = take_int("frame number", start, 0, _FRAME_MAX)
        if truncated:
            break
        if prev_fn is not None and fn < prev_fn:  # below the previous one: out of order, repeated or not
            rep.warn("fap-text-frame-order", fline, fcol, f"frame number {fn} follows frame number {prev_fn}")
        if fn in seen:
            rep.warn("fap-text-frame-duplicate", fline, fcol, f"frame number {fn} already used by an earlier frame")
        if fn > header.declared_frames:
            rep.warn(
                "fap-text-frame-beyond",
                fline,
                fcol,
                f"frame number {fn} is beyond the header's declared count {header.declared_frames}",
            )
        seen.add(fn)
        prev_fn = fn

        high = last_high.copy()
        for fap, sl in ((0, range(0, 4)), (1, range(4, 10))):
            if mask[fap]:
                for j in sl:
                    lo, hi = _HIGH_RANGES[j]
                    v, line, col = take_int(f"FAP{fap + 1} {HIGH_LEVEL_FIELDS[j]}", start, _INT32_MIN, _INT32_MAX)
                    if not lo <= v <= hi:
                        rep.warn(
                            "fap-text-high-level-range",
                            line,
                            col,
                            f"{HIGH_LEVEL_FIELDS[j]} = {v} is outside {lo}..{hi}",
                        )
                    high[j] = v
        values = last_values.copy()
        for fap in np.nonzero(mask[2:])[0] + 2:
            values[fap] = take_int(f"FAP{fap + 1} value", start, _INT32_MIN, _INT32_MAX)[0]
        if truncated:
            break
        ever_set |= mask
        status = np.where(mask, SET, np.where(ever_set, RETAINED, FREE)).astype(np.uint8)
        rows_values.append(values)
        rows_status.append(status)
        rows_high.append(high)
        frame_numbers.append(fn)
        last_values, last_high = values, high

    n = len(frame_numbers)
    if n != header.declared_frames:
        rep.warn(
            "fap-text-frame-count", *count_loc, f"header declares {header.declared_frames} frame(s), the file holds {n}"
        )

    fnum = np.array(frame_numbers, dtype=np.int64)
    with np.errstate(over="ignore"):  # absurdly small frame rates give inf times, not warnings
        time_ms = fnum.astype(np.float64) * 1000.0 / header.frame_rate
    frames = FapFrames(
        values=np.array(rows_values, dtype=np.int32).reshape(n, NUM_FAPS),
        status=np.array(rows_status, dtype=np.uint8).reshape(n, NUM_FAPS),
        high=np.array(rows_high, dtype=np.int32).reshape(n, len(HIGH_LEVEL_FIELDS)),
        frame_number=fnum,
        time_ms=time_ms,
        frame_rate=header.frame_rate,
    )
    return frames, header, rep.finish()


def read_fap_file(
    path, *, strict: bool = False, file: str | None = None
) -> tuple[FapFrames, FapFileHeader, list[TextWarning]]:
    """Read a .fap file (decoded as UTF-8, undecodable bytes replaced). OSError propagates."""
    data = Path(path).read_bytes()
    return read_fap_text(data.decode("utf-8", errors="replace"), file=file or str(path), strict=strict)


def read_fap(
    source, *, file: str | None = None, strict: bool = False
) -> tuple[FapFrames, FapFileHeader, list[TextWarning]]:
    """Read from a path (``os.PathLike``, or a ``str`` without line breaks), from ``bytes``, or
    from the text itself (a ``str`` containing a line break)."""
    if isinstance(source, (bytes, bytearray)):
        return read_fap_text(bytes(source).decode("utf-8", errors="replace"), file=file, strict=strict)
    if isinstance(source, str) and ("\n" in source or "\r" in source):
        return read_fap_text(source, file=file, strict=strict)
    if isinstance(source, (str, os.PathLike)):
        return read_fap_file(source, strict=strict, file=file)
    raise TypeError(f"read_fap: unsupported source type {type(source).__name__}")


# ---------------------------------------------------------------------------------- writer
_WORD = re.compile(r"[^\s#]+")


def _format_rate(rate: float) -> str:
    r = float(rate)
    return str(int(r)) if r.is_integer() else repr(r)


def write_fap(frames: FapFrames, *, name: str = "fbaconf", version: str = "2.1") -> str:
    """The .fap text of ``frames`` (LF line endings, one mask line and one data line per frame).

    The mask is ``status == SET``; RETAINED / FREE / DERIVED FAPs are not written (the format
    only expresses "keep the previous value"). Raises EncodeError (rule ``fap-text-write``)
    for a name/version that is not one whitespace-free token without ``#``, a frame rate that
    is not positive and finite, or frame numbers outside 0..2^31-1."""
    for label, word in (("name", name), ("version", version)):
        if not isinstance(word, str) or not _WORD.fullmatch(word):
            raise EncodeError(
                f".fap {label} {word!r} must be one token without whitespace or '#'", rule="fap-text-write"
            )
    rate = float(frames.frame_rate)
    if not (math.isfinite(rate) and rate > 0):
        raise EncodeError(f"frame rate {frames.frame_rate!r} is not a positive finite number", rule="fap-text-write")
    n = len(frames)
    fnums = np.asarray(frames.frame_number, dtype=np.int64)
    if n and (fnums.min() < 0 or fnums.max() > _FRAME_MAX):
        k = int(np.nonzero((fnums < 0) | (fnums > _FRAME_MAX))[0][0])
        raise EncodeError(f"frame number {int(fnums[k])} outside 0..{_FRAME_MAX}", rule="fap-text-write", frame=k)
    out = [f"{version} {name} {_format_rate(rate)} {n}"]
    masks = frames.status == SET
    for k in range(n):
        mask = masks[k]
        out.append(" ".join("1" if m else "0" for m in mask))
        data = [str(int(fnums[k]))]
        if mask[0]:
            data.extend(str(int(v)) for v in frames.high[k, 0:4])
        if mask[1]:
            data.extend(str(int(v)) for v in frames.high[k, 4:10])
        data.extend(str(int(v)) for v in frames.values[k, 2:][mask[2:]])
        out.append(" ".join(data))
    return "\n".join(out) + "\n"


def write_fap_file(path, frames: FapFrames, *, name: str = "fbaconf", version: str = "2.1") -> None:
    """Write ``write_fap(frames)`` to ``path`` atomically."""
    atomic_write_text(path, write_fap(frames, name=name, version=version))
