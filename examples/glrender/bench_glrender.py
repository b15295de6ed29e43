#!/usr/bin/env python3
"""Render speed of glrender (OpenGL through moderngl) against fbaconf's reference rasteriser,
frames/s at 256x256 on the same frames, without PNG I/O.

Meshes as in benchmarks/bench_render.py (the bundled default head and level-limit head
through the animation stage, and its two synthetic animated heads), under the bundled
default scenario at 256 x 256. glrender: ``render_srgb8`` per frame (upload of the frame's
vertices and normals, draw, resolve, encode, read back 8-bit sRGB). Reference:
``Renderer.render`` (linear float, no encoding) at N x N supersampling.

    python examples/glrender/bench_glrender.py [--frames N] [--repeat R]

fps = frames per second of wall-clock time; in brackets per second of the process's CPU
time (all threads: llvmpipe renders on several, the reference on one).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent.parent / "benchmarks"))

import glrender  # noqa: E402
from bench_render import animated_state, bundled_states, head_mesh  # noqa: E402

GL_VARIANTS = ("ssaa2", "ssaa3", "ssaa4", "msaa4", "msaa4-centroid", "msaa8")
REF_SS = (2, 3, 8)


def _time(fn, n: int, repeat: int) -> tuple[float, float]:
    fn(0)  # warm-up (shader compile, JIT)
    best_w = best_c = 0.0
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        for k in range(n):
            fn(k)
        best_w = max(best_w, n / (time.perf_counter() - t0))
        best_c = max(best_c, n / max(time.process_time() - c0, 1e-9))
    return best_w, best_c


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args(argv)
    from fbaconf.rendering.render import Renderer
    from fbaconf.rendering.scenario import Scenario

    ctx = glrender.gl_context()
    states = bundled_states(a.frames)
    pts, tris = head_mesh(72, 70)
    states["synthetic 5k verts"] = animated_state(pts, tris, a.frames)
    base = Scenario.default().with_(width=256, height=256)
    print(
        f"256x256, best of {a.repeat} x {a.frames} frames; GL: {ctx.info['GL_RENDERER']}, "
        f"{os.cpu_count()} CPUs; fps wall (CPU)"
    )
    for name, state in states.items():
        n = min(a.frames, state.n_frames)
        n_tri = sum(p.triangles.shape[0] for p in state.parts)
        print(f"\n{name}: {state.vertices.shape[1]} vertices, {n_tri} triangles")
        for v in GL_VARIANTS:
            try:
                r = glrender.GLRenderer(state, base, v)
            except glrender.NotSupported as e:
                print(f"  glrender {v:<15} not supported: {e}")
                continue
            w, c = _time(r.render_srgb8, n, a.repeat)
            r.release()
            print(f"  glrender {v:<15} {w:8.1f} ({c:7.1f})")
        for ss in REF_SS:
            r = Renderer(state, base.with_(supersample=ss))
            w, c = _time(r.render, n, a.repeat)
            print(f"  reference ss{ss:<13} {w:8.1f} ({c:7.1f})")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
