"""The run record as strict JSON (schema harness/data/run-report.schema.json), written and read back."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from fbaconf._atomic import atomic_write_text
from fbaconf.harness.results import RunRecord

from .common import _NONFINITE


def jsonable(obj: Any) -> Any:
    """Plain JSON values: numpy scalars/arrays, paths and enums converted; non-finite floats as
    the strings ``Infinity``/``-Infinity``/``NaN`` (strict JSON has no such numbers)."""
    if obj is None or isinstance(obj, (bool, str, int)):
        return obj
    if isinstance(obj, float):
        if math.isfinite(obj):
            return obj
        return "NaN" if math.isnan(obj) else ("Infinity" if obj > 0 else "-Infinity")
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if hasattr(obj, "value") and isinstance(obj.value, str):  # Enum
        return obj.value
    if hasattr(obj, "tolist"):  # numpy array or scalar
        return jsonable(obj.tolist())
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    return str(obj)


def _restore_float(v: Any) -> Any:
    return _NONFINITE.get(v, v) if isinstance(v, str) else v


def _restore(doc: dict[str, Any]) -> dict[str, Any]:
    """Undo the non-finite spelling in the numeric fields (metrics, series, durations, speed)."""
    doc = json.loads(json.dumps(doc))  # private copy
    doc["duration_s"] = _restore_float(doc.get("duration_s", 0.0))
    for r in doc.get("results", []):
        r["duration_s"] = _restore_float(r.get("duration_s", 0.0))
        for st in r.get("stages", []):
            st["metrics"] = {k: _restore_float(v) for k, v in st.get("metrics", {}).items()}
            st["series"] = {k: [_restore_float(x) for x in v] for k, v in st.get("series", {}).items()}
    for s in doc.get("speed", []):
        for k in (
            "per_frame_s",
            "startup_s",
            "rate_fps",
            "required_fps",
            "fit_r2",
            "cpu_s",
            "wall_s",
            "stall_s",
            "others_share",
            "others_share_between",
            "load",
            "uncontended_fps",
        ):
            if k in s:
                s[k] = _restore_float(s[k])
    return doc


def report_json(record: RunRecord) -> dict[str, Any]:
    """The JSON document written by :func:`write_json` (``record.to_json()`` made strict JSON)."""
    doc: dict[str, Any] = jsonable(record.to_json())
    return doc


def write_json(record: RunRecord, path: str | os.PathLike[str]) -> Path:
    """Write ``record.to_json()`` as indented, strict, ASCII-only JSON (atomically); returns the path."""
    path = Path(path)
    text = json.dumps(report_json(record), indent=2, ensure_ascii=True, allow_nan=False)
    atomic_write_text(path, text + "\n")
    return path


def read_json(path: str | os.PathLike[str]) -> RunRecord:
    """Read a report written by :func:`write_json` back (non-finite metrics restored)."""
    with open(path, encoding="utf-8") as f:
        return RunRecord.from_json(_restore(json.load(f)))
