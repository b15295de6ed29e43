"""What a speed run wrote, judged on content (:mod:`.speed`): a sample of the frames of a FAP
output against the reference decoding of the run's content, a sample of the rendered frames
as images against the reference rendering — never a count of lines or of files.

The sample is drawn after the run, from the operating system's random source: the first and
last frames and a few at random, so a decoder cannot know which frames are looked at.
"""

from __future__ import annotations

import secrets
import tempfile
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from fbaconf.bitstreams.faptext import read_fap_text
from fbaconf.bitstreams.frames import FapFrames
from fbaconf.errors import FbaconfInputError
from fbaconf.safefs import UnsafeFileError, open_regular, read_regular

from ..compare.base import OutputError
from ..compare.faps import compare_faps
from ..compare.images import compare_images
from ..compare.loaders import check_output_file, load_output_faps
from ..compare.tolerances import ImageTolerances
from .content import Run

RANDOM_FRAMES = 6  # frames of a run's FAP output compared besides the first and the last
RANDOM_IMAGES = 2  # rendered frames judged besides the first and the last


def sample(n: int, extra: int = RANDOM_FRAMES) -> np.ndarray:
    """The frames judged in one run of ``n``: the first, the last, and ``extra`` drawn afresh."""
    rnd = secrets.SystemRandom()
    inner = rnd.sample(range(1, n - 1), min(extra, max(0, n - 2))) if n > 2 else []
    return np.array(sorted({0, n - 1, *inner}), dtype=np.int64)


def faps_problem(path: Path, run: Run, *, max_bytes: int, player: bool = False) -> str | None:
    """Why the FAP output at ``path`` is not the reference decoding of ``run`` — a clause to
    follow "the decoder" — or None. Raises nothing for the decoder's output."""
    n = run.n
    try:
        check_output_file(path, max_bytes)
        ks = sample(n)
        got, count, text = _sampled(path, n, ks, max_bytes)
    except OutputError as e:
        return (
            f"finished but wrote no output ({path})"
            if e.rule == "output-missing"
            else f"finished but its output is unusable: {e}"
        )
    if count != n:
        return f"was given {n} frames but its output holds {count}"
    r = compare_faps(run.expected(ks), got, text_output=text, player=player)
    if r.outcome.ok:
        return None
    d = r.first_difference or {}
    k = int(ks[d["frame"]]) if isinstance(d.get("frame"), (int, np.integer)) and d["frame"] < len(ks) else None
    where = f"frame {k}" if k is not None else "a sampled frame"
    return (
        f"finished but its output is not the decoding of the content it was given ({where} of {n}, "
        f"{d.get('what', 'value')}"
        f"{' of FAP ' + str(d['fap']) if d.get('fap') is not None else ''}: expected {d.get('expected')}, "
        f"got {d.get('got')})"
    )


def images_problem(
    images_dir: Path, run: Run, ks: Iterable[int], *, width: int, height: int, scene: Path | None = None, max_bytes: int
) -> str | None:
    """Why the images of frames ``ks`` in ``images_dir`` (``frame_<k:05d>.png``) are not the
    reference rendering of ``run`` at ``width`` x ``height`` — judged as the image stage judges
    a case (:func:`~.compare.images.compare_images`, the default tolerances: what a faithful
    renderer with at least 2 x 2 samples per pixel meets) — or None. ``ks`` must start at frame
    0, which places the fitted camera."""
    ks = [int(k) for k in ks]
    with tempfile.TemporaryDirectory(prefix="fbaconf-speed-images-") as tmp:
        expected = run.reference_images(ks, Path(tmp) / "expected", width=width, height=height, scene=scene)
        got = [Path(images_dir) / f"frame_{k:05d}.png" for k in ks]
        r = compare_images(
            expected,
            got,
            ImageTolerances.from_dict(None, {}),
            Path(tmp) / "artefacts",
            frames=ks,
            max_bytes=max_bytes,
            max_artefact_frames=0,
        )
    if r.outcome.ok:
        return None
    return (
        f"finished but its images are not the rendering of the content it was given (frames "
        f"{', '.join(map(str, ks))} of {run.n} judged as images): {r.message}"
    )


def _sampled(path: Path, n: int, ks: np.ndarray, max_bytes: int) -> tuple[FapFrames, int, bool]:
    """(frames ``ks`` of the output, its frame count, whether it is .fap text). A .fap output
    laid out as the format's writers lay it out (a header, then a mask line of all ones and a
    data line per frame) is read for the sampled frames only; any other layout is read whole."""
    try:
        with open_regular(path, max_bytes) as f:
            zipped = f.read(4) == b"PK\x03\x04"
        if zipped or path.suffix.lower() == ".npz":
            frames = load_output_faps(path, max_bytes=max_bytes)
            return (frames.select(ks) if len(frames) == n else frames), len(frames), False
        data = read_regular(path, max_bytes)
    except UnsafeFileError as e:
        raise OutputError(f"unusable output: {e}", rule="output-unsafe", file=str(path)) from None
    lines = [ln for ln in data.split(b"\n") if ln.strip() and not ln.lstrip().startswith(b"#")]
    try:
        head = lines[0].split()
        declared = int(head[-1])
    except (IndexError, ValueError):
        raise OutputError("no .fap header with a frame count", rule="output-fap-count", file=str(path)) from None
    ones = b" ".join([b"1"] * 68)
    if declared == n and len(lines) == 1 + 2 * n and all(lines[1 + 2 * k].strip() == ones for k in ks):
        mini = (
            b" ".join(head[:-1] + [str(len(ks)).encode()])
            + b"\n"
            + b"".join(lines[1 + 2 * k] + b"\n" + lines[2 + 2 * k] + b"\n" for k in ks)
        )
        try:
            frames, _header, _w = read_fap_text(mini.decode("utf-8"), file=str(path))
        except (FbaconfInputError, UnicodeDecodeError) as e:
            raise OutputError(f"unreadable FAP output: {e}", rule="output-fap-text", file=str(path)) from None
        return frames, n, True
    if declared != n or len(lines) - 1 < n:  # each frame takes at least one line: short, whatever it holds
        return FapFrames.empty(0), min(declared, len(lines) - 1), True
    frames = load_output_faps(path, max_bytes=max_bytes)  # another layout: read whole
    return (frames.select(ks) if len(frames) == n else frames), len(frames), True
