"""Typed errors of the rendering stage.

All derive from :class:`fbaconf.errors.FbaconfInputError` (so the CLI reports
them as one line and exits 2) and from :class:`ValueError` (so plain Python callers can
catch them as bad values).
"""

from __future__ import annotations

from fbaconf.errors import FbaconfInputError, join_location


class RenderInputError(FbaconfInputError, ValueError):
    """Base class of the rendering stage's input errors."""

    rule = "render"


class ScenarioError(RenderInputError):
    """A scenario (TOML) is semantically invalid: names the file and the dotted key."""

    rule = "scenario"

    def __init__(
        self, message: str, *, key: str | None = None, file: str | None = None, rule: str | None = None
    ) -> None:
        super().__init__(message, rule=rule, file=file)
        self.key = key

    def location(self) -> str:
        return f"key '{self.key}'" if self.key else ""

    def to_dict(self) -> dict:
        d = super().to_dict()
        d.update(key=self.key)
        return d


class GeometryError(RenderInputError):
    """The mesh cannot be rendered: non-finite vertex, triangle index out of range.

    Names the mesh part, the vertex (index local to the part) and the frame."""

    rule = "geometry"

    def __init__(
        self,
        message: str,
        *,
        part: str | None = None,
        vertex: int | None = None,
        frame: int | None = None,
        rule: str | None = None,
        file: str | None = None,
    ) -> None:
        super().__init__(message, rule=rule, file=file)
        self.part = part
        self.vertex = vertex
        self.frame = frame

    def location(self) -> str:
        return join_location(
            ("frame", self.frame), ("part", None if self.part is None else f"'{self.part}'"), ("vertex", self.vertex)
        )

    def to_dict(self) -> dict:
        d = super().to_dict()
        d.update(part=self.part, vertex=self.vertex, frame=self.frame)
        return d


class TextureError(RenderInputError):
    """A texture image cannot be read (missing file, unreadable image)."""

    rule = "texture"


class ImageIOError(RenderInputError):
    """An image could not be written or read through OpenImageIO."""

    rule = "image-io"
