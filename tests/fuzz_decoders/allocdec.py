"""Planted-bug decoder (fuzzer acceptance test): allocates from an unchecked time code.

THE BUG: a timeline buffer of 1 MiB per second of the first time code is allocated without
checking hours (0..31) and minutes (0..63): a time code of hours >= 1 asks for gigabytes."""

import os
import sys

sys.dont_write_bytecode = True
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _frontend import main  # noqa: E402

_keep = []


def on_header(h):
    if "hours" in h:
        seconds = h["hours"] * 3600 + h["minutes"] * 60 + h["tc_seconds"]
        _keep.append(bytearray((seconds + 1) << 20))  # BUG: unchecked range


if __name__ == "__main__":
    sys.exit(main(on_header))
