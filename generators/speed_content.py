"""The content the speed measurement feeds decoders (:mod:`fbaconf.harness.speed`), and its
reference decoding.

A procedural sequence (all low-level and high-level FAPs, 25 Hz) encoded by the
reference encoder. Long streams are built without re-encoding: a 100-frame block encoded once
is repeated (every copy starts with an intra plane and its plane start code, so the decoder's
state resets; the result decodes to the block's frames tiled, frame numbers and times running
on), plus a tail block for the remainder. Decoders that accept only ``.fap`` text get the
reference decoding of that stream as text. The files are named at random
(``content-<random>.fba``): their names say nothing of their length.

"""
from __future__ import annotations

import secrets
import tempfile
from pathlib import Path

import numpy as np

from fbaconf.animation.bundled import default_head_scene
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.faptext import write_fap
from fbaconf.bitstreams.frames import FapFrames
from fbaconf.bitstreams.synth import synthetic_sequence
from fbaconf.errors import FbaconfInputError
from fbaconf.rendering.scenario import Scenario
from fbaconf.scenes import bifs, bt

CONTENT_RATE = 25.0  # Hz of the generated content
CONTENT_QUANT = 4  # fap_quant of the generated stream
BLOCK_FRAMES = 100  # long streams repeat one encoded block of this many frames
_PLANE_START = b"\x00\x00\x01\xbb"
_END = b"\x00\x00\x01\xb1"


class ContentError(FbaconfInputError):
    rule = "speed-content"


class Content:
    """Generated streams (and .fap text, scenes, scenarios) in one directory, by length, and
    the reference decoding of any of them."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self._enc: dict[int, bytes] = {}
        self._dec: dict[int, FapFrames] = {}
        self._fba: dict[int, Path] = {}
        self._fap: dict[int, Path] = {}
        self._scene: dict[str, Path] = {}

    def _encoded(self, n: int) -> bytes:
        if n not in self._enc:
            self._enc[n] = encode(synthetic_sequence(n, CONTENT_RATE),
                                  EncoderOptions(fap_quant=CONTENT_QUANT)).data
        return self._enc[n]

    def stream_bytes(self, n: int) -> bytes:
        """An ``n``-frame .fba stream (``n`` >= 1)."""
        if n <= BLOCK_FRAMES:
            return self._encoded(n)
        m, r = divmod(n, BLOCK_FRAMES)
        head, body, end = _split(self._encoded(BLOCK_FRAMES))
        parts = [head, body * m]
        if r:
            h2, tail, _e = _split(self._encoded(r))
            if h2 != head:  # pragma: no cover - the object header does not depend on content
                raise ContentError("the generated blocks' object headers differ")
            parts.append(tail)
        parts.append(end)
        return b"".join(parts)

    def _block(self, n: int) -> FapFrames:
        """The reference decoding of the ``n``-frame encoding (``n`` <= BLOCK_FRAMES)."""
        if n not in self._dec:
            self._dec[n] = decode(self._encoded(n)).frames
        return self._dec[n]

    def expected(self, n: int, ks: np.ndarray) -> FapFrames:
        """Frames ``ks`` of the reference decoding of the ``n``-frame stream (without decoding it)."""
        ks = np.asarray(ks, dtype=np.int64)
        if n <= BLOCK_FRAMES:
            return self._block(n).select(ks)
        m, r = divmod(n, BLOCK_FRAMES)
        block, tail = self._block(BLOCK_FRAMES), (self._block(r) if r else None)
        in_tail = ks >= m * BLOCK_FRAMES
        rows = [tail.select(np.array([k - m * BLOCK_FRAMES])) if t else block.select(np.array([k % BLOCK_FRAMES]))
                for k, t in zip(ks, in_tail)]
        out = FapFrames(values=np.concatenate([x.values for x in rows]),
                        status=np.concatenate([x.status for x in rows]),
                        high=np.concatenate([x.high for x in rows]), frame_number=ks,
                        time_ms=ks * (1000.0 / block.frame_rate), frame_rate=block.frame_rate,
                        is_intra=np.concatenate([x.is_intra for x in rows]))
        return out

    def fba(self, n: int) -> Path:
        if n not in self._fba:
            p = self.root / f"content-{secrets.token_hex(6)}.fba"
            p.write_bytes(self.stream_bytes(n))
            self._fba[n] = p
        return self._fba[n]

    def fap(self, n: int) -> Path:
        if n not in self._fap:
            frames = decode(self.stream_bytes(n)).frames
            p = self.root / f"content-{secrets.token_hex(6)}.fap"
            p.write_text(write_fap(frames), encoding="utf-8")
            self._fap[n] = p
        return self._fap[n]

    def scene(self, kind: str) -> Path:
        """The bundled default head as a ``bt`` (text) or ``bifs`` (binary) scene file."""
        if kind not in self._scene:
            p = self.root / f"default-head.{kind}"
            if kind == "bifs":
                p.write_bytes(bifs.encode(default_head_scene()))
            else:
                p.write_text(bt.write(default_head_scene()), encoding="utf-8")
            self._scene[kind] = p
        return self._scene[kind]

    def scenario(self, name: str, **changes) -> Path:
        p = self.root / f"{name}.toml"
        if not p.exists():
            p.write_text(Scenario.default().with_(**changes).to_toml(), encoding="utf-8")
        return p


def _split(data: bytes) -> tuple[bytes, bytes, bytes]:
    """(object header, planes, end code) of a stream written with plane start codes."""
    i = data.find(_PLANE_START)
    if i < 0 or not data.endswith(_END):  # pragma: no cover - encoder options fixed above
        raise ContentError("generated stream lacks plane start codes / end code")
    return data[:i], data[i:-len(_END)], data[-len(_END):]


def content_stream(n: int) -> bytes:
    """The ``n``-frame stream the speed measurement feeds decoders (for tests and tools)."""
    with tempfile.TemporaryDirectory(prefix="fbaconf-speed-") as d:
        return Content(Path(d)).stream_bytes(n)
