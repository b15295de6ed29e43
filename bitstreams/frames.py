"""FapFrames: the value passed between the bitstream stage and the animation stage.

One row per decoded face object plane (skipped frames produce no row; their existence
shows in ``frame_number`` and ``time_ms``).

``values``  int32[n, 68]  FAP values in FAPU (AU for angles) after dequantisation; index
                          i holds FAP i+1. Columns 0 and 1 (FAP 1/2) are always 0: the
                          high-level FAPs live in their own fields below.
``status``  uint8[n, 68]  SET / RETAINED / FREE / DERIVED (see the constants). Columns 0/1
                          give the status of the viseme / expression FAP.

Status reading of mask types (decision D3): a FAP coded in the plane is SET. A FAP not
coded under group mask type 00 or 01 is RETAINED when it has ever been set (its value is
the last one set), else FREE. A FAP not coded under type 10 is FREE (the decoder may
interpolate; ``values`` still holds the last value set, 0 if never set). DERIVED is
written only by the animation stage (left/right fill, FIT), never by the bitstream decoder.
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field, fields

import numpy as np

from .._atomic import atomic_write_bytes
from .tables import NUM_FAPS

FREE = 0
SET = 1
RETAINED = 2
DERIVED = 3
STATUS_NAMES = {FREE: "FREE", SET: "SET", RETAINED: "RETAINED", DERIVED: "DERIVED"}

HIGH_LEVEL_FIELDS = (
    "viseme_select1",
    "viseme_select2",
    "viseme_blend",
    "viseme_def",
    "expression_select1",
    "expression_intensity1",
    "expression_select2",
    "expression_intensity2",
    "init_face",
    "expression_def",
)
VISEME_FIELDS = HIGH_LEVEL_FIELDS[:4]
EXPRESSION_FIELDS = HIGH_LEVEL_FIELDS[4:]

# Per-plane metadata kept alongside the values (decoder output; encoder reconstruction).
META_FIELDS = ("frame_number", "time_ms", "is_intra", "fap_quant", "coding_type", "bit_offset")


@dataclass(eq=False)
class FapFrames:
    values: np.ndarray
    status: np.ndarray
    high: np.ndarray  # int32[n, 10] in HIGH_LEVEL_FIELDS order
    frame_number: np.ndarray  # int64[n]
    time_ms: np.ndarray  # float64[n]
    frame_rate: float = 25.0  # the rate signalled by the first intra plane (D6 default 25 Hz)
    is_intra: np.ndarray = field(default=None)  # bool[n]
    fap_quant: np.ndarray = field(default=None)  # int16[n]
    coding_type: np.ndarray = field(default=None)  # int8[n]
    bit_offset: np.ndarray = field(default=None)  # int64[n], -1 when not from a bitstream
    gender: int = 0

    def __post_init__(self) -> None:
        n = self.values.shape[0]
        self.values = np.asarray(self.values, dtype=np.int32).reshape(n, NUM_FAPS)
        self.status = np.asarray(self.status, dtype=np.uint8).reshape(n, NUM_FAPS)
        self.high = np.asarray(self.high, dtype=np.int32).reshape(n, len(HIGH_LEVEL_FIELDS))
        self.frame_number = np.asarray(self.frame_number, dtype=np.int64).reshape(n)
        self.time_ms = np.asarray(self.time_ms, dtype=np.float64).reshape(n)
        defaults = {
            "is_intra": (bool, False),
            "fap_quant": (np.int16, 0),
            "coding_type": (np.int8, 0),
            "bit_offset": (np.int64, -1),
        }
        for name, (dt, fill) in defaults.items():
            v = getattr(self, name)
            setattr(self, name, np.full(n, fill, dtype=dt) if v is None else np.asarray(v, dtype=dt).reshape(n))

    # ------------------------------------------------------------------ construction
    @classmethod
    def empty(cls, n: int, frame_rate: float = 25.0) -> FapFrames:
        return cls(
            values=np.zeros((n, NUM_FAPS), np.int32),
            status=np.zeros((n, NUM_FAPS), np.uint8),
            high=np.zeros((n, len(HIGH_LEVEL_FIELDS)), np.int32),
            frame_number=np.arange(n, dtype=np.int64),
            time_ms=np.arange(n, dtype=np.float64) * (1000.0 / frame_rate),
            frame_rate=frame_rate,
        )

    def __len__(self) -> int:
        return self.values.shape[0]

    def hl(self, name: str) -> np.ndarray:
        """The column of one high-level field (a view)."""
        return self.high[:, HIGH_LEVEL_FIELDS.index(name)]

    @property
    def mask(self) -> np.ndarray:
        """bool[n, 68]: the FAPs coded in each plane (status SET)."""
        return self.status == SET

    def copy(self) -> FapFrames:
        kw = {
            f.name: (
                getattr(self, f.name).copy() if isinstance(getattr(self, f.name), np.ndarray) else getattr(self, f.name)
            )
            for f in fields(self)
        }
        return FapFrames(**kw)

    def select(self, idx) -> FapFrames:
        kw = {
            f.name: (
                getattr(self, f.name)[idx] if isinstance(getattr(self, f.name), np.ndarray) else getattr(self, f.name)
            )
            for f in fields(self)
        }
        return FapFrames(**kw)

    # ------------------------------------------------------------------ comparison
    def normative_equal(self, other: FapFrames) -> bool:
        """Equal where the standard fixes the result: status, and values/high-level fields of
        every FAP that is not FREE. FREE values are the decoder's choice."""
        return first_difference(self, other) is None

    # ------------------------------------------------------------------ storage
    def to_npz_bytes(self) -> bytes:
        buf = io.BytesIO()
        arrays = {f.name: getattr(self, f.name) for f in fields(self) if isinstance(getattr(self, f.name), np.ndarray)}
        np.savez_compressed(
            buf,
            **arrays,
            frame_rate=np.float64(self.frame_rate),
            gender=np.int64(self.gender),
            format=np.array("fbaconf.FapFrames/1"),
        )
        return buf.getvalue()

    def save_npz(self, path) -> None:
        atomic_write_bytes(path, self.to_npz_bytes())

    @classmethod
    def load_npz(cls, path_or_file) -> FapFrames:
        with np.load(path_or_file, allow_pickle=False) as z:
            if "format" not in z or str(z["format"]) != "fbaconf.FapFrames/1":
                raise ValueError("not an fbaconf FapFrames .npz file (missing format tag)")
            kw = {f.name: z[f.name] for f in fields(cls) if f.name in z and f.name not in ("frame_rate", "gender")}
            return cls(**kw, frame_rate=float(z["frame_rate"]), gender=int(z["gender"]))


