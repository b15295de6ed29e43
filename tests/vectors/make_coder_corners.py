"""Make the arithmetic-coder corner vectors: streams that reach each renormalisation tie
and every position of the 14-bit look-ahead window at a block end, for both D7 rules, written field
by field from the spec notes (../shared/spec/fap-bitstream.md §1.2–§1.4, §3, D3–D7, D9) —
independently of fbaconf: this script imports nothing from it. Its coder is the procedure of §3.2
and §3.3 written out again; its bit writer places every field by hand.

    python tests/vectors/make_coder_corners.py   # rewrites tests/vectors/c*.{bits,expect.toml} and
                                                 # conformance/data/coder/*.fba (take the suites lock)

Each ``.bits`` carries, in comments, every field as written and the derivation of its corner (the
encoder's interval per symbol and the renormalisation steps; for a look-ahead vector the window
bit by bit); its ``.expect.toml`` the decoding a conformant decoder must give, known by
construction (the values that were encoded) and checked here by decoding every block again with
the §3.3 decoder. The same bytes are the suite's ``coder-*`` cases (``conformance/data/coder/``).

* ``c01``–``c04`` — renormalisation ties (§3.3): at a renormalisation test the interval's high
  equals q2 (``high < q2`` false), its low equals q2 (``low >= q2`` true), its low equals q1 with
  high < q3 (the middle test true), its high equals q3 with low in [q1, q2) (the middle test
  false). Values found by a seeded search among streams that a decoder handling that one tie the
  other way decodes differently (checked here with the same decoder under the wrong comparison).
* ``c05``–``c32`` — a block end followed by a run of 22 zeros that completes at look-ahead
  position p = 1..14 of the block's decoder: the bit after the 22nd zero is a '1' of the next
  field (``rewind``: the decoder removes it as a stuffing bit among its look-ahead bits and must
  hand it back at the block end, D7) or a '0' (``error``: a stuffing violation inside the
  look-ahead, which D7 says is no error). p = 2..14: a predicted plane's expression block ends
  with 22 − p zeros and init_face, expression_def and the low-level block continue the run; its
  last bits are found by search, after enough predicted planes (diffs ±a, ±b alternating, so the
  values come back) that its models are skewed where that is needed (§3.2). p = 1: an intra
  low-level block ends with 21 zeros and the next field is next_start_code() (rewind: '0' then a
  '1') or a predicted plane header (error: is_intra '0', then the mask's first bit '0').
  Every stream has that one stuffing position in a look-ahead and no byte-aligned 0x000001 other
  than its start codes (D9).
"""

from __future__ import annotations

import itertools
import random
import sys
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
DATA = ROOT / "conformance" / "data" / "coder"

TOP, Q1, Q2, Q3 = 65535, 16384, 32768, 49152
MAX_FREQUENCY = 16383
ZERO_RUN = 22
LOOKAHEAD = 14
PROVENANCE = "made by tests/vectors/make_coder_corners.py: fields by hand, blocks by §3.3"

# spec notes §2: FAP number -> (name, QP, default intra range, default predicted range); D4 rounds
# ranges to multiples of 60, which these already are
FAPS = {
    3: ("open_jaw", 4, 1080, 360),
    4: ("lower_t_midlip", 2, 600, 180),
    5: ("raise_b_midlip", 2, 1860, 600),
    10: ("raise_b_lip_lm", 2, 1860, 600),
    11: ("raise_b_lip_rm", 2, 1860, 600),
    52: ("raise_b_midlip_o", 2, 1860, 600),
}
GROUPS = [(1, 2), (3, 18), (19, 30), (31, 38), (39, 42), (43, 47), (48, 50), (51, 60), (61, 64), (65, 68)]
SEL_N, INT_N = 7, 64  # intra expression_select 0..6, intensity 0..63 at fap_quant 1 (D5)
PSEL, PINT = 6, 63  # predicted differences -6..6 and -63..63


# ------------------------------------------------------------------------------ models (§3.2)
class Uniform(list):
    """A model whose frequencies are all 1 and stay so (an intra model): c[k] = n - k."""

    def __init__(self, n: int) -> None:
        super().__init__([1] * n)
        self.c = list(range(n, -1, -1))


def cum(freq: list[int]) -> list[int]:
    """The descending cumulative table c (c[0] = total, c[n] = 0)."""
    if isinstance(freq, Uniform):
        return freq.c
    c = [0] * (len(freq) + 1)
    for k in range(len(freq) - 1, -1, -1):
        c[k] = c[k + 1] + freq[k]
    return c


