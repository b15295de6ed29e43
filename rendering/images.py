"""Image files, only through OpenImageIO; colour encoding through colour-science.

* PNG: 8-bit sRGB. ``encode_srgb8``: clip linear to [0, 1], encode with
  ``colour.cctf_encoding(x, function="sRGB")`` (IEC 61966-2-1), then quantise with round
  half up: ``floor(e * 255 + 0.5)``.
* EXR: linear RGB, 32-bit float per channel.

Files carry no time stamp (``DateTime`` is left empty), so identical pixels give
identical bytes. Writes are atomic: the image is written to a temporary name in the destination folder
and moved into place with ``os.replace``; on any error the temporary file is removed, so
no partial image is ever left under the final name.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np

from fbaconf._atomic import atomic_path

from .errors import ImageIOError, TextureError


def openimageio() -> Any:  # a module without type information
    """The OpenImageIO module (imported on first use)."""
    import OpenImageIO  # noqa: PLC0415 (image I/O loads on first use)

    return OpenImageIO


def colour_science() -> Any:  # a module without type information
    """The colour-science module (imported on first use, its import warnings silenced)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import colour  # noqa: PLC0415 (colour-science loads in ~1 s)
    return colour


def encode_srgb8(linear: np.ndarray) -> np.ndarray:
    """Linear float RGB -> uint8 sRGB (clip, sRGB inverse EOTF, round half up)."""
    x = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    e = np.asarray(colour_science().cctf_encoding(x, function="sRGB"), dtype=np.float64)
    return np.floor(e * 255.0 + 0.5).astype(np.uint8)


def srgb_to_linear(encoded: np.ndarray) -> np.ndarray:
    """sRGB-encoded [0, 1] -> linear (colour-science's sRGB EOTF)."""
    return np.asarray(
        colour_science().cctf_decoding(np.asarray(encoded, dtype=np.float64), function="sRGB"), dtype=np.float64
    )


def _write(path: Path, pixels: np.ndarray, fmt: str) -> None:
    oiio = openimageio()
    h, w, c = pixels.shape
    with atomic_path(path, suffix=path.suffix) as tmp:
        out = oiio.ImageOutput.create(tmp)
        if out is None:
            raise ImageIOError(f"no OpenImageIO writer: {oiio.geterror()}", file=str(path))
        spec = oiio.ImageSpec(w, h, c, fmt)
        # No capture date: OpenEXR would otherwise stamp the wall clock into the header and
        # identical renders would differ byte-wise. Compression pinned explicitly.
        spec.attribute("DateTime", "")
        if path.suffix.lower() == ".exr":
            spec.attribute("compression", "zip")
        else:
            spec.attribute("png:compressionLevel", 6)
        if not out.open(tmp, spec):
            raise ImageIOError(f"cannot open for writing: {out.geterror()}", file=str(path))
        ok = out.write_image(np.ascontiguousarray(pixels))
        err = out.geterror() if not ok else ""
        if not out.close() or not ok:
            raise ImageIOError(f"write failed: {err or out.geterror()}", file=str(path))


def write_png(path, linear: np.ndarray) -> Path:
    """Write linear float RGB[H, W, 3] as an 8-bit sRGB PNG."""
    path = Path(path)
    _write(path, encode_srgb8(linear), "uint8")
    return path


def write_exr(path, linear: np.ndarray) -> Path:
    """Write linear float RGB[H, W, 3] as a 32-bit float EXR."""
    path = Path(path)
    _write(path, np.asarray(linear, dtype=np.float32), "float")
    return path


def write_image(path, linear: np.ndarray, fmt: str | None = None) -> Path:
    fmt = fmt or Path(path).suffix.lstrip(".").lower()
    if fmt == "png":
        return write_png(path, linear)
    if fmt == "exr":
        return write_exr(path, linear)
    raise ImageIOError(f"unsupported image format {fmt!r} (png, exr)", file=str(path))


def read_image(path, *, error=ImageIOError) -> tuple[np.ndarray, str]:
    """Read an image with OpenImageIO: (float32 pixels[H, W, C] as stored, pixel format name).
    Integer formats come back normalised to [0, 1]."""
    oiio = openimageio()
    path = Path(path)
    if not path.is_file():
        raise error(f"image not found: {path}", file=str(path))
    buf = oiio.ImageBuf(str(path))
    px = buf.get_pixels(oiio.FLOAT)
    if buf.has_error or px is None:
        raise error(f"cannot read image: {buf.geterror()}", file=str(path))
    fmt = str(buf.spec().format)
    px = np.asarray(px, dtype=np.float32)
    if px.ndim == 2:
        px = px[:, :, None]
    return px, fmt


def read_linear_rgb(path, *, error=ImageIOError) -> np.ndarray:
    """An image as linear float64 RGB[H, W, 3]: float formats (half, float, double) are
    taken as linear; integer formats as sRGB-encoded and decoded. One channel (or grey +
    alpha) is replicated to RGB; channels beyond the third (alpha) are ignored."""
    px, fmt = read_image(path, error=error)
    c = px.shape[2]
    if c >= 3:
        rgb = px[:, :, :3]
    else:
        rgb = np.repeat(px[:, :, :1], 3, axis=2)
    rgb = rgb.astype(np.float64)
    if fmt not in ("half", "float", "double"):
        rgb = srgb_to_linear(rgb)
    return rgb


def read_texture(path) -> np.ndarray:
    return read_linear_rgb(path, error=TextureError)
