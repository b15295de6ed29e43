"""The reference chain, in one place: bits -> FapFrames -> FaceState -> images.

    stream (.fba bits, or .fap text)  --bitstreams.decoder-->  FapFrames
    FapFrames (+ scene: BT or BIFS)   --animation.engine-->    FaceState (vertices per frame)
    FaceState + scenario              --rendering.render-->    images

Used by the reference decoder (``reference/decoder.py``, in-process and as a program)
and by the golden builder (``conformance/golden.py``): the goldens are exactly what this
chain writes.
"""

from __future__ import annotations

from pathlib import Path

from fbaconf.errors import FbaconfInputError


def load_stream(path: Path):
    """FapFrames from a ``.fba`` stream (reference decoder) or ``.fap`` text."""
    path = Path(path)
    if path.suffix.lower() == ".fap":
        from fbaconf.bitstreams.faptext import read_fap_file

        return read_fap_file(path)[0]
    from fbaconf.bitstreams.decoder import decode

    try:
        data = path.read_bytes()
    except OSError as e:
        raise FbaconfInputError(f"cannot read stream: {e.strerror}", rule="io", file=str(path)) from None
    return decode(data, file=str(path)).frames


def reference_outputs(
    stream: Path,
    *,
    scene: Path | None = None,
    scenario: Path | None = None,
    faps_out: Path | None = None,
    vertices_out: Path | None = None,
    images_dir: Path | None = None,
    player_state: bool = False,
    supersample: int | None = None,
) -> None:
    """Decode (and animate, render) one stream with the reference, writing the requested outputs.
    ``player_state``: the FAP output is a player's (docs/harness.md, "Players"): its state,
    every FAP that holds a value written as set in every frame. ``supersample``: render with
    this many samples per pixel side instead of the scenario's (the goldens' 8 x 8)."""
    from fbaconf.bitstreams.fapio import save_faps

    frames = load_stream(stream)
    if faps_out is not None:
        save_faps(state_of(frames) if player_state else frames, faps_out)
    if vertices_out is None and images_dir is None:
        return
    from fbaconf.animation.engine import animate
    from fbaconf.animation.stateio import save_npz

    state = animate(frames, scene=scene)
    if vertices_out is not None:
        save_npz(state, vertices_out)
    if images_dir is not None:
        from fbaconf.rendering.render import render_frames
        from fbaconf.rendering.scenario import Scenario

        sc = Scenario.load(scenario) if scenario is not None else Scenario.default()
        if supersample is not None:
            sc = sc.with_(supersample=supersample)
        render_frames(state, sc, images_dir, scene_dir=Path(scene).resolve().parent if scene else None)


def is_fap_text(path) -> bool:
    """A .fap text input: the reference is then a player, and writes its state (docs/harness.md)."""
    return path is not None and Path(path).suffix.lower() == ".fap"


def state_of(frames):
    """What a player holds in each frame: every FAP with a value (SET, RETAINED or DERIVED)
    as SET, FREE ones as they are."""
    import numpy as np

    from fbaconf.bitstreams.frames import DERIVED, RETAINED, SET

    out = frames.copy()
    out.status = np.where(np.isin(out.status, (RETAINED, DERIVED)), SET, out.status).astype(out.status.dtype)
    return out


def multi_outputs(streams: list[Path], out_dir: Path, fmt: str = "npz") -> None:
    from fbaconf.bitstreams.fapio import save_faps

    out_dir.mkdir(parents=True, exist_ok=True)
    for s in streams:
        save_faps(load_stream(s), out_dir / f"{Path(s).stem}.{fmt}")
