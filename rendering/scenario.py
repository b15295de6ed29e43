"""Scenario files (TOML): how to look at the face — image size, camera, lights, shading.

Example (every key shown; see ``data/default.toml`` for the bundled default)::

    width = 256                  # output image size in pixels (1 .. 16384)
    height = 256
    supersample = 3              # render N x bigger and box-filter down (1 .. 8)
    background = [0.1, 0.1, 0.12]  # sRGB-encoded RGB in [0, 1]
    shading = "gouraud"          # "gouraud" | "flat"
    cull_backfaces = false       # true: drop triangles facing away (CW on screen)
    specular = true              # false: ignore the parts' specular terms
    format = "png"               # "png" (8-bit sRGB) | "exr" (linear float)
    frames = [0, 5, 10]          # optional: frame indices, or {start=0, stop=10, step=1}

    [camera]
    fit = true                   # frame frame 0's bounding box automatically, or give
    fov_deg = 25.0               #   position/look_at (/up/near/far) with fit = false
    direction = [0, 0, -1]       # (fit) direction the camera looks along
    up = [0, 1, 0]
    margin = 1.1                 # (fit) the bounding box fills 1/margin of the view
    fit_to = "first"             # (fit) box of frame 0 ("first") or of all frames ("all")

    [ambient]
    color = [1, 1, 1]            # linear RGB
    intensity = 0.2

    [[lights]]                   # directional lights, any number
    direction = [-0.4, -0.5, -1] # direction the light travels (VRML DirectionalLight)
    color = [1, 1, 1]            # linear RGB
    intensity = 0.8

Light and ambient colours are linear RGB; the background is sRGB-encoded (as a colour
picker shows it) and decoded with colour-science before compositing.

Errors: TOML syntax -> :class:`TextFormatError` (line:column); anything else
(unknown key, wrong type, out of range) -> :class:`ScenarioError` naming the file and
the dotted key.
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field, fields, replace
from importlib import resources
from pathlib import Path

import numpy as np

from fbaconf._atomic import atomic_write_text
from fbaconf.errors import TextFormatError

from .errors import ScenarioError
from .raster import Camera

SHADINGS = ("gouraud", "flat")
FORMATS = ("png", "exr")
FIT_TO = ("first", "all")
MAX_SIZE = 16384
MAX_SUPERSAMPLE = 8


@dataclass(frozen=True)
class DirectionalLight:
    direction: tuple[float, float, float]
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    intensity: float = 1.0


@dataclass(frozen=True)
class CameraSpec:
    fit: bool = True
    fov_deg: float = 30.0
    # fit = false
    position: tuple[float, float, float] | None = None
    look_at: tuple[float, float, float] | None = None
    near: float | None = None
    far: float | None = None
    # both
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    # fit = true
    direction: tuple[float, float, float] = (0.0, 0.0, -1.0)
    margin: float = 1.1
    fit_to: str = "first"  # "first": bounding box of frame 0; "all": of every frame


@dataclass(frozen=True)
class FrameRange:
    start: int = 0
    stop: int | None = None  # exclusive; None = to the last frame
    step: int = 1


@dataclass(frozen=True)
class Scenario:
    width: int = 256
    height: int = 256
    supersample: int = 1
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    shading: str = "gouraud"
    cull_backfaces: bool = False
    specular: bool = True
    format: str = "png"
    frames: tuple[int, ...] | FrameRange | None = None
    camera: CameraSpec = field(default_factory=CameraSpec)
    ambient_color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    ambient_intensity: float = 0.0
    lights: tuple[DirectionalLight, ...] = ()

    # ------------------------------------------------------------------ derived
    def frame_indices(self, n_frames: int) -> list[int]:
        """The frame indices to render for a sequence of ``n_frames`` frames."""
        if self.frames is None:
            return list(range(n_frames))
        if isinstance(self.frames, FrameRange):
            stop = n_frames if self.frames.stop is None else self.frames.stop
            idx = list(range(self.frames.start, stop, self.frames.step))
        else:
            idx = list(self.frames)
        for k in idx:
            if not 0 <= k < n_frames:
                raise ScenarioError(
                    f"frame {k} out of range: the sequence has {n_frames} frames",
                    key="frames",
                    rule="scenario-frame-range",
                )
        return idx

    def resolve_camera(self, vertices0: np.ndarray) -> Camera:
        """The concrete camera; ``fit`` frames the bounding box of the points ``vertices0``
        (the renderer passes frame 0, or every frame with ``fit_to = "all"``).

        Fit (deterministic): the camera looks along ``direction`` at the box centre c from
        the smallest distance at which all 8 box corners project inside the image shrunk by
        ``margin`` (corner (x, y, z) in view coordinates relative to c needs
        ``distance >= margin * |x| / tan(h_half) - z`` and ``margin * |y| / tan(v_half) - z``);
        near = half the depth of the nearest corner, far = twice that of the farthest. An
        empty or single-point box is treated as a unit cube around its centre."""
        cam = self.camera
        if not cam.fit:
            return Camera(
                position=cam.position,
                look_at=cam.look_at,
                up=cam.up,
                fov_deg=cam.fov_deg,
                near=0.1 if cam.near is None else cam.near,
                far=1e5 if cam.far is None else cam.far,
            )
        v = np.asarray(vertices0, dtype=np.float64).reshape(-1, 3)
        v = v[np.all(np.isfinite(v), axis=1)]
        if v.shape[0] == 0:
            lo = hi = np.zeros(3)
        else:
            lo, hi = v.min(axis=0), v.max(axis=0)
        c = (lo + hi) / 2.0
        half = (hi - lo) / 2.0
        if not np.any(half > 0.0):
            half = np.full(3, 0.5)
        c_t = tuple(float(x) for x in c)
        probe = Camera(position=tuple(float(x) for x in c - np.asarray(cam.direction)), look_at=c_t, up=cam.up)
        right, tup, fwd = probe.basis()
        tan_v = math.tan(math.radians(cam.fov_deg) / 2.0)
        tan_h = tan_v * self.width / self.height
        dist, zmin, zmax = 0.0, math.inf, -math.inf
        for sx in (-1.0, 1.0):
            for sy in (-1.0, 1.0):
                for sz in (-1.0, 1.0):
                    p = half * np.array([sx, sy, sz])
                    x = float(p[0] * right[0] + p[1] * right[1] + p[2] * right[2])
                    y = float(p[0] * tup[0] + p[1] * tup[1] + p[2] * tup[2])
                    z = float(p[0] * fwd[0] + p[1] * fwd[1] + p[2] * fwd[2])
                    dist = max(dist, cam.margin * abs(x) / tan_h - z, cam.margin * abs(y) / tan_v - z)
                    zmin, zmax = min(zmin, z), max(zmax, z)
        dist = max(dist, -zmin + 1e-6 * (zmax - zmin + 1.0))
        pos = c - dist * fwd
        near = (dist + zmin) / 2.0
        return Camera(
            position=tuple(float(x) for x in pos),
            look_at=c_t,
            up=cam.up,
            fov_deg=cam.fov_deg,
            near=near,
            far=2.0 * (dist + zmax),
        )

    # ------------------------------------------------------------------ I/O
    @classmethod
    def from_toml(cls, text: str, *, file: str | None = None) -> Scenario:
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            msg = str(e)
            m = re.search(r"\(at line (\d+), column (\d+)\)", msg)
            line, col = (int(m.group(1)), int(m.group(2))) if m else (1, 1)
            raise TextFormatError(
                re.sub(r"\s*\(at line \d+, column \d+\)", "", msg) or "invalid TOML",
                line=line,
                column=col,
                rule="toml-syntax",
                file=file,
            ) from None
        return cls.from_dict(data, file=file)

    @classmethod
    def load(cls, path) -> Scenario:
        path = Path(path)
        try:
            raw = path.read_bytes()
        except OSError as e:
            raise ScenarioError(
                f"cannot read scenario: {e.strerror or e}", file=str(path), rule="scenario-unreadable"
            ) from None
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as e:
            raise ScenarioError(
                f"scenario is not UTF-8 (byte {e.start})", file=str(path), rule="scenario-encoding"
            ) from None
        return cls.from_toml(text, file=str(path))

    @classmethod
    def default(cls) -> Scenario:
        """The bundled default scenario (``rendering/data/default.toml``)."""
        ref = resources.files("fbaconf.rendering").joinpath("data/default.toml")
        return cls.from_toml(ref.read_text(encoding="utf-8"), file="<bundled default.toml>")

    @classmethod
    def from_dict(cls, data: dict, *, file: str | None = None) -> Scenario:
        return _Parser(file).scenario(data)

    def to_toml(self) -> str:
        """Every key written explicitly; ``Scenario.from_toml(s.to_toml()) == s``."""
        out = [
            f"width = {self.width}",
            f"height = {self.height}",
            f"supersample = {self.supersample}",
            f"background = {_fmt(self.background)}",
            f"shading = {_fmt(self.shading)}",
            f"cull_backfaces = {_fmt(self.cull_backfaces)}",
            f"specular = {_fmt(self.specular)}",
            f"format = {_fmt(self.format)}",
        ]
        if isinstance(self.frames, FrameRange):
            fr = self.frames
            stop = "" if fr.stop is None else f", stop = {fr.stop}"
            out.append(f"frames = {{ start = {fr.start}{stop}, step = {fr.step} }}")
        elif self.frames is not None:
            out.append(f"frames = {_fmt(self.frames)}")
        c = self.camera
        out += ["", "[camera]", f"fit = {_fmt(c.fit)}", f"fov_deg = {_fmt(c.fov_deg)}", f"up = {_fmt(c.up)}"]
        if c.fit:
            out += [f"direction = {_fmt(c.direction)}", f"margin = {_fmt(c.margin)}", f"fit_to = {_fmt(c.fit_to)}"]
        else:
            out += [f"position = {_fmt(c.position)}", f"look_at = {_fmt(c.look_at)}"]
            if c.near is not None:
                out.append(f"near = {_fmt(c.near)}")
            if c.far is not None:
                out.append(f"far = {_fmt(c.far)}")
        out += ["", "[ambient]", f"color = {_fmt(self.ambient_color)}", f"intensity = {_fmt(self.ambient_intensity)}"]
        for lt in self.lights:
            out += [
                "",
                "[[lights]]",
                f"direction = {_fmt(lt.direction)}",
                f"color = {_fmt(lt.color)}",
                f"intensity = {_fmt(lt.intensity)}",
            ]
        return "\n".join(out) + "\n"

    def save(self, path) -> None:
        atomic_write_text(path, self.to_toml())

    def with_(self, **changes) -> Scenario:
        return replace(self, **changes)


def _fmt(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("nan" if v != v else ("inf" if v > 0 else "-inf"))
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (tuple, list)):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


class _Parser:
    def __init__(self, file: str | None) -> None:
        self.file = file

    def err(self, key: str, msg: str, rule: str = "scenario-value") -> ScenarioError:
        return ScenarioError(msg, key=key, file=self.file, rule=rule)

    def table(self, d, key: str, allowed: set[str]) -> dict:
        if not isinstance(d, dict):
            raise self.err(key, f"expected a table, got {_tname(d)}", "scenario-type")
        for k in d:
            if k not in allowed:
                full = f"{key}.{k}" if key else k
                raise self.err(full, f"unknown key (allowed: {', '.join(sorted(allowed))})", "scenario-unknown-key")
        return d

    def int_(self, d, name, key, default, lo, hi) -> int:
        v = d.get(name, default)
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.err(key, f"expected an integer, got {_tname(v)}", "scenario-type")
        if not lo <= v <= hi:
            raise self.err(key, f"{v} out of range [{lo}, {hi}]", "scenario-range")
        return v

    def num(self, d, name, key, default, lo=-math.inf, hi=math.inf, lo_open=False) -> float:
        v = d.get(name, default)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.err(key, f"expected a number, got {_tname(v)}", "scenario-type")
        v = float(v)
        if not math.isfinite(v):
            raise self.err(key, "must be finite", "scenario-range")
        if v < lo or v > hi or (lo_open and v == lo):
            lo_s = "(" if lo_open else "["
            raise self.err(key, f"{v} out of range {lo_s}{lo}, {hi}]", "scenario-range")
        return v

    def bool_(self, d, name, key, default) -> bool:
        v = d.get(name, default)
        if not isinstance(v, bool):
            raise self.err(key, f"expected true or false, got {_tname(v)}", "scenario-type")
        return v

    def vec3(self, d, name, key, default, lo=-math.inf, hi=math.inf, nonzero=False):
        v = d.get(name, default)
        if v is None:
            return None
        if not isinstance(v, (list, tuple)) or len(v) != 3:
            raise self.err(key, f"expected an array of 3 numbers, got {_tname(v)}", "scenario-type")
        out = []
        for i, x in enumerate(v):
            if isinstance(x, bool) or not isinstance(x, (int, float)):
                raise self.err(f"{key}[{i}]", f"expected a number, got {_tname(x)}", "scenario-type")
            x = float(x)
            if not math.isfinite(x) or x < lo or x > hi:
                raise self.err(f"{key}[{i}]", f"{x} out of range [{lo}, {hi}]", "scenario-range")
            out.append(x)
        if nonzero and all(x == 0.0 for x in out):
            raise self.err(key, "must not be the zero vector", "scenario-range")
        return tuple(out)

    def choice(self, d, name, key, default, options) -> str:
        v = d.get(name, default)
        if v not in options:
            raise self.err(key, f"expected one of {', '.join(repr(o) for o in options)}, got {v!r}", "scenario-choice")
        return v

    def scenario(self, data: dict) -> Scenario:
        top = {f.name for f in fields(Scenario)} - {"ambient_color", "ambient_intensity"} | {"ambient"}
        d = self.table(data, "", top)
        base = Scenario()
        width = self.int_(d, "width", "width", base.width, 1, MAX_SIZE)
        height = self.int_(d, "height", "height", base.height, 1, MAX_SIZE)
        ss = self.int_(d, "supersample", "supersample", base.supersample, 1, MAX_SUPERSAMPLE)
        if width * ss > MAX_SIZE or height * ss > MAX_SIZE:
            raise self.err(
                "supersample", f"supersampled image {width * ss}x{height * ss} exceeds {MAX_SIZE}", "scenario-range"
            )
        bg = self.vec3(d, "background", "background", base.background, 0.0, 1.0)
        shading = self.choice(d, "shading", "shading", base.shading, SHADINGS)
        fmt = self.choice(d, "format", "format", base.format, FORMATS)
        cull = self.bool_(d, "cull_backfaces", "cull_backfaces", base.cull_backfaces)
        spec = self.bool_(d, "specular", "specular", base.specular)
        frames = self.frames(d.get("frames"))
        camera = self.camera(d.get("camera", {}))
        amb = self.table(d.get("ambient", {}), "ambient", {"color", "intensity"})
        amb_c = self.vec3(amb, "color", "ambient.color", (1.0, 1.0, 1.0), 0.0)
        amb_i = self.num(amb, "intensity", "ambient.intensity", 0.0, 0.0)
        lights_raw = d.get("lights", [])
        if not isinstance(lights_raw, list):
            raise self.err(
                "lights", f"expected an array of tables ([[lights]]), got {_tname(lights_raw)}", "scenario-type"
            )
        lights = []
        for i, lt in enumerate(lights_raw):
            k = f"lights[{i}]"
            lt = self.table(lt, k, {"direction", "color", "intensity"})
            if "direction" not in lt:
                raise self.err(f"{k}.direction", "missing (the direction the light travels)", "scenario-missing")
            lights.append(
                DirectionalLight(
                    direction=self.vec3(lt, "direction", f"{k}.direction", None, nonzero=True),
                    color=self.vec3(lt, "color", f"{k}.color", (1.0, 1.0, 1.0), 0.0),
                    intensity=self.num(lt, "intensity", f"{k}.intensity", 1.0, 0.0),
                )
            )
        return Scenario(
            width=width,
            height=height,
            supersample=ss,
            background=bg,
            shading=shading,
            cull_backfaces=cull,
            specular=spec,
            format=fmt,
            frames=frames,
            camera=camera,
            ambient_color=amb_c,
            ambient_intensity=amb_i,
            lights=tuple(lights),
        )

    def frames(self, v):
        if v is None:
            return None
        if isinstance(v, list):
            out = []
            for i, x in enumerate(v):
                if isinstance(x, bool) or not isinstance(x, int) or x < 0:
                    raise self.err(f"frames[{i}]", f"expected a frame index >= 0, got {x!r}", "scenario-type")
                out.append(x)
            return tuple(out)
        if isinstance(v, dict):
            t = self.table(v, "frames", {"start", "stop", "step"})
            start = self.int_(t, "start", "frames.start", 0, 0, 2**62)
            stop = None if "stop" not in t else self.int_(t, "stop", "frames.stop", 0, 0, 2**62)
            step = self.int_(t, "step", "frames.step", 1, 1, 2**62)
            return FrameRange(start, stop, step)
        raise self.err(
            "frames", f"expected an array of indices or {{start, stop, step}}, got {_tname(v)}", "scenario-type"
        )

    def camera(self, v) -> CameraSpec:
        allowed = {f.name for f in fields(CameraSpec)}
        c = self.table(v, "camera", allowed)
        base = CameraSpec()
        fit = self.bool_(c, "fit", "camera.fit", "position" not in c and "look_at" not in c)
        fov = self.num(c, "fov_deg", "camera.fov_deg", base.fov_deg, 0.0, 179.0, lo_open=True)
        up = self.vec3(c, "up", "camera.up", base.up, nonzero=True)
        if fit:
            for k in ("position", "look_at", "near", "far"):
                if k in c:
                    raise self.err(f"camera.{k}", "not allowed with camera.fit = true", "scenario-conflict")
            direction = self.vec3(c, "direction", "camera.direction", base.direction, nonzero=True)
            margin = self.num(c, "margin", "camera.margin", base.margin, 1.0, 100.0)
            fit_to = self.choice(c, "fit_to", "camera.fit_to", base.fit_to, FIT_TO)
            if _parallel(direction, up):
                raise self.err("camera.up", "parallel to camera.direction", "scenario-conflict")
            return CameraSpec(fit=True, fov_deg=fov, up=up, direction=direction, margin=margin, fit_to=fit_to)
        for k in ("direction", "margin", "fit_to"):
            if k in c:
                raise self.err(f"camera.{k}", "only allowed with camera.fit = true", "scenario-conflict")
        for k in ("position", "look_at"):
            if k not in c:
                raise self.err(f"camera.{k}", "missing (required when camera.fit = false)", "scenario-missing")
        pos = self.vec3(c, "position", "camera.position", None)
        look = self.vec3(c, "look_at", "camera.look_at", None)
        if pos == look:
            raise self.err("camera.look_at", "equals camera.position", "scenario-conflict")
        fwd = tuple(b - a for a, b in zip(pos, look))
        if _parallel(fwd, up):
            raise self.err("camera.up", "parallel to the viewing direction", "scenario-conflict")
        near = None if "near" not in c else self.num(c, "near", "camera.near", 0.1, 0.0, lo_open=True)
        far = None if "far" not in c else self.num(c, "far", "camera.far", 1e5, 0.0, lo_open=True)
        if (near if near is not None else 0.1) >= (far if far is not None else 1e5):
            raise self.err("camera.far", "must be greater than camera.near", "scenario-conflict")
        return CameraSpec(fit=False, fov_deg=fov, position=pos, look_at=look, near=near, far=far, up=up)


def _parallel(a, b) -> bool:
    cx = a[1] * b[2] - a[2] * b[1]
    cy = a[2] * b[0] - a[0] * b[2]
    cz = a[0] * b[1] - a[1] * b[0]
    na = math.sqrt(a[0] ** 2 + a[1] ** 2 + a[2] ** 2)
    nb = math.sqrt(b[0] ** 2 + b[1] ** 2 + b[2] ** 2)
    return math.sqrt(cx * cx + cy * cy + cz * cz) <= 1e-12 * na * nb


def _tname(v) -> str:
    if isinstance(v, bool):
        return "a boolean"
    if isinstance(v, int):
        return "an integer"
    if isinstance(v, float):
        return "a float"
    if isinstance(v, str):
        return f"the string {v!r}"
    if isinstance(v, list):
        return f"an array of {len(v)}"
    if isinstance(v, dict):
        return "a table"
    return type(v).__name__
