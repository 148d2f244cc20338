"""Scene schema: frozen dataclasses and the validation of a parsed TOML dictionary.

Every key of SCENE_FORMAT.md is here, with its type, default and allowed range; the README's
"Scene format" table lists the same keys. ``validate(raw, file)`` turns a dictionary (as
read from TOML, after ``-D`` overrides) into a ``SceneSpec`` or raises ``SceneError`` naming
the file and the dotted key (``medium.phase.g``, ``lights[1].irradiance``).
"""

import difflib
import math
from dataclasses import dataclass
from typing import Optional, Union

from .errors import SceneError

Vec3 = tuple[float, float, float]
RGB = tuple[float, float, float]

CAMERA_TYPES = ("perspective", "orthographic")
PHASE_TYPES = ("isotropic", "hg")
LIGHT_TYPES = ("environment", "directional", "point")
GENERATORS = ("cloud",)


@dataclass(frozen=True)
class Camera:
    """Pinhole or orthographic camera. Lengths in world units, fov in degrees (vertical)."""
    type: str = "perspective"
    eye: Vec3 = (0.0, 0.0, 4.0)
    target: Vec3 = (0.0, 0.0, 0.0)
    up: Vec3 = (0.0, 1.0, 0.0)
    fov: float = 45.0
    size: float = 2.0
    resolution: tuple[int, int] = (256, 256)


@dataclass(frozen=True)
class ConstantDensity:
    """Homogeneous medium: density is this number everywhere in the box."""
    value: float


@dataclass(frozen=True)
class FileDensity:
    """Density grid read from a .npy, .npz (array "density") or Mitsuba .vol file."""
    path: str          # as written in the scene
    resolved: str      # absolute path (relative paths are relative to the scene file)


@dataclass(frozen=True)
class GeneratedDensity:
    """Procedural density grid, e.g. the "cloud" generator at resolution^3 voxels."""
    generator: str
    resolution: int
    seed: int = 0


Density = Union[ConstantDensity, FileDensity, GeneratedDensity]


@dataclass(frozen=True)
class Phase:
    """Phase function: "isotropic" or Henyey-Greenstein "hg" with asymmetry g in (-1, 1)."""
    type: str = "isotropic"
    g: float = 0.0


@dataclass(frozen=True)
class Medium:
    """Axis-aligned box of medium: extinction = scale * density (1/world unit)."""
    bounds: tuple[Vec3, Vec3]
    density: Density
    scale: float = 1.0
    albedo: RGB = (1.0, 1.0, 1.0)
    phase: Phase = Phase()


@dataclass(frozen=True)
class EnvironmentLight:
    """Constant radiance arriving from every direction."""
    radiance: RGB
    type: str = "environment"


@dataclass(frozen=True)
class DirectionalLight:
    """Parallel light travelling along ``direction`` (unit) with ``irradiance``."""
    direction: Vec3
    irradiance: RGB
    type: str = "directional"


@dataclass(frozen=True)
class PointLight:
    """Isotropic point light with radiant ``intensity`` (per steradian)."""
    position: Vec3
    intensity: RGB
    type: str = "point"


Light = Union[EnvironmentLight, DirectionalLight, PointLight]


@dataclass(frozen=True)
class Render:
    """Integrator settings."""
    spp: int = 64
    max_depth: int = 64
    rr_depth: int = 5
    seed: int = 0
    max_steps: int = 1_000_000
    transmittance: str = "ratio"
    majorant: str = "grid"
    free_flight: str = "delta"
    majorant_resolution: tuple = ()


@dataclass(frozen=True)
class SceneSpec:
    """A validated scene description (grids not loaded yet)."""
    file: str
    camera: Camera
    medium: Medium
    lights: tuple
    render: Render


# (key, default or REQUIRED); the kind of each key is checked in the section functions.
REQUIRED = object()
CAMERA_KEYS = ("type", "eye", "target", "up", "fov", "size", "resolution")
MEDIUM_KEYS = ("bounds", "density", "scale", "albedo", "phase")
PHASE_KEYS = ("type", "g")
RENDER_KEYS = ("spp", "max_depth", "rr_depth", "seed", "max_steps", "transmittance", "majorant",
               "majorant_resolution", "free_flight")
