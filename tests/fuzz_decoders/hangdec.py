"""Planted-bug decoder (fuzzer acceptance test): loops forever on a zero frame rate.

THE BUG: the frames per second are counted by stepping a clock in sixteenths of the frame
rate field; with frame_rate = seconds = 0 the step is 0 and the loop never ends."""

import os
import sys

sys.dont_write_bytecode = True
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _frontend import main  # noqa: E402


def on_header(h):
    if "frame_rate" in h:
        step = h["frame_rate"] * 16 + h["seconds"]
        t = n = 0
        while t < 16 * 16:  # BUG: step 0 never advances
            t += step
            n += 1


if __name__ == "__main__":
    sys.exit(main(on_header))
