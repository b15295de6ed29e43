"""Animation speed of the reference engine: a 30 s sequence at 30 Hz (900 frames).

Prints frames/s for the bundled default head and the Predictable-L1 level-limit model
(5,000 vertices), with every low-level FAP and an expression + viseme varying smoothly.
Run: python benchmarks/bench_animate.py
"""

from __future__ import annotations

import time

import numpy as np

from fbaconf.animation import engine
from fbaconf.bitstreams.frames import SET, FapFrames
from fbaconf.bitstreams.tables import fap_table
from fbaconf.generators import models


def sequence(seconds: float = 30.0, rate: float = 30.0) -> FapFrames:
    n = int(round(seconds * rate))
    fr = FapFrames.empty(n, frame_rate=rate)
    t = np.arange(n) / rate
    for f in fap_table()[2:]:
        amp = 20000.0 if f.fapu == "AU" else 200.0
        fr.values[:, f.number - 1] = np.round(amp * np.sin(2 * np.pi * (0.3 + 0.05 * f.number) * t + f.number))
        fr.status[:, f.number - 1] = SET
    # every third FAP left free so the high-level FAPs and left/right fill have work to do
    fr.status[:, 2::3] = 0
    fr.status[:, :2] = SET
    fr.high[:, 0] = (np.arange(n) // 5) % 14 + 1
    fr.high[:, 1] = (np.arange(n) // 5 + 1) % 14 + 1
    fr.high[:, 2] = (np.arange(n) % 5) * 63 // 4
    fr.high[:, 4] = (np.arange(n) // 60) % 6 + 1
    fr.high[:, 5] = np.round(31.5 + 31.5 * np.sin(t))
    return fr


def bench(name: str, scene, frames: FapFrames, repeat: int = 3) -> None:
    t0 = time.perf_counter()
    model = engine.compile_scene(scene)
    t_compile = time.perf_counter() - t0
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        st = engine.animate_model(frames, model)
        best = min(best, time.perf_counter() - t0)
    print(
        f"{name:<22} {st.vertices.shape[1]:>6} vertices  compile {t_compile * 1e3:7.1f} ms  "
        f"animate {len(frames)} frames in {best:6.3f} s = {len(frames) / best:8.0f} frames/s"
    )


def main() -> None:
    fr = sequence()
    print(f"animation benchmark: {len(fr)} frames (30 s at 30 Hz)")
    bench("default head", None, fr)
    bench("level-limit (5,000 v)", models.level_limit_scene(), fr)
    bench("logo", models.logo_scene(), fr)


if __name__ == "__main__":
    main()
