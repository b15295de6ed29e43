"""Shared plane-header front-end of the planted-bug Python decoders (stdlib only, run with -I -S).

Parses the first plane and every plane after a plane start code up to its skip chain and calls
``on_header(fields)``; exit 2 for what it cannot parse, 69 (payload not supported) otherwise."""

import sys


class Truncated(Exception):
    pass


def planes(data):
    nbits = len(data) * 8
    pos = [0]

    def rd(n):
        if pos[0] + n > nbits:
            raise Truncated()
        v = 0
        for _ in range(n):
            p = pos[0]
            v = (v << 1) | ((data[p >> 3] >> (7 - (p & 7))) & 1)
            pos[0] = p + 1
        return v

    def plane():
        h = {"intra": rd(1), "mask": rd(2)}
        if h["mask"] != 1:
            raise Truncated()
        if h["intra"]:
            if rd(1):
                h["frame_rate"], h["seconds"], h["offset"] = rd(8), rd(4), rd(1)
            if rd(1):
                h["hours"], h["minutes"], h["marker"], h["tc_seconds"] = rd(5), rd(6), rd(1), rd(6)
        skip = 0
        if rd(1):
            while True:
                v = rd(4)
                skip += v
                if v != 15:
                    break
        h["skip"] = skip
        return h

    if data[:4] != b"\x00\x00\x01\xba":
        raise Truncated()
    pos[0] = 32
    if data[4:9] != b"\x7f\x00\x00\x01\xbb":  # plane 0 directly after the object start code
        yield plane()
    i = data.find(b"\x00\x00\x01\xbb", 4)
    while i >= 0:
        pos[0] = (i + 4) * 8
        yield plane()
        i = data.find(b"\x00\x00\x01\xbb", i + 4)


def main(on_header):
    data = open(sys.argv[1], "rb").read()
    try:
        for h in planes(data):
            on_header(h)
    except Truncated:
        sys.stderr.write("bad plane header\n")
        return 2
    sys.stderr.write("headers parsed; payload decoding not supported\n")
    return 69
