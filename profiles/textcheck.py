"""``fbaconf check F.fap``: the ASCII ``.fap`` form checked against the text rules of its reader.

The reader (:mod:`fbaconf.bitstreams.faptext`) defines the rules (``fap-text-*``, each with its
``FAP-TEXT-*`` code in :mod:`fbaconf.rules`); :func:`faptext.check_fap_text` reports every one a
file breaks — it reads on past an error inside a frame — and this module turns them into checker
diagnostics with their ``line:column``. A profile claim is about the binary stream, so a text
file has no profile or level checks.
"""

from __future__ import annotations

from fbaconf import rules as R
from fbaconf.bitstreams import faptext

from .checker import Report
from .diagnostics import text_diag

TEXT_SUFFIXES = (".fap",)


def is_text_input(path: str, data: bytes) -> bool:
    """A ``.fap`` file name, or bytes that are no face object stream but start like a .fap header
    (a version number such as ``2.1`` or a ``#`` comment)."""
    if path.lower().endswith(TEXT_SUFFIXES):
        return True
    head = data[:64].lstrip(b"\xef\xbb\xbf \t\r\n")
    return head[:1] == b"#" or (head[:2] in (b"1.", b"2.", b"3.") and head[2:3].isdigit())


def analyse_text(data: bytes, *, file: str | None = None) -> Report:
    """Every text rule the bytes (decoded as UTF-8, bad bytes replaced) break, as diagnostics in
    file order, and a summary (frames, frame rate). Never raises."""
    text = data.decode("utf-8", errors="replace")
    out = []
    summary: dict = {"bytes": len(data), "form": "fap-text"}
    try:
        findings, frames, header = faptext.check_fap_text(text, file=file)
        for w in findings:
            out.append(
                text_diag(R.code_for_rule(w.rule, R.TEXT_HEADER), f"{w.message} [rule {w.rule}]", w.line, w.column)
            )
        if frames is not None and header is not None:
            summary.update(frames=len(frames), frame_rate=header.frame_rate)
    except Exception as e:  # noqa: BLE001 - a checker bug must not crash the caller
        out.append(text_diag(R.CHECK_INTERNAL, f"internal checker failure: {type(e).__name__}: {e}", 1, 1))
    return Report(out, summary)


__all__ = ["analyse_text", "is_text_input", "TEXT_SUFFIXES"]
