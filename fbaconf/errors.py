"""Typed errors for everything that reads untrusted input.

Every error names where (file, bit offset -> byte offset, plane/frame index, FAP, or
line:column for text) and which rule was broken (a short stable rule id plus a message).
Callers catch :class:`FbaconfInputError`; anything else escaping a parser is a bug.

These are the root error types of every stage; stage-specific errors (``rendering/errors.py``,
``scenes.bifs.BifsError``) derive from them. Every rule id is registered in
:mod:`fbaconf.rules`.
"""

from __future__ import annotations

from typing import Any


def join_location(*parts: str | tuple[str, object]) -> str:
    """Comma-separated location: a str part as it is, a (label, value) part as 'label value'
    unless the value is None or empty."""
    out = []
    for p in parts:
        if isinstance(p, str):
            out.append(p)
        elif p[1] is not None and p[1] != "":
            out.append(f"{p[0]} {p[1]}")
    return ", ".join(out)


class FbaconfInputError(Exception):
    """Base class: bad input, reported with a precise location and the rule broken."""

    rule: str = "input"

    def __init__(self, message: str, *, rule: str | None = None, file: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        if rule is not None:
            self.rule = rule
        self.file = file

    def location(self) -> str:
        return ""

    def __str__(self) -> str:
        where = self.location()
        prefix = f"{self.file}: " if self.file else ""
        return f"{prefix}{where}{': ' if where else ''}{self.message} [rule {self.rule}]"

    def to_dict(self) -> dict[str, Any]:
        return {"type": type(self).__name__, "rule": self.rule, "message": self.message, "file": self.file}


class BitstreamError(FbaconfInputError):
    """A face object bitstream violates the syntax or a decoding rule."""

    rule = "bitstream"

    def __init__(
        self,
        message: str,
        *,
        bit_offset: int,
        rule: str,
        plane: int | None = None,
        frame: int | None = None,
        fap: int | None = None,
        file: str | None = None,
        partial: Any = None,  # the decoder's FapFrames; the core imports no stage
    ) -> None:
        super().__init__(message, rule=rule, file=file)
        self.bit_offset = int(bit_offset)
        self.plane = plane
        self.frame = frame
        self.fap = fap
        self.partial = partial  # frames decoded before the error (never written out as a result)

    @property
    def byte_offset(self) -> int:
        return self.bit_offset // 8

    def location(self) -> str:
        return join_location(
            f"byte {self.byte_offset} bit {self.bit_offset % 8} (bit offset {self.bit_offset})",
            ("plane", self.plane),
            ("frame", self.frame),
            ("FAP", self.fap),
        )

    def to_dict(self) -> dict[str, Any]:
        d = super().to_dict()
        d.update(
            bit_offset=self.bit_offset, byte_offset=self.byte_offset, plane=self.plane, frame=self.frame, fap=self.fap
        )
        return d


class TextFormatError(FbaconfInputError):
    """A text file (.fap, BT scene, TOML) is malformed."""

    rule = "text"

    def __init__(
        self, message: str, *, line: int, column: int, rule: str, file: str | None = None, node_path: str | None = None
    ) -> None:
        super().__init__(message, rule=rule, file=file)
        self.line = line
        self.column = column
        self.node_path = node_path

    def location(self) -> str:
        loc = f"{self.line}:{self.column}"
        return f"{loc} ({self.node_path})" if self.node_path else loc

    def to_dict(self) -> dict[str, Any]:
        d = super().to_dict()
        d.update(line=self.line, column=self.column, node_path=self.node_path)
        return d


class EncodeError(FbaconfInputError):
    """The encoder cannot code its input (value out of codable range, bad option)."""

    rule = "encode"

    def __init__(
        self,
        message: str,
        *,
        rule: str,
        frame: int | None = None,
        fap: int | None = None,
        value: int | None = None,
        file: str | None = None,
    ) -> None:
        super().__init__(message, rule=rule, file=file)
        self.frame = frame
        self.fap = fap
        self.value = value

    def location(self) -> str:
        return join_location(("frame", self.frame), ("FAP", self.fap), ("value", self.value))

    def to_dict(self) -> dict[str, Any]:
        d = super().to_dict()
        d.update(frame=self.frame, fap=self.fap, value=self.value)
        return d


class SceneError(FbaconfInputError):
    """A scene (face model, FDP, FIT, FaceDefTables) is semantically invalid."""

    rule = "scene"

    def __init__(self, message: str, *, rule: str, node_path: str | None = None, file: str | None = None) -> None:
        super().__init__(message, rule=rule, file=file)
        self.node_path = node_path

    def location(self) -> str:
        return self.node_path or ""

    def to_dict(self) -> dict[str, Any]:
        d = super().to_dict()
        d.update(node_path=self.node_path)
        return d
