"""Start-code emulation (decision D9 of the spec notes).

A byte-aligned ``0x000001`` may occur in a face stream only as the prefix of a start code
the encoder wrote: the face object start code at byte 0, a plane start code after its
next_start_code() stuffing, and the code that ends the object. Anything else is an
*emulation*: a decoder or systems demultiplexer that scans for start codes (the usual way to
find planes and resynchronise) would cut the stream there. The arithmetic coder's stuffing
(a '1' after 22 zeros) does not prevent it by itself: a zero run can straddle the fixed-length
fields between blocks, and the end of one plane and the start of the next.

:func:`find_emulations` locates them (the checker reports each as an error with its byte
offset); the encoder (:func:`fbaconf.bitstreams.encoder.encode`) never writes one: where a
plane would complete an emulation it writes a plane start code before that plane (or the
one before it), whose stuffing ends the zero run and re-aligns the plane — a choice every
reading of the syntax allows (D1), in both coding modes. Our decoder decodes the bits as
written (it does not scan for start codes inside a plane), so a stream with an emulation still
decodes; it is nonetheless not conformant.
"""

from __future__ import annotations

from fbaconf.errors import FbaconfInputError

from .decoder import decode

PREFIX = b"\x00\x00\x01"


def legitimate_start_codes(data: bytes, result=None) -> tuple[set[int], int]:
    """(byte offsets of the start codes the syntax consumed, byte offset where the object
    ends). ``result`` is a DecodeResult of ``data`` (decoded here when not given); for a stream
    the decoder refuses, only the object start code is known and the scan covers everything."""
    legit = {0}
    if result is None:
        try:
            result = decode(data)
        except FbaconfInputError:
            return legit, len(data)
    for p in result.planes:
        if p.start_code:
            legit.add(p.bit_offset // 8 + 1)  # after next_start_code() stuffing: the next byte
    end = len(data)
    if result.end_code is not None:
        end = result.end_offset // 8 - 4
        legit.add(end)
    return legit, end


def find_emulations(data: bytes, result=None, *, start_codes=None) -> list[int]:
    """Byte offsets of every byte-aligned 0x000001 that is not a start code the syntax
    consumed, up to the end of the face object (trailing data after the end code is not
    part of it). ``start_codes``: the byte offsets where a writer put its start codes (the
    encoder knows them; the stream is then not decoded)."""
    if start_codes is not None:
        legit, end = set(start_codes), len(data)
    else:
        legit, end = legitimate_start_codes(data, result)
    out = []
    i = data.find(PREFIX, 0, end + 3)
    while i != -1 and i < end + 1:
        if i not in legit:
            out.append(i)
        i = data.find(PREFIX, i + 1, end + 3)
    return out
