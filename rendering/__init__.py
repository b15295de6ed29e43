"""The reference renderer: a deterministic software rasteriser (pure numpy, float64).

Modules
-------
:mod:`.render`: ``render_frames(state, scenario, out_dir, *, scene_dir=None) -> list[Path]``
    one image per scenario frame: ``out_dir/frame_00000.png`` (8-bit sRGB) or ``.exr``
    (linear float32), named by the frame index in the FaceState; written atomically;
    ``render_frame(state, k, scenario, *, scene_dir=None) -> float64[H, W, 3]`` linear RGB;
    ``Renderer(state, scenario, *, scene_dir=None)``: ``.render(k)``, ``.write(k, out_dir)``,
    ``.camera`` (the resolved camera), ``.skipped_near`` (triangles skipped per frame).
:mod:`.scenario`: ``Scenario`` (TOML): ``Scenario.load(path)``, ``Scenario.default()``,
    ``.to_toml()``, ``.save(path)``; errors ``ScenarioError`` (file + dotted key) and
    ``TextFormatError``.
:mod:`.images`: ``write_png``, ``write_exr``, ``read_image``, ``encode_srgb8``.

Conventions (camera, coverage, clipping, depth ties, lighting, textures, anti-aliasing)
are specified in :mod:`fbaconf.rendering.raster`; scenario keys in
:mod:`fbaconf.rendering.scenario`.
"""
