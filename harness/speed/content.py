"""The content the speed measurement feeds decoders (:mod:`fbaconf.harness.speed`), made fresh
for every run, and the reference outputs that judge a sample of what the decoder wrote.

Fresh, secret content. A :class:`Content` draws a 256-bit secret when it is made (one per
measurement, kept in memory only) and every run gets its own stream from it: a procedural
sequence (all low-level and high-level FAPs, 25 Hz; :func:`synthetic_sequence` with a phase
drawn from the secret) plus, on every low-level FAP of every frame, a few quantiser steps of
noise drawn from SHAKE-256 of the secret, the run's number and the block's. Nothing the
decoder sees determines the next frame: a decoder cannot know the content in advance (a table
it ships matches nothing), cannot derive it from the first frames it decodes, and never sees
an input twice — not a whole stream again (a cache of answers) nor a block within one (a
cache of blocks). The files are named at random (``content-<random>.fba``): their names say
nothing of their length.

Cheap reference. A stream is :data:`BLOCK_FRAMES`-frame blocks, each encoded on its own by the
reference encoder (every block starts with an intra plane and its plane start code, so the
decoder's state resets; the stream decodes to the blocks' frames one after the other, frame
numbers and times running on). The expected frames of a sample are the reference decoding of
the blocks that hold them only, and the expected images the reference rendering of those
frames (8 x 8 samples per pixel, as the goldens): a 100,000-frame run costs its encoding, and
a few blocks' decoding.
"""

from __future__ import annotations

import hashlib
import secrets
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fbaconf.animation.bundled import default_head_scene
from fbaconf.animation.engine import animate
from fbaconf.bitstreams import tables
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import encode
from fbaconf.bitstreams.encoder_options import EncoderOptions
from fbaconf.bitstreams.faptext import write_fap
from fbaconf.bitstreams.frames import SET, FapFrames
from fbaconf.bitstreams.synth import synthetic_sequence
from fbaconf.errors import FbaconfInputError
from fbaconf.rendering.render import render_frames
from fbaconf.rendering.scenario import Scenario
from fbaconf.scenes import bifs, bt

CONTENT_RATE = 25.0  # Hz of the generated content
CONTENT_QUANT = 4  # fap_quant of the generated stream
BLOCK_FRAMES = 100  # frames of each independently encoded block
NOISE_LEVELS = 3  # each low-level value moves by up to this many quantiser steps, drawn per frame
REFERENCE_SUPERSAMPLE = 8  # samples per pixel side of the expected images (the goldens' 8 x 8)
_PLANE_START = b"\x00\x00\x01\xbb"
_END = b"\x00\x00\x01\xb1"


class ContentError(FbaconfInputError):
    rule = "speed-content"