def first_difference(expected: FapFrames, got: FapFrames) -> dict | None:
    """The first normative difference between two FapFrames, or None.

    Compares frame count, frame numbers, status, values of non-FREE low-level FAPs and the
    high-level fields of frames where FAP 1 / FAP 2 is not FREE. Returns a dict naming
    frame, FAP / field, expected and got."""
    if len(expected) != len(got):
        return {
            "frame": min(len(expected), len(got)),
            "what": "frame count",
            "expected": len(expected),
            "got": len(got),
        }
    if len(expected) == 0:
        return None
    bad_fn = np.nonzero(expected.frame_number != got.frame_number)[0]
    bad_st = np.nonzero((expected.status != got.status).any(axis=1))[0]
    normative = expected.status != FREE
    bad_val = np.nonzero(((expected.values != got.values) & normative).any(axis=1))[0]
    hl_vis = np.repeat(normative[:, [0]], len(VISEME_FIELDS), axis=1)
    hl_exp = np.repeat(normative[:, [1]], len(EXPRESSION_FIELDS), axis=1)
    hl_norm = np.concatenate([hl_vis, hl_exp], axis=1)
    bad_hl = np.nonzero(((expected.high != got.high) & hl_norm).any(axis=1))[0]
    candidates = [
        (int(a[0]), k)
        for k, a in (("frame_number", bad_fn), ("status", bad_st), ("value", bad_val), ("high", bad_hl))
        if len(a)
    ]
    if not candidates:
        return None
    frame, kind = min(candidates)
    if kind == "frame_number":
        return {
            "frame": frame,
            "what": "frame number",
            "expected": int(expected.frame_number[frame]),
            "got": int(got.frame_number[frame]),
        }
    if kind == "status":
        fap = int(np.nonzero(expected.status[frame] != got.status[frame])[0][0])
        return {
            "frame": frame,
            "fap": fap + 1,
            "what": "status",
            "expected": STATUS_NAMES.get(int(expected.status[frame, fap]), "?"),
            "got": STATUS_NAMES.get(int(got.status[frame, fap]), str(int(got.status[frame, fap]))),
        }
    if kind == "value":
        fap = int(np.nonzero((expected.values[frame] != got.values[frame]) & normative[frame])[0][0])
        return {
            "frame": frame,
            "fap": fap + 1,
            "what": "value",
            "expected": int(expected.values[frame, fap]),
            "got": int(got.values[frame, fap]),
        }
    k = int(np.nonzero((expected.high[frame] != got.high[frame]) & hl_norm[frame])[0][0])
    return {
        "frame": frame,
        "fap": 1 if k < len(VISEME_FIELDS) else 2,
        "what": HIGH_LEVEL_FIELDS[k],
        "expected": int(expected.high[frame, k]),
        "got": int(got.high[frame, k]),
    }