MAJORANTS = ("global", "grid")
FREE_FLIGHTS = ("delta", "decomposition")
#: Shadow-ray transmittance estimators for grids: every estimator of the registry in
#: volmc/reference/estimators.py except "analytic" (which needs a homogeneous segment).
TRANSMITTANCE_ESTIMATORS = ("ratio", "residual_ratio", "next_flight", "track_length",
                            "power_series", "unbiased_raymarch", "biased_raymarch")
LIGHT_KEYS = {
    "environment": ("type", "radiance"),
    "directional": ("type", "direction", "irradiance"),
    "point": ("type", "position", "intensity"),
}
TOP_KEYS = ("camera", "medium", "lights", "render")
FILE_DENSITY_KEYS = ("file",)
GENERATOR_KEYS = ("generator", "resolution", "seed")


class _Checker:
    """Type and range checks that raise SceneError naming the file and dotted key."""

    def __init__(self, file):
        self.file = file

    def fail(self, key, msg):
        raise SceneError(self.file, key, msg)

    def table(self, value, key):
        if not isinstance(value, dict):
            self.fail(key, f"expected a table, got {_show(value)}")
        return value

    def known(self, table, allowed, prefix):
        for k in table:
            if k not in allowed:
                near = difflib.get_close_matches(k, allowed, n=1)
                hint = f" (did you mean '{near[0]}'?)" if near else \
                    f" (allowed: {', '.join(allowed)})"
                self.fail(f"{prefix}{k}", f"unknown key{hint}")

    def required(self, table, k, prefix):
        if k not in table:
            self.fail(f"{prefix}{k}", "missing required key")
        return table[k]

    def number(self, v, key, lo=-math.inf, hi=math.inf, lo_open=False, hi_open=False):
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(key, f"expected a number, got {_show(v)}")
        v = float(v)
        if not math.isfinite(v):
            self.fail(key, f"must be finite, got {v}")
        if v < lo or (lo_open and v == lo) or v > hi or (hi_open and v == hi):
            lb = "(" if lo_open else "["
            hb = ")" if hi_open else "]"
            self.fail(key, f"must be in {lb}{_fmt(lo)}, {_fmt(hi)}{hb}, got {_fmt(v)}")
        return v

    def integer(self, v, key, lo=None, hi=None):
        if isinstance(v, bool) or not isinstance(v, int):
            self.fail(key, f"expected an integer, got {_show(v)}")
        if lo is not None and v < lo:
            self.fail(key, f"must be >= {lo}, got {v}")
        if hi is not None and v > hi:
            self.fail(key, f"must be <= {hi}, got {v}")
        return v

    def choice(self, v, key, options):
        if not isinstance(v, str):
            self.fail(key, f"expected a string, one of {', '.join(options)}; got {_show(v)}")
        if v not in options:
            self.fail(key, f"must be one of {', '.join(repr(o) for o in options)}, got {v!r}")
        return v

    def vec3(self, v, key, nonzero=False):
        if not isinstance(v, list) or len(v) != 3:
            self.fail(key, f"expected a list of 3 numbers, got {_show(v)}")
        out = tuple(self.number(x, key) for x in v)
        if nonzero and all(x == 0.0 for x in out):
            self.fail(key, "must not be the zero vector")
        return out

    def rgb(self, v, key, hi=math.inf):
        """A number or [r, g, b], each in [0, hi]."""
        if isinstance(v, list):
            if len(v) != 3:
                self.fail(key, f"expected a number or a list of 3 numbers, got {_show(v)}")
            return tuple(self.number(x, key, 0.0, hi) for x in v)
        x = self.number(v, key, 0.0, hi)
        return (x, x, x)


def _fmt(x):
    return f"{x:g}"


def _show(v):
    text = repr(v)
    if len(text) > 40:
        text = text[:37] + "..."
    return f"{type(v).__name__} {text}"


