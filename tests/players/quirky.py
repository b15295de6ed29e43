"""A .fap text player with five planted quirks, for the root-cause tests (fbaconf explain).

    python quirky.py INPUT.fap OUTPUT.fap

It reads the text with fbaconf's reader and writes what a player holds (docs/harness.md), but:
  1. integer rate: the header's frame rate is truncated to an integer (12.5 Hz -> 12 Hz);
  2. values scaled: head rotation FAPs 48-50 are read in other units (divided by 20);
  3. frames numbered from one: a file whose first frame is numbered 1 is shifted to start at 0;
  4. CRLF breaks values: with CRLF line ends the last value of each frame reads as 0;
  5. viseme_def dropped: the viseme_def and expression_def fields of FAP 1/2 read as 0.
An invalid file is rejected (exit 1)."""

import sys

import numpy as np

from fbaconf.bitstreams.fapio import save_faps
from fbaconf.bitstreams.faptext import read_fap_text
from fbaconf.bitstreams.frames import SET
from fbaconf.reference.pipeline import state_of


def main(src: str, out: str) -> int:
    raw = open(src, "rb").read().decode("utf-8", errors="replace")
    try:
        frames, _, _ = read_fap_text(raw, strict=False)
    except Exception as e:  # noqa: BLE001 - any reading error is a rejection
        print(f"quirky: {e}", file=sys.stderr)
        return 1
    fr = frames.copy()
    fr.frame_rate = float(int(fr.frame_rate))  # 1
    if fr.frame_rate <= 0:
        fr.frame_rate = 25.0
    v = fr.values.copy()
    v[:, 47:50] = v[:, 47:50] // 20  # 2
    if len(fr) and int(fr.frame_number[0]) == 1:  # 3
        fr.frame_number = fr.frame_number - 1
    if "\r\n" in raw:  # 4
        for k in range(len(fr)):
            sent = np.nonzero(frames.status[k, 2:] == SET)[0]
            if len(sent):
                v[k, 2 + sent[-1]] = 0
    fr.values = v
    h = fr.high.copy()
    h[:, [3, 9]] = 0  # 5
    fr.high = h
    fr.time_ms = fr.frame_number * 1000.0 / fr.frame_rate
    save_faps(state_of(fr), out)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2]))
