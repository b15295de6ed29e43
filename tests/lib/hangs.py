"""Telling a hang from slowness without timing anything: the work runs in a thread, and only
never finishing (within HANG_S, minutes above what the work takes on a loaded machine) fails.
A test states what ends the work (an exception, a verdict, a kill), never how fast it ends."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TypeVar

import pytest

T = TypeVar("T")

HANG_S = 300.0


def finishes(work: Callable[[], T], what: str) -> T:
    """``work()``'s result or exception; a test failure naming ``what`` if it is still running
    after HANG_S (it is left behind in a daemon thread)."""
    box: dict[str, object] = {}

    def run() -> None:
        try:
            box["value"] = work()
        except BaseException as e:  # noqa: BLE001 - handed back to the caller as it was raised
            box["error"] = e

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(HANG_S)
    if t.is_alive():
        pytest.fail(f"{what}: still running after {HANG_S:.0f} s — it hangs")
    if "error" in box:
        raise box["error"]  # type: ignore[misc]
    return box["value"]  # type: ignore[return-value]
