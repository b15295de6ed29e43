"""The comparison ladder: a decoder's outputs against the golden (reference) outputs —
one module per stage (:mod:`.faps`, :mod:`.vertices`, :mod:`.images`), with
:mod:`.loaders` (untrusted output files), :mod:`.tolerances` and :mod:`.base`.

Pure functions (no subprocesses): the runner reads a decoder's output files with the
``load_output_*`` functions and judges them with the ``compare_*`` functions, each giving
one :class:`~fbaconf.harness.results.StageResult`.

* ``faps`` (:func:`compare_faps`) — exact and normative: frame count, frame numbers, and
  per frame the value of every FAP whose expected status is SET, RETAINED or DERIVED (and
  the high-level fields of FAP 1/2 when they are not FREE). FREE values are the decoder's
  choice. FapFrames ``.npz`` outputs must also reproduce the status of every FAP; ``.fap``
  text carries no SET/RETAINED distinction, so there only "a value is present" is checked.
* ``vertices`` (:func:`compare_vertices`) — per-frame maximum and RMS euclidean error
  against tolerances (:class:`VertexTolerances`).
* ``images`` (:func:`compare_images`) — OpenImageIO ``ImageBufAlgo.compare`` on
  sRGB-encoded values plus CIEDE2000 (colour-science), with a fail band and a warn band
  (:class:`ImageTolerances`); failing/warning frames leave expected/got/diff PNGs.

Default tolerances live in one data file, ``harness/data/tolerances.toml``, with the
reasoning for each number; suite cases override them per comparison with a dict.

Decoder outputs are untrusted: :func:`load_output_faps` and :func:`load_output_vertices`
raise :class:`OutputError` (an :class:`~fbaconf.errors.FbaconfInputError`)
naming the file for any unreadable, oversized, mis-shaped, mistyped or non-finite input,
and never another exception. ``.npz`` members are read without pickles, and every array's
header is checked (dtype, shape, size against the byte cap) before any data is read, so a
zip bomb or a header claiming a huge array cannot exhaust memory. Unreadable images are a
``Fail`` of the images stage, not an exception.
"""

from .base import DEFAULT_MAX_BYTES, DEFAULT_MAX_PIXELS, PSNR_CAP, OutputError, ToleranceError, worst
from .faps import compare_faps
from .images import compare_images
from .loaders import check_output_file, load_output_faps, load_output_vertices, open_npz
from .tolerances import ImageTolerances, VertexTolerances, load_tolerances
from .vertices import compare_vertices, part_namer

__all__ = [
    "OutputError",
    "ToleranceError",
    "DEFAULT_MAX_BYTES",
    "DEFAULT_MAX_PIXELS",
    "PSNR_CAP",
    "ImageTolerances",
    "VertexTolerances",
    "load_tolerances",
    "load_output_faps",
    "load_output_vertices",
    "check_output_file",
    "open_npz",
    "compare_faps",
    "compare_vertices",
    "compare_images",
    "part_namer",
    "worst",
]