def adapt(freq: list[int], s: int) -> None:
    """A predicted model after symbol s: halve with round-up at the total 16383, then f[s] + 1."""
    if sum(freq) == MAX_FREQUENCY:
        freq[:] = [(f + 1) // 2 for f in freq]
    freq[s] += 1


# ------------------------------------------------------------------------------ the coder (§3.3)
class Encoder:
    """Emits a bit per q2 renormalisation, defers bits for the middle case and writes a stuffing
    '1' after 22 consecutive '0's of the block, eagerly (flush bits included)."""

    def __init__(self) -> None:
        self.low, self.high, self.pending, self.zeros = 0, TOP, 0, 0
        self.out: list[str] = []  # '0'/'1', and 'S' for a stuffing '1'
        self.trace: list[str] = []
        self.ties: list[tuple[str, int]] = []  # (tie, index of the symbol) at a renormalisation test

    def _emit(self, b: int) -> None:
        self.out.append(str(b))
        self.zeros = 0 if b else self.zeros + 1
        if self.zeros == ZERO_RUN:
            self.out.append("S")
            self.zeros = 0

    def _bit_plus_follow(self, b: int) -> None:
        self._emit(b)
        for _ in range(self.pending):
            self._emit(1 - b)
        self.pending = 0

    def encode(self, freq: list[int], s: int, what: str) -> None:
        c = cum(freq)
        length = self.high - self.low + 1
        high = self.low - 1 + length * c[s] // c[0]
        low = self.low + length * c[s + 1] // c[0]
        before = f"[{low}, {high}]"
        steps = []
        k = len(self.trace)
        while True:
            if high == Q2:
                self.ties.append(("high-q2", k))
            if high < Q2:
                steps.append("lower: 0")
                self._bit_plus_follow(0)
            else:
                if low == Q2:
                    self.ties.append(("low-q2", k))
                if low >= Q2:
                    steps.append("upper: 1")
                    self._bit_plus_follow(1)
                    low, high = low - Q2, high - Q2
                else:
                    if low == Q1 and high < Q3:
                        self.ties.append(("low-q1", k))
                    if low >= Q1 and high == Q3:
                        self.ties.append(("high-q3", k))
                    if low >= Q1 and high < Q3:
                        steps.append("middle")
                        self.pending += 1
                        low, high = low - Q1, high - Q1
                    else:
                        break
            low, high = 2 * low, 2 * high + 1
        shown = ", ".join(steps) if len(steps) < 6 else f"{len(steps)} shifts ({', '.join(sorted(set(steps)))})"
        self.trace.append(
            f"{what}: index {s} of {len(freq)} (c[{s}] = {c[s]}, c[{s + 1}] = {c[s + 1]}, "
            f"c[0] = {c[0]}): {before} -> {shown or 'no shift'} -> [{low}, {high}], "
            f"pending {self.pending}"
        )
        self.low, self.high = low, high

    def flush(self) -> str:
        self.pending += 1
        b = 0 if self.low < Q1 else 1
        self.trace.append(f"flush: low {self.low} {'<' if b == 0 else '>='} q1: {b} and {self.pending} pending {1 - b}")
        self._bit_plus_follow(b)
        return "".join(self.out)


def decode_block(bits: str, start: int, models: list[list[int]], wrong: str = "") -> tuple:
    """Decode one block of len(models) symbols at ``bits[start:]`` (§3.3, D7). ``wrong``: a tie the
    decoder handles the other way. Returns (symbols, block length, stuffing counts, bad stuffing
    counts, bits read); raises ValueError for an impossible state or a stuffing violation in the block."""
    pos, count, zeros = start, 0, 0
    stuffing, bad = [], []

    def bit() -> int:
        nonlocal pos, count, zeros
        b = int(bits[pos]) if pos < len(bits) else 0
        pos += 1
        count += 1
        zeros = 0 if b else zeros + 1
        if zeros == ZERO_RUN:
            if (int(bits[pos]) if pos < len(bits) else 0) != 1:
                bad.append(count)
            pos += 1
            stuffing.append(count)
            zeros = 0
        return b

    low, high, value = 0, TOP, 0
    for _ in range(16):
        value = 2 * value + bit()
    out = []
    for freq in models:
        c = cum(freq)
        length = high - low + 1
        target = ((value - low + 1) * c[0] - 1) // length
        if not 0 <= target < c[0]:
            raise ValueError("state out of range")
        if isinstance(freq, Uniform):
            s = max(1, len(freq) - target) - 1
        else:
            s = next(k for k in range(1, len(freq) + 1) if c[k] <= target) - 1
        high = low - 1 + length * c[s] // c[0]
        low = low + length * c[s + 1] // c[0]
        while True:
            if (high <= Q2) if wrong == "high-q2" else (high < Q2):
                pass
            elif (low > Q2) if wrong == "low-q2" else (low >= Q2):
                value, low, high = value - Q2, low - Q2, high - Q2
            elif ((low > Q1) if wrong == "low-q1" else (low >= Q1)) and (
                (high <= Q3) if wrong == "high-q3" else (high < Q3)
            ):
                value, low, high = value - Q1, low - Q1, high - Q1
            else:
                break
            low, high = 2 * low, 2 * high + 1
            value = 2 * value + bit()
        out.append(s)
    used = count - LOOKAHEAD
    if any(c_ <= used for c_ in bad):
        raise ValueError("stuffing violation inside the block")
    return out, used + sum(1 for c_ in stuffing if c_ <= used), stuffing, bad, count


def trailing_zeros(bits: str) -> int:
    return len(bits) - len(bits.rstrip("0"))


# ------------------------------------------------------------------------------ the bit writer
@dataclass
class Block:
    start: int
    models: list[list[int]]  # the frequency table each symbol was coded with (copies)
    symbols: list[int]
    length: int


@dataclass
class Stream:
    """Stream bits with the .bits text of each field, and the arithmetic blocks written."""

    bits: list[str] = field(default_factory=list)
    lines: list[str] = field(default_factory=list)
    blocks: list[Block] = field(default_factory=list)

    def put(self, text: str, note: str = "") -> None:
        self.bits += list(text)
        self.lines.append(f"{text:<24s} # {note}" if note else text)

    def uint(self, value: int, width: int, note: str) -> None:
        self.put(format(value, f"0{width}b"), note)

    def hexbytes(self, hexstr: str, note: str) -> None:
        self.bits += list("".join(f"{b:08b}" for b in bytes.fromhex(hexstr)))
        self.lines.append(f"x:{hexstr:<22s} # {note}")

    def comment(self, text: str) -> None:
        self.lines += [f"# {ln}".rstrip() for ln in text.splitlines()]

    def block(
        self, items: list[tuple[list[int], int, str]], note: str, trace: bool = True, adaptive: bool = False
    ) -> str:
        """An arithmetic block of (frequency table, symbol index, what) items; predicted (adaptive)
        tables are updated after each symbol."""
        enc = Encoder()
        models = []
        for freq, s, what in items:
            models.append(freq if isinstance(freq, Uniform) else list(freq))
            enc.encode(freq, s, what)
            if adaptive:
                adapt(freq, s)
        raw = enc.flush()
        text = raw.replace("S", "1")
        if trace:
            self.comment("\n".join(enc.trace))
        self.blocks.append(Block(len(self.bits), models, [s for _, s, _ in items], len(text)))
        self.bits += list(text)
        shown = raw.replace("S", " 1 ").strip() if "S" in raw else raw
        spaced = "; a spaced 1 is a stuffing bit" if "S" in raw else ""
        self.lines.append(f"{shown}   # {note} ({len(text)} bits{spaced})")
        self.enc = enc
        return text

    def joined(self, since: int, note: str) -> None:
        """The .bits lines written since line ``since`` as one line (the fields of a plane)."""
        text = " ".join(ln.split("#", 1)[0].strip() for ln in self.lines[since:] if not ln.startswith("#"))
        self.lines[since:] = [f"{text}   # {note}"]

    def stuff(self) -> None:
        n = 8 if len(self.bits) % 8 == 0 else (-len(self.bits)) % 8
        self.bits += list("0" + "1" * (n - 1))
        self.lines.append("stuff                    # next_start_code(): '0' then '1's to the byte boundary")

    def data(self) -> bytes:
        assert len(self.bits) % 8 == 0
        s = "".join(self.bits)
        return bytes(int(s[i : i + 8], 2) for i in range(0, len(s), 8))

    def check(self) -> list[tuple[int, int, int]]:
        """Decode every block again (§3.3): the symbols and lengths written. Returns the look-ahead
        stuffing positions: (block index, window position, the bit after the 22nd zero)."""
        s = "".join(self.bits)
        events = []
        for i, b in enumerate(self.blocks):
            syms, length, stuffing, bad, count = decode_block(s, b.start, b.models)
            assert syms == b.symbols and length == b.length, (i, syms, b.symbols, length, b.length)
            used = count - LOOKAHEAD
            events += [(i, c - used, 0 if c in bad else 1) for c in stuffing if c > used]
        return events


def emulations(data: bytes) -> list[int]:
    """Byte offsets of a 0x000001 that does not start one of the written start codes (D9)."""
    return [
        i
        for i in range(len(data) - 2)
        if data[i : i + 3] == b"\x00\x00\x01" and (i + 3 >= len(data) or data[i + 3] not in (0xBA, 0xB1))
    ]


def intra_header(w: Stream, masked: set[int], p_lists: dict[int, int] | None = None) -> None:
    """An intra plane's header at 25 Hz, fap_quant 1; with ``p_lists`` (FAP -> v) new predicted
    max and min lists (max +v x 60, min -v x 60, §1.4)."""
    w.put("1", "is_intra")
    w.put("01", "fba_object_mask: FAPs")
    w.put("1", "is_frame_rate")
    w.uint(25, 8, "frame_rate 25")
    w.uint(0, 4, "seconds 0")
    w.put("0", "frequency_offset 0")
    w.put("0", "is_time_code 0")
    w.put("0", "skip_frames 0")
    w.uint(1, 5, "fap_quant 1")
    for g, (a, b) in enumerate(GROUPS, 1):
        faps = [f for f in range(a, b + 1) if f in masked]
        if faps:
            w.put(
                "1" + "01" + "".join("1" if f in masked else "0" for f in range(a, b + 1)),
                f"group {g}: marker, type 01, mask: FAP {', '.join(map(str, faps))}",
            )
        else:
            w.put("100", f"group {g}: marker, type 00")
    w.put("0", "suggested_gender")
    w.put("0", "coding_type 0 (arithmetic)")
    if not p_lists:
        w.put("0000", "no new min/max lists: the default ranges (D4)")
        return
    w.put("0011", "is_i_new_max 0, is_i_new_min 0, is_p_new_max 1, is_p_new_min 1")
    for which in ("p_max", "p_min"):
        w.comment(f"{which} list (§1.4): a marker before every 4th FAP of each group, a 5-bit v after a masked FAP")
        for a, b in GROUPS[1:]:
            for j, f in enumerate(range(a, b + 1)):
                if j % 4 == 0:
                    w.put("1", "marker")
                if f in masked:
                    w.uint(
                        p_lists[f],
                        5,
                        f"FAP {f}: v = {p_lists[f]} ({'+' if which == 'p_max' else '-'}{60 * p_lists[f]})",
                    )


def predicted_header(w: Stream, k: int) -> None:
    w.put("0 01 0".replace(" ", ""), f"plane {k}: is_intra 0, fba_object_mask 01, skip_frames 0")


def low_values(faps: list[int], symbols: dict[int, int]) -> dict[int, int]:
    return {f: symbols[f] * FAPS[f][1] for f in faps}


# ------------------------------------------------------------------------------ ties
TIE_FAPS = [5, 10, 11, 52]  # intra alphabets of 3721 symbols: values -1860..1860 at fap_quant 1
TIES = {
    "high-q2": "high = q2 = 32768: the lower-half test high < q2 is false",
    "low-q2": "low = q2 = 32768: the upper-half test low >= q2 is true",
    "low-q1": "low = q1 = 16384 with high < q3: the middle test low >= q1 is true",
    "high-q3": "high = q3 = 49152 with q1 <= low < q2: the middle test high < q3 is false",
}
UNIFORM_I = Uniform(3721)


def _diverges(syms: list[int], tie: str) -> bool:
    enc = Encoder()
    for s in syms:
        enc.encode(UNIFORM_I, s, "")
    if tie not in {t for t, _ in enc.ties}:
        return False
    bits = enc.flush().replace("S", "1") + "0" * 40
    ref = decode_block(bits, 0, [UNIFORM_I] * len(syms))
    try:
        other = decode_block(bits, 0, [UNIFORM_I] * len(syms), wrong=tie)
    except ValueError:
        return True
    return other[0] != ref[0] or other[1] != ref[1]


def find_tie(tie: str, rng: random.Random) -> list[int]:
    """Intra symbol indices of the four FAPs whose block reaches ``tie`` and that a decoder
    handling the tie the other way decodes differently (other symbols or another length)."""
    for _ in range(3_000_000):
        syms = [rng.randrange(3721) for _ in TIE_FAPS]
        enc = Encoder()
        for s in syms:
            enc.encode(UNIFORM_I, s, "")
        at = [k for t, k in enc.ties if t == tie]
        if not at or at[0] == len(syms) - 1:
            continue
        # after the tie, symbols at one end of their interval: the coded point sits at the edge of the
        # tie symbol's interval, where a decoder one shift out of step rounds the boundary differently
        for edge in (None, 3720, 0):
            cand = syms if edge is None else syms[: at[0] + 1] + [edge] * (len(syms) - at[0] - 1)
            enc = Encoder()
            for s in cand:
                enc.encode(UNIFORM_I, s, "")
            if tie not in {t for t, _ in enc.ties}:
                continue
            bits = enc.flush().replace("S", "1") + "0" * 40
            ref = decode_block(bits, 0, [UNIFORM_I] * 4)
            try:
                other = decode_block(bits, 0, [UNIFORM_I] * 4, wrong=tie)
            except ValueError:
                return cand
            if other[0] != ref[0] or other[1] != ref[1]:
                return cand
    raise SystemExit(f"no stream found for the tie {tie}")


def tie_stream(tie: str, syms: list[int]) -> tuple[Stream, list[dict]]:
    w = Stream()
    w.comment(
        f"Renormalisation tie {tie} (§3.3): {TIES[tie]}.\n"
        f"One intra plane: FAPs {', '.join(map(str, TIE_FAPS))} at fap_quant 1, default ranges -1860..1860: "
        "3721 symbols each,\nindex k = value + 1860 (c[k] = 3721 - k: index 0, the value -1860, is the top of "
        "the interval)."
    )
    w.hexbytes("000001BA", "face_object_start_code")
    intra_header(w, set(TIE_FAPS))
    w.block(
        [(UNIFORM_I, s, f"FAP {f} value {s - 1860}") for f, s in zip(TIE_FAPS, syms)],
        f"FAP3..68 block: FAPs {', '.join(map(str, TIE_FAPS))}",
    )
    ((_, k),) = [t for t in w.enc.ties if t[0] == tie][:1]
    w.comment(
        f"The tie: at a renormalisation test after symbol {k + 1} (FAP {TIE_FAPS[k]}). A decoder that takes "
        "it the other way\nshifts (or stops) where the encoder did not: it decodes other symbols."
    )
    w.stuff()
    w.hexbytes("000001B1", "visual_object_sequence_end_code")
    values = {f: (s - 1860) * FAPS[f][1] for f, s in zip(TIE_FAPS, syms)}
    return w, [{"frame_number": 0, "time_ms": 0.0, "is_intra": True, "fap_quant": 1, "set": values}]


# high = q3 happens only right after narrowing (after a shift high is odd) and needs a symbol of
# probability above 1/4 ending exactly at q3: a predicted model made that skewed by training. Found
# by a seeded search over training lengths and the symbols before the tie (the high-q3 vector).
Q3_FAPS = [3, 4, 5, 10]
Q3_LISTS = {3: 6, 4: 3, 5: 1, 10: 10}  # predicted ranges +-360, +-180, +-60, +-600: FAP 5 has 121 symbols
Q3_TRAINING = 170  # planes with every difference 0
Q3_LAST = {3: -24, 4: 0, 5: 0, 10: -600}  # the tie is FAP 5's symbol; FAP 10's puts the point at an edge


def tie_q3_stream() -> tuple[Stream, list[dict]]:
    w = Stream()
    w.comment(
        f"Renormalisation tie high-q3 (§3.3): {TIES['high-q3']}.\nPlane 0 (intra): FAPs 3, 4, 5, 10 at "
        "fap_quant 1, value 0, new predicted ranges +-360, +-180, +-60, +-600.\n"
        f"Planes 1..{Q3_TRAINING}: predicted, every difference 0: each predicted model's symbol 0 gets a "
        f"frequency of {Q3_TRAINING + 1} (§3.2).\nPlane {Q3_TRAINING + 1}: differences "
        + ", ".join(f"FAP {f} {d:+d}" for f, d in Q3_LAST.items())
        + ": FAP 5's difference 0 (probability "
        f"{Q3_TRAINING + 1}/{121 + Q3_TRAINING}) narrows the interval\nto one that ends exactly at q3 with its "
        "low between q1 and q2. A decoder that takes the middle step there (high <= q3)\nis one shift "
        "ahead with its interval doubled, and rounds FAP 10's boundary the other way."
    )
    w.hexbytes("000001BA", "face_object_start_code")
    intra_header(w, set(Q3_FAPS), Q3_LISTS)
    w.block(
        [(Uniform(2 * FAPS[f][2] + 1), FAPS[f][2], f"FAP {f} value 0") for f in Q3_FAPS],
        "plane 0: FAP3..68 block (intra: index = value + range)",
        trace=False,
    )
    models = {f: [1] * (120 * Q3_LISTS[f] + 1) for f in Q3_FAPS}
    frames = [{"frame_number": 0, "time_ms": 0.0, "is_intra": True, "fap_quant": 1, "set": dict.fromkeys(Q3_FAPS, 0)}]
    for k in range(1, Q3_TRAINING + 1):
        since = len(w.lines)
        predicted_header(w, k)
        w.block(
            [(models[f], 60 * Q3_LISTS[f], "") for f in Q3_FAPS],
            f"plane {k}: FAP3..68 block, differences 0",
            trace=False,
            adaptive=True,
        )
        w.joined(since, f"plane {k}: is_intra 0, mask 01, skip 0; FAP3..68 block, every difference 0")
        frames.append(
            {
                "frame_number": k,
                "time_ms": 40.0 * k,
                "is_intra": False,
                "fap_quant": 1,
                "set": dict.fromkeys(Q3_FAPS, 0),
            }
        )
    k = Q3_TRAINING + 1
    predicted_header(w, k)
    w.block(
        [(models[f], 60 * Q3_LISTS[f] + d, f"FAP {f} difference {d:+d}") for f, d in Q3_LAST.items()],
        f"plane {k}: FAP3..68 block",
        adaptive=True,
    )
    ((_, at),) = [t for t in w.enc.ties if t[0] == "high-q3"][:1]
    w.comment(f"The tie: at the renormalisation test after symbol {at + 1} (FAP {Q3_FAPS[at]}).")
    w.stuff()
    w.hexbytes("000001B1", "visual_object_sequence_end_code")
    frames.append(
        {
            "frame_number": k,
            "time_ms": 40.0 * k,
            "is_intra": False,
            "fap_quant": 1,
            "set": {f: d * FAPS[f][1] for f, d in Q3_LAST.items()},
        }
    )
    return w, frames


def q3_diverges() -> bool:
    """The block of the last plane, decoded with the middle test high <= q3, gives other symbols."""
    w, _ = tie_q3_stream()
    b = w.blocks[-1]
    bits = "".join(w.bits)
    ref = decode_block(bits, b.start, b.models)
    try:
        other = decode_block(bits, b.start, b.models, wrong="high-q3")
    except ValueError:
        return True
    return other[0] != ref[0] or other[1] != ref[1]


# ------------------------------------------------------------------------------ look-ahead, p = 2..14
E0 = (3, 32, 3, 32)  # the intra plane's expression fields: mid-range, so every difference below stays valid


@dataclass
class Plan:
    position: int
    rule: str  # "rewind" or "error"
    training: tuple[int, int, int]  # N planes, select difference a, intensity difference b (alternating signs)
    e1: tuple[int, int, int, int]  # the expression differences of the last plane
    raw: tuple[int, int] = (0, 0)  # its init_face, expression_def
    l1: dict[int, int] = field(default_factory=dict)  # its FAP 3 and FAP 5 differences


# (N, a, b) and the last plane's expression differences whose block ends with 22 - p zeros: found
# by search (find_expression below; seeded, kept here so the vectors are remade without it)
EXPRESSION_ENDS: dict[int, tuple[tuple[int, int, int], tuple[int, int, int, int]]] = {
    2: ((216, 3, 8), (2, -6, 0, -1)),
    3: ((216, 1, 8), (2, -6, 0, -1)),
    4: ((216, 2, 8), (1, -6, 0, -1)),
    5: ((216, 1, 8), (-2, -6, 0, -1)),
    6: ((0, 1, 8), (-1, -2, 0, -8)),
    7: ((100, 3, 8), (3, 8, -1, -4)),
    8: ((20, 1, 8), (3, 3, -1, -4)),
    9: ((40, 3, 8), (0, 8, -2, 1)),
    10: ((0, 1, 8), (0, -8, -1, 2)),
    11: ((0, 1, 8), (2, 0, -1, -3)),
    12: ((0, 1, 8), (-3, 5, -1, 2)),
    13: ((0, 1, 8), (-2, -2, 3, 8)),
    14: ((0, 1, 8), (-3, -8, -1, 2)),
}


def _p_tables(training: tuple[int, int, int]) -> tuple[list[list[int]], dict[int, list[int]]]:
    """The predicted models after the training planes: expression (4) and low-level (FAPs 3, 5)."""
    n, a, b = training
    expr = []
    for half, d in ((PSEL, a), (PINT, b), (PSEL, a), (PINT, b)):
        f = [1] * (2 * half + 1)
        f[half + d] += n // 2
        f[half - d] += n // 2
        expr.append(f)
    low = {}
    for fap in (3, 5):
        f = [1] * (2 * FAPS[fap][3] + 1)
        f[FAPS[fap][3]] += n  # difference 0 in every training plane
        low[fap] = f
    return expr, low


def _expr_zeros(training, e1) -> int:
    expr, _ = _p_tables(training)
    enc = Encoder()
    for f, half, d in zip(expr, (PSEL, PINT, PSEL, PINT), e1):
        enc.encode(f, half + d, "")
    return trailing_zeros(enc.flush().replace("S", "1"))


def find_expression(p: int) -> tuple[tuple[int, int, int], tuple[int, int, int, int]]:
    want = ZERO_RUN - p
    for n in range(0, 402, 6):
        for a in (1, 2, 3):
            for b in (8, 16, 31):
                for e1 in itertools.product(range(-3, 4), range(-8, 9), range(-3, 4), range(-8, 9)):
                    if _expr_zeros((n, a, b), e1) == want:
                        return (n, a, b), e1
    raise SystemExit(f"no expression block ends with {want} zeros")


def lookahead_stream(pl: Plan) -> tuple[Stream, list[dict]]:
    n, a, b = pl.training
    w = Stream()
    slot = (
        "1 of the next field: the decoder removes it as a stuffing bit and must hand it back at the block end"
        if pl.rule == "rewind"
        else "0 of the next field: a stuffing violation inside the look-ahead, not an error (D7)"
    )
    w.comment(
        f"Block end with a stuffing position at look-ahead position {pl.position} ({pl.rule} rule, D7).\n"
        f"Plane 0 (intra): FAP 2 (expression) and FAPs 3, 5 at fap_quant 1. Planes 1..{n}: predicted, "
        f"expression differences\n+-{a}, +-{b}, +-{a}, +-{b} alternating (the values come back), FAPs 3 "
        f"and 5 unchanged: they skew the predicted models (§3.2).\nPlane {n + 1} (predicted): its expression "
        f"block ends with {ZERO_RUN - pl.position} zeros; init_face, expression_def and the low-level\nblock's "
        f"first bits continue the run, whose 22nd zero is look-ahead bit {pl.position} of the expression "
        f"block's decoder;\nthe bit after it is a {slot}."
    )
    w.hexbytes("000001BA", "face_object_start_code")
    intra_header(w, {2, 3, 5})
    w.block(
        [(Uniform(n), v, f"{name} {v}") for n, v, name in zip((SEL_N, INT_N, SEL_N, INT_N), E0, HIGH2)],
        "plane 0: expression block (intra, index = value)",
    )
    w.put("0", "init_face 0")
    w.put("0", "expression_def 0")
    w.block(
        [(Uniform(2161), 1080, "FAP 3 value 0"), (UNIFORM_I, 1860, "FAP 5 value 0")],
        "plane 0: FAP3..68 block (intra: index = value + range)",
    )
    frames = [
        {
            "frame_number": 0,
            "time_ms": 0.0,
            "is_intra": True,
            "fap_quant": 1,
            "fap2": "SET",
            "set": {3: 0, 5: 0},
            "high": dict(zip(HIGH2, (*E0, 0, 0))),
        }
    ]
    expr = [[1] * (2 * h + 1) for h in (PSEL, PINT, PSEL, PINT)]
    low = {3: [1] * 721, 5: [1] * 1201}
    for k in range(1, n + 1):
        sign = 1 if k % 2 else -1
        d = (sign * a, sign * b, sign * a, sign * b)
        since = len(w.lines)
        predicted_header(w, k)
        w.block(
            [(m, h + x, "") for m, h, x in zip(expr, (PSEL, PINT, PSEL, PINT), d)],
            f"plane {k}: expression block, differences {', '.join(f'{x:+d}' for x in d)}",
            trace=False,
            adaptive=True,
        )
        w.put("00", "init_face 0, expression_def 0")
        w.block(
            [(low[3], 360, ""), (low[5], 600, "")],
            f"plane {k}: FAP3..68 block, differences 0, 0",
            trace=False,
            adaptive=True,
        )
        w.joined(
            since,
            f"plane {k}: is_intra 0, mask 01, skip 0; expression block (differences "
            f"{', '.join(f'{x:+d}' for x in d)}); init_face 0, expression_def 0; FAP3..68 block (0, 0)",
        )
        e = [E0[i] + (d[i] if k % 2 else 0) for i in range(4)]
        frames.append(
            {
                "frame_number": k,
                "time_ms": 40.0 * k,
                "is_intra": False,
                "fap_quant": 1,
                "fap2": "SET",
                "set": {3: 0, 5: 0},
                "high": dict(zip(HIGH2, (*e, 0, 0))),
            }
        )
    k = n + 1
    predicted_header(w, k)
    w.comment(
        "the predicted models now: expression "
        + "; ".join(
            f"{name} frequencies {_freq_text(m)}"
            for name, m in zip(("select1", "intensity1", "select2", "intensity2"), expr)
        )
        + f"; FAP 3 difference 0: {low[3][360]}, "
        f"FAP 5 difference 0: {low[5][600]} (others 1)"
    )
    ebits = w.block(
        [
            (m, h + x, f"{name} difference {x:+d}")
            for m, h, x, name in zip(
                expr, (PSEL, PINT, PSEL, PINT), pl.e1, ("select1", "intensity1", "select2", "intensity2")
            )
        ],
        f"plane {k}: expression block",
        adaptive=True,
    )
    w.put(str(pl.raw[0]), f"init_face {pl.raw[0]}")
    w.put(str(pl.raw[1]), f"expression_def {pl.raw[1]}")
    lbits = w.block(
        [(low[f], FAPS[f][3] + pl.l1[f], f"FAP {f} difference {pl.l1[f]:+d}") for f in (3, 5)],
        f"plane {k}: FAP3..68 block",
        adaptive=True,
    )
    window = f"{pl.raw[0]}{pl.raw[1]}{lbits}"[: LOOKAHEAD + 1]
    how = ", removes it" if pl.rule == "rewind" else " (a violation it must not report)"
    w.comment(
        f"Plane {k}'s expression block ends with {trailing_zeros(ebits)} zeros. Its decoder reads on into "
        f"init_face, expression_def\nand the low-level block: {' '.join(window)}. The run of 22 zeros completes "
        f"at look-ahead bit {pl.position};\nthe decoder reads the next bit ({window[pl.position]}) as the "
        f"stuffing bit{how}; at the block end it hands back its 14 look-ahead\narithmetic bits and the "
        "stuffing bit among them: init_face is read right after the block."
    )
    w.stuff()
    w.hexbytes("000001B1", "visual_object_sequence_end_code")
    e = [E0[i] + pl.e1[i] for i in range(4)]
    frames.append(
        {
            "frame_number": k,
            "time_ms": 40.0 * k,
            "is_intra": False,
            "fap_quant": 1,
            "fap2": "SET",
            "set": low_values([3, 5], pl.l1),
            "high": dict(zip(HIGH2, (*e, *pl.raw))),
        }
    )
    return w, frames


HIGH2 = (
    "expression_select1",
    "expression_intensity1",
    "expression_select2",
    "expression_intensity2",
    "init_face",
    "expression_def",
)


def _freq_text(m: list[int]) -> str:
    half = len(m) // 2
    big = {i - half: f for i, f in enumerate(m) if f > 1}
    return "1 except " + ", ".join(f"{d:+d}: {f}" for d, f in sorted(big.items())) if big else "all 1"


def find_low(pl: Plan, rng: random.Random) -> Plan:
    """init_face, expression_def and FAP 3/5 differences that continue the run to the position and put
    the wanted bit after it, with no other look-ahead stuffing and no emulation."""
    want = "1" if pl.rule == "rewind" else "0"
    _, low = _p_tables(pl.training)
    for _ in range(400_000):
        l1 = (
            {3: rng.randint(250, 360), 5: rng.randint(400, 600)}
            if rng.random() < 0.8
            else {3: rng.randint(-360, 360), 5: rng.randint(-600, 600)}
        )
        enc = Encoder()
        for f in (3, 5):
            enc.encode(low[f], FAPS[f][3] + l1[f], "")
        lbits = enc.flush().replace("S", "1")
        for raw in ((0, 0), (0, 1), (1, 0), (1, 1)):
            tail = f"{raw[0]}{raw[1]}{lbits}"
            if tail[: pl.position] != "0" * pl.position or tail[pl.position] != want:
                continue
            cand = Plan(pl.position, pl.rule, pl.training, pl.e1, raw, l1)
            w, _ = lookahead_stream(cand)
            if not emulations(w.data()) and w.check() == [(len(w.blocks) - 2, pl.position, int(want))]:
                return cand
    raise SystemExit(f"no low-level block for position {pl.position} ({pl.rule})")


# ------------------------------------------------------------------------------ look-ahead, p = 1
LOW_A = [5, 10, 11, 52]


def low_end_stream(rule: str, syms: list[int], nxt: list[int]) -> tuple[Stream, list[dict]]:
    w = Stream()
    follow = (
        "next_start_code(): its '0' is the 22nd zero and its first '1' the bit after it, which the decoder "
        "removes\nas a stuffing bit and must hand back (rewind rule)"
        if rule == "rewind"
        else "plane 1's header: is_intra '0' is the 22nd zero and the mask's first bit '0' the bit after it: a\n"
        "stuffing violation inside the look-ahead, not an error (D7)"
    )
    w.comment(
        f"Block end with a stuffing position at look-ahead position 1 ({rule} rule, D7).\nPlane 0 (intra): FAPs "
        f"{', '.join(map(str, LOW_A))} at fap_quant 1; its low-level block ends with 21 zeros and what follows "
        f"is {follow}."
    )
    w.hexbytes("000001BA", "face_object_start_code")
    intra_header(w, set(LOW_A))
    bits = w.block(
        [(UNIFORM_I, s, f"FAP {f} value {s - 1860}") for f, s in zip(LOW_A, syms)], "plane 0: FAP3..68 block"
    )
    w.comment(f"The block ends with {trailing_zeros(bits)} zeros.")
    frames = [
        {
            "frame_number": 0,
            "time_ms": 0.0,
            "is_intra": True,
            "fap_quant": 1,
            "set": {f: (s - 1860) * FAPS[f][1] for f, s in zip(LOW_A, syms)},
        }
    ]
    if rule == "error":
        predicted_header(w, 1)
        models = {f: [1] * 1201 for f in LOW_A}
        w.block(
            [(models[f], d + 600, f"FAP {f} difference {d:+d}") for f, d in zip(LOW_A, nxt)],
            "plane 1: FAP3..68 block (uniform predicted models, index = difference + 600)",
            adaptive=True,
        )
        frames.append(
            {
                "frame_number": 1,
                "time_ms": 40.0,
                "is_intra": False,
                "fap_quant": 1,
                "set": {f: (s - 1860 + d) * FAPS[f][1] for f, s, d in zip(LOW_A, syms, nxt)},
            }
        )
    w.stuff()
    w.hexbytes("000001B1", "visual_object_sequence_end_code")
    return w, frames


def find_low_end(rule: str, rng: random.Random) -> tuple[list[int], list[int]]:
    for _ in range(2_000_000):
        prefix = [rng.randrange(3721) for _ in range(3)]
        enc = Encoder()
        for s in prefix:
            enc.encode(UNIFORM_I, s, "")
        if enc.pending < 7:
            continue
        length = enc.high - enc.low + 1
        near = 3720 - (Q2 - enc.low) * 3721 // length  # the symbol whose interval holds q2: many middle shifts
        for last in range(max(0, near - 2), min(3721, near + 3)):
            e = Encoder()
            e.low, e.high, e.pending = enc.low, enc.high, enc.pending
            e.encode(UNIFORM_I, last, "")
            if e.low < Q1 or e.pending + 1 != 21:
                continue
            syms = prefix + [last]
            nxt = [rng.randint(-600, 600) for _ in LOW_A]
            w, _ = low_end_stream(rule, syms, nxt)
            if trailing_zeros("".join(w.bits[w.blocks[0].start : w.blocks[0].start + w.blocks[0].length])) != 21:
                continue
            if not emulations(w.data()) and w.check() == [(0, 1, 1 if rule == "rewind" else 0)]:
                return syms, nxt
    raise SystemExit(f"no low-level block ends with 21 zeros ({rule})")


# ------------------------------------------------------------------------------ output
def _inline(fr: dict) -> str:
    def val(v):
        if isinstance(v, bool):
            return str(v).lower()
        if isinstance(v, str):
            return f'"{v}"'
        if isinstance(v, dict):
            return "{" + ", ".join(f"{k} = {val(x)}" for k, x in v.items()) + "}"
        return str(v)

    return val({**fr, "set": dict(sorted(fr["set"].items())), "retained": {}})


def _toml(frames: list[dict], what: str) -> str:
    lines = [f"# {what}", f"# {PROVENANCE}", "[stream]", f"frames = {len(frames)}", "frame_rate = 25.0", ""]
    if len(frames) > 4:  # long streams: one frame a line (a top-level array, before the [stream] table)
        return "\n".join(lines[:2] + ["frame = ["] + [f"  {_inline(fr)}," for fr in frames] + ["]", ""] + lines[2:])
    for fr in frames:
        lines.append("[[frame]]")
        for k in ("frame_number", "time_ms", "is_intra", "fap_quant"):
            v = fr[k]
            lines.append(f"{k} = {str(v).lower() if isinstance(v, bool) else v}")
        if "fap2" in fr:
            lines.append(f'fap2 = "{fr["fap2"]}"')
        lines.append("set = {" + ", ".join(f"{f} = {v}" for f, v in sorted(fr["set"].items())) + "}")
        lines.append("retained = {}")
        if "high" in fr:
            lines.append("high = {" + ", ".join(f"{k} = {v}" for k, v in fr["high"].items()) + "}")
        lines.append("")
    return "\n".join(lines)


def write(name: str, w: Stream, frames: list[dict], what: str) -> None:
    assert not emulations(w.data()), name
    (HERE / f"{name}.bits").write_text("\n".join(w.lines) + "\n")
    (HERE / f"{name}.expect.toml").write_text(_toml(frames, what))
    DATA.mkdir(parents=True, exist_ok=True)
    (DATA / f"{name.split('-', 1)[1]}.fba").write_bytes(w.data())


def main() -> int:
    rng = random.Random(33)
    for i, tie in enumerate(TIES, 1):
        if tie == "high-q3":
            assert q3_diverges()
            w, frames = tie_q3_stream()
            syms = Q3_LAST
        else:
            syms = find_tie(tie, rng)
            w, frames = tie_stream(tie, syms)
        w.check()
        write(f"c{i:02d}-coder-tie-{tie}", w, frames, f"renormalisation tie {tie}: {TIES[tie]}")
        print(f"tie {tie}: {syms}", flush=True)
    i = len(TIES)
    for p in range(1, LOOKAHEAD + 1):
        if p > 1:
            training, e1 = EXPRESSION_ENDS[p] if p in EXPRESSION_ENDS else find_expression(p)
            print(f"position {p}: training {training}, expression differences {e1}", flush=True)
        for rule in ("rewind", "error"):
            i += 1
            if p == 1:
                syms, nxt = find_low_end(rule, rng)
                w, frames = low_end_stream(rule, syms, nxt)
                print(f"position 1 {rule}: {syms} then {nxt}", flush=True)
            else:
                pl = find_low(Plan(p, rule, training, e1), rng)
                w, frames = lookahead_stream(pl)
                print(f"position {p} {rule}: {pl}", flush=True)
            write(
                f"c{i:02d}-coder-lookahead-{rule}-{p:02d}",
                w,
                frames,
                f"a stuffing position at look-ahead position {p} after a block end ({rule} rule, D7)",
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