def _camera(c, raw):
    p = "camera."
    c.known(raw, CAMERA_KEYS, p)
    d = Camera()
    cam_type = c.choice(raw.get("type", d.type), p + "type", CAMERA_TYPES)
    eye = c.vec3(raw.get("eye", list(d.eye)), p + "eye")
    target = c.vec3(raw.get("target", list(d.target)), p + "target")
    up = c.vec3(raw.get("up", list(d.up)), p + "up", nonzero=True)
    fov = c.number(raw.get("fov", d.fov), p + "fov", 0.0, 180.0, lo_open=True, hi_open=True)
    size = c.number(raw.get("size", d.size), p + "size", 0.0, lo_open=True)
    res = raw.get("resolution", list(d.resolution))
    if not isinstance(res, list) or len(res) != 2:
        c.fail(p + "resolution", f"expected [width, height], got {_show(res)}")
    res = tuple(c.integer(x, p + "resolution", lo=1) for x in res)
    fwd = [target[i] - eye[i] for i in range(3)]
    if all(x == 0.0 for x in fwd):
        c.fail(p + "target", "must differ from camera.eye")
    cross = (fwd[1] * up[2] - fwd[2] * up[1], fwd[2] * up[0] - fwd[0] * up[2],
             fwd[0] * up[1] - fwd[1] * up[0])
    nf = math.sqrt(sum(x * x for x in fwd))
    nu = math.sqrt(sum(x * x for x in up))
    if math.sqrt(sum(x * x for x in cross)) <= 1e-9 * nf * nu:
        c.fail(p + "up", "must not be parallel to the viewing direction (target - eye)")
    return Camera(cam_type, eye, target, up, fov, size, res)


def _density(c, v, file_dir):
    import os
    key = "medium.density"
    if isinstance(v, dict):
        if "file" in v and "generator" in v:
            c.fail(key, "give either 'file' or 'generator', not both")
        if "file" in v:
            c.known(v, FILE_DENSITY_KEYS, key + ".")
            path = v["file"]
            if not isinstance(path, str) or not path:
                c.fail(key + ".file", f"expected a file path, got {_show(path)}")
            resolved = path if os.path.isabs(path) else os.path.join(file_dir, path)
            return FileDensity(path, os.path.abspath(resolved))
        if "generator" in v:
            c.known(v, GENERATOR_KEYS, key + ".")
            gen = c.choice(v["generator"], key + ".generator", GENERATORS)
            res = c.integer(c.required(v, "resolution", key + "."), key + ".resolution",
                            lo=1, hi=2048)
            seed = c.integer(v.get("seed", 0), key + ".seed", lo=0, hi=2**63 - 1)
            return GeneratedDensity(gen, res, seed)
        c.fail(key, "a density table needs 'file' or 'generator'")
    return ConstantDensity(c.number(v, key, 0.0))


def _medium(c, raw, file_dir):
    p = "medium."
    c.known(raw, MEDIUM_KEYS, p)
    b = c.required(raw, "bounds", p)
    if not isinstance(b, list) or len(b) != 2:
        c.fail(p + "bounds", f"expected [[xmin, ymin, zmin], [xmax, ymax, zmax]], got {_show(b)}")
    lo = c.vec3(b[0], p + "bounds")
    hi = c.vec3(b[1], p + "bounds")
    for a, name in enumerate("xyz"):
        if not lo[a] < hi[a]:
            what = "zero size" if lo[a] == hi[a] else "inverted"
            c.fail(p + "bounds", f"box has {what} along {name} ({_fmt(lo[a])} .. {_fmt(hi[a])});"
                                 " need min < max on every axis")
    density = _density(c, c.required(raw, "density", p), file_dir)
    scale = c.number(raw.get("scale", 1.0), p + "scale", 0.0)
    albedo = c.rgb(raw.get("albedo", 1.0), p + "albedo", hi=1.0)
    ph = c.table(raw.get("phase", {"type": "isotropic"}), p + "phase")
    c.known(ph, PHASE_KEYS, p + "phase.")
    ptype = c.choice(c.required(ph, "type", p + "phase."), p + "phase.type", PHASE_TYPES)
    g = 0.0
    if ptype == "hg":
        g = c.number(c.required(ph, "g", p + "phase."), p + "phase.g", -1.0, 1.0,
                     lo_open=True, hi_open=True)
    elif "g" in ph:
        c.fail(p + "phase.g", "only the 'hg' phase function takes g")
    return Medium((lo, hi), density, scale, albedo, Phase(ptype, g))


