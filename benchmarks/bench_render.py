"""Rendering speed of the reference rasteriser: frames/s at 256x256, one core.

Meshes: the bundled default head and the Predictable level-limit head through the
animation stage (when ``fbaconf.animation.engine`` exists), and two synthetic meshes generated here: a
head-sized (~2,500 triangles) deformed ellipsoid with a nose, and a 5,000-vertex mesh
(~10,000 triangles) of the same shape, animated over 30 frames (a jaw-like stretch) so
per-frame normals are recomputed. Prints frames/s for supersample 1 and 3, rendering only
and rendering + PNG writing (sRGB encoding + zlib), under the bundled default scenario.

Then, where an OpenGL context can be made (moderngl on Mesa's llvmpipe, headless EGL:
examples/glrender), the same frames side by side: the reference at 3 x 3 supersampling against
the OpenGL renderer-under-test at 3 x 3 (examples/glrender ``ssaa3``: draw, resolve, sRGB
encode, read back), both on the one core this benchmark is pinned to, and the ratio.

    python benchmarks/bench_render.py [--frames N] [--repeat R]
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from fbaconf.animation.facestate import FaceState, MeshPart
from fbaconf.rendering.render import Renderer
from fbaconf.rendering.scenario import Scenario


def head_mesh(n_lat: int, n_lon: int) -> tuple[np.ndarray, np.ndarray]:
    """A closed head-like surface: an ellipsoid (160 x 230 x 190 units) with a nose bump."""
    th = np.linspace(0.0, np.pi, n_lat + 1)[1:-1]
    ph = np.linspace(0.0, 2.0 * np.pi, n_lon, endpoint=False)
    T, P = np.meshgrid(th, ph, indexing="ij")
    x, y, z = np.sin(T) * np.cos(P), np.cos(T), np.sin(T) * np.sin(P)
    pts = np.stack([x, y, z], -1).reshape(-1, 3)
    pts = np.vstack([[0.0, 1.0, 0.0], pts, [0.0, -1.0, 0.0]])
    nose = np.exp(-((pts[:, 0] / 0.18) ** 2 + ((pts[:, 1] + 0.05) / 0.25) ** 2)) * (pts[:, 2] > 0)
    pts = pts * np.array([80.0, 115.0, 95.0]) + np.outer(nose, [0.0, 0.0, 25.0])

    def idx(i, j):
        return 1 + i * n_lon + (j % n_lon)

    tris = [[0, idx(0, j + 1), idx(0, j)] for j in range(n_lon)]
    for i in range(n_lat - 2):
        for j in range(n_lon):
            a, b, c, d = idx(i, j), idx(i, j + 1), idx(i + 1, j), idx(i + 1, j + 1)
            tris += [[a, b, d], [a, d, c]]
    last = len(pts) - 1
    tris += [[last, idx(n_lat - 2, j), idx(n_lat - 2, j + 1)] for j in range(n_lon)]
    return pts, np.asarray(tris)


def animated_state(pts: np.ndarray, tris: np.ndarray, n_frames: int) -> FaceState:
    t = np.arange(n_frames)[:, None]
    jaw = (pts[None, :, 1] < -30.0) * (1.0 + 0.08 * np.sin(t * 0.4))  # lower part stretches
    frames = np.repeat(pts[None], n_frames, axis=0)
    frames[:, :, 1] = np.where(jaw > 0, pts[None, :, 1] * jaw, pts[None, :, 1])
    part = MeshPart("head", 0, len(pts), tris, color=(0.85, 0.66, 0.55), specular=0.2, shininess=0.2)
    return FaceState([part], frames, t[:, 0] * 40.0)


def bench(state: FaceState, ss: int, n_frames: int, repeat: int, write: bool) -> tuple[float, float]:
    """Best (wall-clock fps, CPU-time fps) over ``repeat`` runs of ``n_frames`` frames."""
    sc = Scenario.default().with_(supersample=ss, width=256, height=256)
    r = Renderer(state, sc)
    r.render(0)  # warm-up
    best_wall = best_cpu = 0.0
    n = min(n_frames, state.n_frames)
    with tempfile.TemporaryDirectory() as d:
        for _ in range(repeat):
            t0, c0 = time.perf_counter(), time.process_time()
            for k in range(n):
                if write:
                    r.write(k, d)
                else:
                    r.render(k)
            best_wall = max(best_wall, n / (time.perf_counter() - t0))
            best_cpu = max(best_cpu, n / max(time.process_time() - c0, 1e-9))
    return best_wall, best_cpu


def bundled_states(n_frames: int) -> dict[str, FaceState]:
    """The bundled default head and level-limit head through the animation stage, when
    that stage exists (neutral frames: the renderer's cost does not depend on the FAPs)."""
    out = {}
    try:
        from fbaconf.animation.engine import animate  # noqa: PLC0415 (the stage is optional here)
        from fbaconf.bitstreams.frames import FapFrames  # noqa: PLC0415 (optional, as above)

        out["default head"] = animate(FapFrames.empty(n_frames), scene=None)
        from fbaconf.generators.models import level_limit_scene  # noqa: PLC0415 (optional, as above)

        out["level-limit head"] = animate(FapFrames.empty(n_frames), scene=level_limit_scene())
    except Exception as e:  # noqa: BLE001 - the animation stage is optional for this benchmark
        print(f"(bundled heads unavailable: {type(e).__name__}: {e})")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    if hasattr(os, "sched_setaffinity"):
        try:
            os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
        except OSError:
            pass
    states = bundled_states(args.frames)
    for name, (pts, tris) in {
        "synthetic ~2.5k tris": head_mesh(36, 36),
        "synthetic 5k verts": head_mesh(72, 70),
    }.items():
        states[name] = animated_state(pts, tris, args.frames)
    print(f"fbaconf reference rasteriser, 256x256, one core, best of {args.repeat} x {args.frames} frames")
    print("fps = frames per second of wall-clock time (CPU time in brackets: unaffected by other load)")
    print(f"{'mesh':<22}{'verts':>7}{'tris':>7}  {'ss':>2}  {'render fps':>16}  {'render+PNG fps':>16}")
    for name, state in states.items():
        n_tri = sum(p.triangles.shape[0] for p in state.parts)
        for ss in (1, 3):
            w, c = bench(state, ss, args.frames, args.repeat, write=False)
            ww, cw = bench(state, ss, args.frames, args.repeat, write=True)
            print(
                f"{name:<22}{state.vertices.shape[1]:>7}{n_tri:>7}  {ss:>2}  {w:>7.1f} ({c:>6.1f})"
                f"  {ww:>7.1f} ({cw:>6.1f})"
            )
    sys.stdout.flush()
    side_by_side(states, args.frames, args.repeat)
    return 0


def side_by_side(states: dict, n_frames: int, repeat: int) -> None:
    """The reference against llvmpipe (examples/glrender) at 3 x 3 supersampling, same frames."""
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "examples" / "glrender"))
    try:
        glrender = importlib.import_module("glrender")
        ctx = glrender.gl_context()
    except Exception as e:  # noqa: BLE001 - no moderngl / no GL context: say so and stop
        print(f"\nreference vs OpenGL: skipped ({type(e).__name__}: {e})")
        return
    print(f"\nreference vs OpenGL ({ctx.info['GL_RENDERER']}), 256x256, 3x3 supersampling, same frames, one core")
    print(f"{'mesh':<22}{'reference fps':>15}{'OpenGL fps':>12}{'ratio':>8}")
    sc = Scenario.default().with_(supersample=3, width=256, height=256)
    for name, state in states.items():
        n = min(n_frames, state.n_frames)
        ref, gl = Renderer(state, sc), glrender.GLRenderer(state, sc, "ssaa3")
        rates = []
        for fn in (ref.render, gl.render_srgb8):
            fn(0)
            best = 0.0
            for _ in range(repeat):
                t0 = time.perf_counter()
                for k in range(n):
                    fn(k)
                best = max(best, n / (time.perf_counter() - t0))
            rates.append(best)
        gl.release()
        print(f"{name:<22}{rates[0]:>15.1f}{rates[1]:>12.1f}{rates[0] / rates[1]:>7.2f}x")
    sys.stdout.flush()


if __name__ == "__main__":
    sys.exit(main())
