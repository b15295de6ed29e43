"""FapFrames as files: an fbaconf ``.npz`` or ``.fap`` text, read and written by suffix (the one
place every stage loads and saves decoded FAPs)."""

from __future__ import annotations

from pathlib import Path

from fbaconf._atomic import atomic_write_text
from fbaconf.errors import FbaconfInputError

from .faptext import read_fap_file, write_fap
from .frames import FapFrames


def load_faps(path: str | Path) -> tuple[FapFrames, list]:
    """FapFrames from a .fap text file or an fbaconf .npz; returns (frames, warnings)."""
    p = Path(path)
    if not p.is_file():
        raise FbaconfInputError(f"FAP file not found: {p}", rule="faps-missing", file=str(p))
    if p.suffix.lower() == ".npz":
        try:
            return FapFrames.load_npz(p), []
        except FbaconfInputError:
            raise
        except Exception as e:  # noqa: BLE001 - np.load / zipfile errors of a damaged or foreign file
            raise FbaconfInputError(f"not a FapFrames .npz: {e}", rule="faps-npz", file=str(p)) from None
    frames, _header, warnings = read_fap_file(p)
    return frames, warnings


def save_faps(frames: FapFrames, path: str | Path, name: str = "fbaconf") -> None:
    """Write ``frames`` as ``.npz`` or ``.fap`` text, by the path's suffix (atomically)."""
    p = Path(path)
    if p.suffix.lower() == ".npz":
        frames.save_npz(p)
    elif p.suffix.lower() == ".fap":
        atomic_write_text(p, write_fap(frames, name=name))
    else:
        raise FbaconfInputError(f"output must end in .fap or .npz: {p}", rule="io", file=str(p))