class Content:
    """The measurement's generator: a secret drawn once, a fresh :class:`Run` per call of
    :meth:`make`, and the files every run shares (scenes, scenarios) in ``root``."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self._secret = secrets.token_bytes(32)
        self._runs = 0
        self._scene: dict[str, Path] = {}

    def make(self, n: int) -> Run:
        """An ``n``-frame run (``n`` >= 1) no run of this or any other measurement shares."""
        if n < 1:  # a caller's mistake, not an input's
            raise ValueError(f"a run needs at least one frame, not {n}")
        self._runs += 1
        return Run(self, self._runs, int(n))

    def _random(self, label: str, size: int) -> bytes:
        return hashlib.shake_256(self._secret + label.encode("ascii")).digest(size)

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

    def scenario(self, name: str, **changes: Any) -> Path:
        p = self.root / f"{name}.toml"
        if not p.exists():
            p.write_text(Scenario.default().with_(**changes).to_toml(), encoding="utf-8")
        return p


class Run:
    """One run's content: the stream, its files, and the reference outputs of any frames."""

    def __init__(self, content: Content, number: int, n: int) -> None:
        self.content = content
        self.number = number
        self.n = n
        sizes = [BLOCK_FRAMES] * (n // BLOCK_FRAMES) + ([n % BLOCK_FRAMES] if n % BLOCK_FRAMES else [])
        self._blocks: list[bytes] = []  # each block's planes (without the object header and end code)
        head = None
        for j, size in enumerate(sizes):
            h, body, _end = _split(encode(self._frames(j, size), EncoderOptions(fap_quant=CONTENT_QUANT)).data)
            if head is not None and h != head:  # pragma: no cover - the object header does not depend on content
                raise ContentError("the generated blocks' object headers differ")
            head = h
            self._blocks.append(body)
        if head is None:
            raise ContentError(f"a run of {n} frames has no blocks")
        self._head: bytes = head
        self._sizes = sizes
        self._decoded: dict[int, FapFrames] = {}
        self._files: list[Path] = []

    def _frames(self, j: int, size: int) -> FapFrames:
        """Block ``j``: the procedural motion at a secret phase plus secret per-frame noise."""
        raw = self.content._random(f"run {self.number} block {j}", 4 + size * tables.NUM_FAPS)
        frames = synthetic_sequence(size, CONTENT_RATE, seed=int.from_bytes(raw[:4], "little") & 0x7FFFFFFF)
        levels = (
            np.frombuffer(raw[4:], dtype=np.uint8).reshape(size, tables.NUM_FAPS).astype(np.int64)
            % (2 * NOISE_LEVELS + 1)
        ) - NOISE_LEVELS
        info = tables.fap_table()
        step = np.array([f.quant_step for f in info], dtype=np.int64) * CONTENT_QUANT
        bound = np.array([f.intra_range * f.quant_step for f in info], dtype=np.int64) * 9 // 10
        low = np.array([f.direction == "U" for f in info])
        v = frames.values.astype(np.int64) + levels * step
        v = np.clip(v, np.where(low, 0, -bound), bound)
        coded = frames.status == SET
        coded[:, :2] = False  # the high-level FAPs keep their own values
        frames.values[coded] = v[coded].astype(np.int32)
        return frames

    def stream_bytes(self) -> bytes:
        return b"".join([self._head, *self._blocks, _END])

    def fba(self) -> Path:
        """The stream as a file named at random (written at the first call)."""
        return self._write("fba", self.stream_bytes())

    def fap(self) -> Path:
        """The reference decoding as ``.fap`` text, for decoders that read only FAPs."""
        return self._write("fap", write_fap(decode(self.stream_bytes()).frames).encode("utf-8"))

    def _write(self, ext: str, data: bytes) -> Path:
        for p in self._files:
            if p.suffix == f".{ext}":
                return p
        p = self.content.root / f"content-{secrets.token_hex(6)}.{ext}"
        p.write_bytes(data)
        self._files.append(p)
        return p

    def remove(self) -> None:
        """Delete the run's files (its content is used once)."""
        for p in self._files:
            p.unlink(missing_ok=True)
        self._files.clear()

    def _block(self, j: int) -> FapFrames:
        if j not in self._decoded:
            self._decoded[j] = decode(b"".join([self._head, self._blocks[j], _END])).frames
        return self._decoded[j]

    def expected(self, ks: Iterable[int] | np.ndarray) -> FapFrames:
        """Frames ``ks`` of the reference decoding of the stream (decoding only their blocks)."""
        idx = np.asarray(ks, dtype=np.int64)
        if len(idx) and (np.min(idx) < 0 or np.max(idx) >= self.n):
            raise ValueError(f"frames {idx.tolist()} outside the run's {self.n}")
        rows = [self._block(int(k) // BLOCK_FRAMES).select(np.array([int(k) % BLOCK_FRAMES])) for k in idx]
        first = self._block(0)
        return FapFrames(
            values=np.concatenate([x.values for x in rows]).reshape(len(idx), -1),
            status=np.concatenate([x.status for x in rows]).reshape(len(idx), -1),
            high=np.concatenate([x.high for x in rows]).reshape(len(idx), -1),
            frame_number=idx,
            time_ms=idx * (1000.0 / first.frame_rate),
            frame_rate=first.frame_rate,
            is_intra=np.concatenate([x.is_intra for x in rows]) if rows else np.zeros(0, bool),
        )

    def reference_images(
        self, ks: Sequence[int], out_dir: Path, *, width: int, height: int, scene: Path | None = None
    ) -> list[Path]:
        """The reference rendering of frames ``ks`` at ``width`` x ``height`` (the default
        scenario's camera and lights, :data:`REFERENCE_SUPERSAMPLE` samples per pixel side), one
        PNG per frame in ``out_dir``, in the order of ``ks``."""
        out_dir = Path(out_dir)
        state = animate(self.expected(ks), scene=scene)
        sc = Scenario.default().with_(width=width, height=height, supersample=REFERENCE_SUPERSAMPLE, frames=None)
        render_frames(state, sc, out_dir, scene_dir=Path(scene).resolve().parent if scene else None)
        return [out_dir / f"frame_{i:05d}.png" for i in range(len(ks))]


def _split(data: bytes) -> tuple[bytes, bytes, bytes]:
    """(object header, planes, end code) of a stream written with plane start codes."""
    i = data.find(_PLANE_START)
    if i < 0 or not data.endswith(_END):  # pragma: no cover - encoder options fixed above
        raise ContentError("generated stream lacks plane start codes / end code")
    return data[:i], data[i : -len(_END)], data[-len(_END) :]


def content_stream(n: int) -> bytes:
    """A fresh ``n``-frame stream as the speed measurement makes them (for tests and tools)."""
    with tempfile.TemporaryDirectory(prefix="fbaconf-speed-") as d:
        return Content(Path(d)).make(n).stream_bytes()
