"""Typed errors of the animation stage.

Text-location problems in BT files raise :class:`fbaconf.errors.TextFormatError`
(line:column + node path). Problems found in a well-formed scene model (a FaceDefTable that
indexes a missing vertex, unsorted interval borders, a FIT graph with a cycle, degenerate
geometry ...) raise :class:`SceneError`, which names the node path and the rule broken.
"""
from __future__ import annotations

from fbaconf.errors import FbaconfInputError


class SceneError(FbaconfInputError):
    """A scene (face model, FDP, FIT, FaceDefTables) is semantically invalid."""

    rule = "scene"

    def __init__(self, message: str, *, rule: str, node_path: str | None = None, file: str | None = None) -> None:
        super().__init__(message, rule=rule, file=file)
        self.node_path = node_path

    def location(self) -> str:
        return self.node_path or ""

    def to_dict(self) -> dict:
        d = super().to_dict()
        d.update(node_path=self.node_path)
        return d