def _light(c, raw, i):
    p = f"lights[{i}]."
    c.table(raw, p[:-1])
    ltype = c.choice(c.required(raw, "type", p), p + "type", LIGHT_TYPES)
    c.known(raw, LIGHT_KEYS[ltype], p)
    if ltype == "environment":
        return EnvironmentLight(c.rgb(c.required(raw, "radiance", p), p + "radiance"))
    if ltype == "directional":
        direction = c.vec3(c.required(raw, "direction", p), p + "direction", nonzero=True)
        n = math.sqrt(sum(x * x for x in direction))
        return DirectionalLight(tuple(x / n for x in direction),
                                c.rgb(c.required(raw, "irradiance", p), p + "irradiance"))
    return PointLight(c.vec3(c.required(raw, "position", p), p + "position"),
                      c.rgb(c.required(raw, "intensity", p), p + "intensity"))


def _render(c, raw):
    p = "render."
    c.known(raw, RENDER_KEYS, p)
    d = Render()
    return Render(
        spp=c.integer(raw.get("spp", d.spp), p + "spp", lo=1),
        max_depth=c.integer(raw.get("max_depth", d.max_depth), p + "max_depth", lo=-1,
                            hi=2**31 - 1),
        rr_depth=c.integer(raw.get("rr_depth", d.rr_depth), p + "rr_depth", lo=0, hi=2**31 - 1),
        seed=c.integer(raw.get("seed", d.seed), p + "seed", lo=0, hi=2**64 - 1),
        max_steps=c.integer(raw.get("max_steps", d.max_steps), p + "max_steps", lo=1,
                            hi=2**31 - 1),
        transmittance=c.choice(raw.get("transmittance", d.transmittance), p + "transmittance",
                               TRANSMITTANCE_ESTIMATORS),
        majorant=c.choice(raw.get("majorant", d.majorant), p + "majorant", MAJORANTS),
        free_flight=c.choice(raw.get("free_flight", d.free_flight), p + "free_flight",
                             FREE_FLIGHTS),
        majorant_resolution=_majorant_resolution(c, raw.get("majorant_resolution", [])),
    )


def _majorant_resolution(c, v):
    """[] (automatic) or [cx, cy, cz] cells, each in [1, 256]."""
    key = "render.majorant_resolution"
    if not isinstance(v, list) or len(v) not in (0, 3):
        c.fail(key, f"expected [] (automatic) or [cx, cy, cz], got {_show(v)}")
    return tuple(c.integer(x, key, lo=1, hi=256) for x in v)


def validate(raw: dict, file: str, file_dir: Optional[str] = None) -> SceneSpec:
    """Validate a scene dictionary; raise SceneError(file, key, message) on the first problem."""
    import os
    c = _Checker(file)
    file_dir = file_dir if file_dir is not None else os.path.dirname(os.path.abspath(file))
    c.known(raw, TOP_KEYS, "")
    camera = _camera(c, c.table(c.required(raw, "camera", ""), "camera"))
    medium = _medium(c, c.table(c.required(raw, "medium", ""), "medium"), file_dir)
    lights_raw = raw.get("lights", [])
    if not isinstance(lights_raw, list):
        c.fail("lights", f"expected an array of tables ([[lights]]), got {_show(lights_raw)}")
    lights = tuple(_light(c, lt, i) for i, lt in enumerate(lights_raw))
    render = _render(c, c.table(raw.get("render", {}), "render"))
    return SceneSpec(str(file), camera, medium, lights, render)
