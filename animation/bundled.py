"""The bundled default head, loaded from its committed data files (``data/models/``).

The head is generated once by :mod:`fbaconf.generators.models` at a fixed precision and
committed; the animation stage only reads it: ``default_head_scene()`` (the BT scene with
its FaceDefTables) and ``default_head_feature_vertices()`` (which vertex of which part
carries each feature point — coinciding points such as 2.2/2.3, lips in contact, cannot be
told apart by position).
"""

from __future__ import annotations

import json
from functools import lru_cache
from importlib import resources

from fbaconf.scenes import bt

DATA = ("data", "models")


def _text(name: str) -> str:
    return resources.files("fbaconf.animation").joinpath(*DATA, name).read_text("utf-8")


@lru_cache(maxsize=1)
def default_head_scene() -> bt.Scene:
    """The default head (cached: do not modify the returned object)."""
    return bt.parse(_text("default-head.bt"), "default-head.bt")


@lru_cache(maxsize=1)
def default_head_feature_vertices() -> dict[str, tuple[str, int]]:
    """Feature point label -> (part name, vertex index) on the default head."""
    data = json.loads(_text("default-head.features.json"))
    return {k: (str(v[0]), int(v[1])) for k, v in data["feature_points"].items()}
