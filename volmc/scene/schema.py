"""Scene schema: frozen dataclasses and the validation of a parsed TOML dictionary.

Every key of docs/scene_format.md is here, with its type, default and allowed range; the table
of docs/scenes.md lists the same keys. ``validate(raw, file)`` turns a dictionary (as
read from TOML, after ``-D`` overrides) into a ``SceneSpec`` or raises ``SceneError`` naming
the file and the dotted key (``medium.phase.g``, ``lights[1].irradiance``).
"""

import difflib
import json
import math
import re
import struct
import sys
from dataclasses import MISSING, dataclass, field, fields, is_dataclass
from typing import Optional, Union, get_args

from ..constants import MAX_MEDIA
from ..techniques import ESTIMATORS, chromatic_estimators, grid_estimators
from .errors import SceneError
from .transform import parse as parse_transform

Vec3 = tuple[float, float, float]
RGB = tuple[float, float, float]

CAMERA_TYPES = ("perspective", "orthographic", "panoramic")
PHASE_TYPES = ("isotropic", "hg")
#: Procedural sources and the fields each returns, in order (``channel``; generators.py
#: returns a tuple when there are several).
#: Samples per pixel: the kernels index a pixel's samples with a uint32.
MAX_SPP = 2**32 - 1
GENERATORS = {"cloud": ("density",), "plume": ("density", "temperature")}
#: Formats that hold several named grids (``grid`` picks one).
NAMED_GRID_SUFFIXES = (".npz", ".vdb", ".nvdb")
#: Largest finite float32: every number reaches the kernels as a float32.
FLOAT32_MAX = 3.4028234663852886e38


@dataclass(frozen=True)
class Camera:
    """Perspective (pinhole or thin lens), orthographic or panoramic camera. Lengths in world
    units, fov in degrees (vertical). ``aperture``: the lens radius (0: a pinhole);
    ``focus_distance``: the distance of the plane in focus along the view direction, None
    for the distance from eye to target (a validated scene always holds the number)."""
    type: str = "perspective"
    eye: Vec3 = (0.0, 0.0, 4.0)
    target: Vec3 = (0.0, 0.0, 0.0)
    up: Vec3 = (0.0, 1.0, 0.0)
    fov: float = 45.0
    size: float = 2.0
    resolution: tuple[int, int] = (256, 256)
    aperture: float = 0.0
    focus_distance: Optional[float] = None


@dataclass(frozen=True)
class ConstantDensity:
    """Homogeneous medium: density is this number everywhere in the box."""
    value: float


@dataclass(frozen=True)
class FileDensity:
    """Grid read from a .npy, .npz (array ``grid``), Mitsuba .vol, OpenVDB .vdb or NanoVDB
    .nvdb (grid ``grid``) file."""
    path: str          # as written in the scene
    resolved: str      # absolute path (relative paths are relative to the scene file)
    grid: str = "density"


@dataclass(frozen=True)
class GeneratedDensity:
    """Procedural grid: the ``channel`` field ("density", or "temperature" for "plume") of
    a generator at resolution^3 voxels."""
    generator: str
    resolution: int
    seed: int = 0
    channel: str = "density"


@dataclass(frozen=True, eq=False)
class ArrayDensity:
    """Grid given as a numpy array [z, y, x] (a scene built in Python); validated when the
    scene is loaded, as a grid file is (loading.py)."""
    array: object

    def __repr__(self):
        return f"ArrayDensity(shape={getattr(self.array, 'shape', None)}, " \
               f"dtype={getattr(self.array, 'dtype', None)})"


Density = Union[ConstantDensity, FileDensity, GeneratedDensity, ArrayDensity]


@dataclass(frozen=True)
class Phase:
    """Phase function: "isotropic" or Henyey-Greenstein "hg" with asymmetry g in (-1, 1)."""
    type: str = "isotropic"
    g: float = 0.0


@dataclass(frozen=True)
class Emission:
    """Emitted radiance Le(x) of the medium (its source term is sigma_a(x) Le(x)): either
    ``radiance`` (RGB) x ``field``(x), or the blackbody radiance of ``temperature``(x)
    (kelvin) in linear sRGB, in nits, x ``scale`` (volmc/emission.py)."""
    radiance: Optional[RGB] = None
    field: Density = ConstantDensity(1.0)
    temperature: Optional[Density] = None
    scale: float = 1.0
    # (v_min, v_max, T_min, T_max): the temperature grid holds a flame-style field whose
    # values v map to T_min + clamp((v - v_min) / (v_max - v_min), 0, 1) (T_max - T_min)
    # kelvin, voxel by voxel (loading.load_emission); None: it holds kelvin.
    remap: Optional[tuple] = None


@dataclass(frozen=True)
class Medium:
    """A box of medium: extinction = scale * density per channel (1/world unit). ``bounds`` is
    the box in the medium's local space, None only before a VDB file has given it
    (loading.py); ``transform`` places that space in the world (a 4x4 row-major affine matrix,
    world = M x local; None: the identity; convention in transform.py)."""
    bounds: Optional[tuple[Vec3, Vec3]]
    density: Density
    scale: RGB = (1.0, 1.0, 1.0)
    albedo: RGB = (1.0, 1.0, 1.0)
    phase: Phase = Phase()
    emission: Optional[Emission] = None
    transform: Optional[tuple] = None

    @property
    def chromatic(self):
        """True when extinction depends on colour (the scale's channels differ)."""
        return not self.scale[0] == self.scale[1] == self.scale[2]


@dataclass(frozen=True)
class EnvironmentLight:
    """Radiance arriving from every direction: constant, or a lat-long map (``file``, read
    by scene/envmap.py; conventions in reference/environment.py) times ``radiance`` x
    ``strength``, turned by ``rotation`` (3x3, world = rotation x map; None: unturned)."""
    radiance: RGB
    type: str = "environment"
    file: Optional[str] = None        # as written in the scene
    resolved: Optional[str] = None    # absolute path
    strength: float = 1.0
    rotation: Optional[tuple] = None
    # The map's float32 [H, W, 3] texels once loaded (scene/loading.py), so a scene sent to
    # cluster workers carries them as it carries its grids.
    texels: object = field(default=None, compare=False, repr=False)


@dataclass(frozen=True)
class DirectionalLight:
    """Light travelling along ``direction`` (unit) with ``irradiance`` on a surface facing
    it: parallel (``angle`` 0), or a sun disc of full apex ``angle`` degrees whose radiance
    is uniform over its cone (reference/lights.py)."""
    direction: Vec3
    irradiance: RGB
    type: str = "directional"
    angle: float = 0.0


@dataclass(frozen=True)
class SpotLight:
    """A point light at ``position`` shining along ``direction`` (unit): ``intensity`` on
    the axis, falling off to 0 at ``angle`` degrees (the half-angle) by a smoothstep over
    the outer ``blend`` fraction of the cone (reference/lights.py, spot_falloff)."""
    position: Vec3
    direction: Vec3
    intensity: RGB
    angle: float
    blend: float = 0.0
    type: str = "spot"


@dataclass(frozen=True)
class SphereLight:
    """An opaque sphere of ``radius`` at ``position`` whose surface emits ``radiance``
    uniformly on both sides (``power`` in the scene file: radiance = power / (4 pi^2 r^2))."""
    position: Vec3
    radius: float
    radiance: RGB
    type: str = "sphere"


@dataclass(frozen=True)
class PointLight:
    """Isotropic point light with radiant ``intensity`` (per steradian)."""
    position: Vec3
    intensity: RGB
    type: str = "point"


Light = Union[EnvironmentLight, DirectionalLight, PointLight, SpotLight, SphereLight]


@dataclass(frozen=True)
class Render:
    """Integrator settings."""
    spp: int = 64
    max_depth: int = 64
    rr_depth: int = 5
    seed: int = 0
    max_steps: int = 1_000_000
    transmittance: str = "auto"
    majorant: str = "grid"
    majorant_resolution: tuple = ()
    free_flight: str = "delta"
    spectral: str = "hero"
    grid_storage: str = "auto"
    mis: str = "balance"
    sampler: str = "independent"
    light_samples: int = 1
    equiangular: bool = False
    rr: str = "throughput"
    transparent_background: bool = False
    env_sampling: str = "importance"
    env_compensation: bool = False
    emission_sampling: str = "collision"


@dataclass(frozen=True)
class SceneSpec:
    """A validated scene description (grids not loaded yet). ``medium`` is the first medium
    (a ``[medium]`` table, or ``[[media]]``'s first), ``others`` the rest of ``[[media]]``;
    ``media`` is all of them, in file order."""
    file: str
    camera: Camera
    medium: Medium
    lights: tuple
    render: Render
    others: tuple = ()

    @property
    def media(self):
        return (self.medium,) + tuple(self.others)

    @property
    def chromatic(self):
        """True when extinction depends on colour in some medium."""
        return any(m.chromatic for m in self.media)


#: Where a section's TOML keys differ from its dataclass's fields: field -> the keys that set
#: it (none: the field is not a key). Every other field is a key of the same name, in field
#: order; ``_keys`` derives the key lists below from this table and the dataclasses.
_KEYS_OF_FIELD = {
    SceneSpec: {"file": (),                      # the scene file's path, not a key
                "medium": ("medium", "media"),   # [medium], or the first of [[media]]
                "others": ()},                   # the rest of [[media]]
    FileDensity: {"path": ("file",),             # as written in the scene
                  "resolved": ()},               # the absolute path, worked out
    EnvironmentLight: {"resolved": (), "texels": ()},   # worked out / loaded later
    SphereLight: {"radiance": ("radiance", "power")},   # or power / (4 pi^2 radius^2)
}


def _keys(cls):
    """The TOML keys of dataclass ``cls``'s table, in field order."""
    renamed = _KEYS_OF_FIELD.get(cls, {})
    return tuple(k for f in fields(cls) for k in renamed.get(f.name, (f.name,)))


def _defaults(cls):
    """{field: default} of the fields of dataclass ``cls`` that have one."""
    return {f.name: f.default for f in fields(cls) if f.default is not MISSING}


CAMERA_KEYS = _keys(Camera)
MEDIUM_KEYS = _keys(Medium)
EMISSION_KEYS = _keys(Emission)
PHASE_KEYS = _keys(Phase)
RENDER_KEYS = _keys(Render)
#: How emission reaches a scattering vertex (render.emission_sampling; docs/emission.md).
EMISSION_SAMPLINGS = ("collision", "light", "mis")
ENV_SAMPLINGS = ("importance", "uniform")
MIS_HEURISTICS = ("balance", "power")
SAMPLERS = ("independent", "stratified", "sobol")
RR_RULES = ("throughput", "albedo")
#: Most light samples per light and scattering vertex (render.light_samples).
MAX_LIGHT_SAMPLES = 1024
GRID_STORAGES = ("auto", "dense", "bricks")
SPECTRAL_MODES = ("tracking", "hero", "channel")
MAJORANTS = ("global", "grid", "octree")
FREE_FLIGHTS = ("delta", "decomposition")
#: Shadow-ray transmittance estimators for grids: every estimator of the registry
#: (volmc/techniques.py) except those exact only on homogeneous segments.
TRANSMITTANCE_ESTIMATORS = grid_estimators()
#: The type of each light class (its ``type`` default) -> the class.
LIGHT_CLASSES = {_defaults(cls)["type"]: cls for cls in get_args(Light)}
#: Each light type's keys, ``type`` (which picks the class) first.
LIGHT_KEYS = {t: ("type",) + tuple(k for k in _keys(cls) if k != "type")
              for t, cls in LIGHT_CLASSES.items()}
LIGHT_TYPES = tuple(LIGHT_CLASSES)
TOP_KEYS = _keys(SceneSpec)
#: The top-level keys that are one table each ([camera], [medium], [render]); the others are
#: arrays of tables ([[lights]], [[media]]).
TABLE_KEYS = tuple(f.name for f in fields(SceneSpec) if is_dataclass(f.type))
FILE_DENSITY_KEYS = _keys(FileDensity)
GENERATOR_KEYS = _keys(GeneratedDensity)


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
                near = difflib.get_close_matches(k, allowed, n=1) if isinstance(k, str) \
                    else []
                hint = f" (did you mean '{near[0]}'?)" if near else \
                    f" (allowed: {', '.join(allowed)})"
                self.fail(f"{prefix}{_key_name(k)}", f"unknown key{hint}")

    def required(self, table, k, prefix):
        if k not in table:
            self.fail(f"{prefix}{k}", "missing required key")
        return table[k]

    def number(self, v, key, lo=-math.inf, hi=math.inf, lo_open=False, hi_open=False):
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(key, f"expected a number, got {_show(v)}")
        try:
            v = float(v)
        except OverflowError:   # an integer beyond the float range
            self.fail(key, f"must be finite, got an integer of {v.bit_length()} bits")
        if not math.isfinite(v):
            self.fail(key, f"must be finite, got {v}")
        if abs(v) > FLOAT32_MAX:
            self.fail(key, f"must be at most {FLOAT32_MAX:g} in magnitude (the kernels use "
                           f"float32), got {_fmt(v)}")
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

    def boolean(self, v, key):
        if not isinstance(v, bool):
            self.fail(key, f"expected true or false, got {_show(v)}")
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


def _key_name(k):
    """A key as TOML writes it: bare if it can be, else quoted (so "" and "a b" show); a
    dict's non-string key as its repr."""
    if not isinstance(k, str):
        return repr(k)
    if re.fullmatch(r"[A-Za-z0-9_-]+", k):
        return k
    return json.dumps(k, ensure_ascii=False)


def _fmt(x):
    """x short ("%g"), unless that rounds it: "got 1" for 1.0000001 hid why it was refused."""
    short = f"{x:g}"
    return short if float(short) == x else repr(float(x))


def _show(v):
    try:
        text = repr(v)
    except ValueError:   # an int beyond Python's str conversion limit
        text = f"<{v.bit_length()} bits>"
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
    if res[0] * res[1] > 2**31 - 1:   # the kernels index pixels with an int
        c.fail(p + "resolution", f"{res[0]} x {res[1]} pixels; at most 2^31 - 1 in all")
    fwd = [target[i] - eye[i] for i in range(3)]
    if all(x == 0.0 for x in fwd):
        c.fail(p + "target", "must differ from camera.eye")
    # The same arithmetic as pack.camera_basis, which normalises target - eye and then
    # forward x up: both lengths must be positive and finite in floating point.
    nf = math.sqrt(sum(x * x for x in fwd))
    if not 0.0 < nf < math.inf:
        c.fail(p + "target", f"target - eye has length {_fmt(nf)} in floating point; "
                             "cannot normalise it")
    nu = math.sqrt(sum(x * x for x in up))
    if not 0.0 < nu < math.inf:
        c.fail(p + "up", f"has length {_fmt(nu)} in floating point; cannot normalise it")
    f = [x / nf for x in fwd]
    cross = (f[1] * up[2] - f[2] * up[1], f[2] * up[0] - f[0] * up[2],
             f[0] * up[1] - f[1] * up[0])
    if not math.sqrt(sum(x * x for x in cross)) > 1e-9 * nu:
        c.fail(p + "up", "must not be parallel to the viewing direction (target - eye)")
    aperture = c.number(raw.get("aperture", d.aperture), p + "aperture", 0.0)
    if cam_type == "panoramic" and aperture > 0.0:
        c.fail(p + "aperture", f"a panoramic camera has no lens; must be 0, got {_fmt(aperture)}")
    focus = raw.get("focus_distance", d.focus_distance)
    focus = nf if focus is None else c.number(focus, p + "focus_distance", 0.0, lo_open=True)
    return Camera(cam_type, eye, target, up, fov, size, res, aperture, focus)


def _source(c, v, key, file_dir, channel="density"):
    """A grid source at ``key``: a number (constant), { file, grid } or { generator,
    resolution, seed, channel }. ``channel`` is the field the key asks of a generator by
    default. A numpy array is a grid given directly (``ArrayDensity``)."""
    import os

    import numpy as np
    if isinstance(v, np.ndarray):
        return ArrayDensity(v)
    if isinstance(v, dict):
        if "file" in v and "generator" in v:
            c.fail(key, "give either 'file' or 'generator', not both")
        if "file" in v:
            c.known(v, FILE_DENSITY_KEYS, key + ".")
            path = v["file"]
            if not isinstance(path, str) or not path:
                c.fail(key + ".file", f"expected a file path, got {_show(path)}")
            suffix = os.path.splitext(path)[1].lower()
            grid = v.get("grid", _defaults(FileDensity)["grid"])
            if not isinstance(grid, str) or not grid:
                c.fail(key + ".grid", f"expected a grid name, got {_show(grid)}")
            if "grid" in v and suffix not in NAMED_GRID_SUFFIXES:
                c.fail(key + ".grid", f"a {suffix} file holds one grid; 'grid' names one of "
                                      f"several in {', '.join(NAMED_GRID_SUFFIXES)} files")
            resolved = path if os.path.isabs(path) else os.path.join(file_dir, path)
            return FileDensity(path, os.path.abspath(resolved), grid)
        if "generator" in v:
            c.known(v, GENERATOR_KEYS, key + ".")
            gen = c.choice(v["generator"], key + ".generator", tuple(GENERATORS))
            res = c.integer(c.required(v, "resolution", key + "."), key + ".resolution",
                            lo=1, hi=2048)
            seed = c.integer(v.get("seed", _defaults(GeneratedDensity)["seed"]), key + ".seed",
                             lo=0, hi=2**63 - 1)
            ch = c.choice(v.get("channel", channel), key + ".channel", GENERATORS[gen])
            return GeneratedDensity(gen, res, seed, ch)
        c.fail(key, "a grid table needs 'file' or 'generator'")
    return ConstantDensity(c.number(v, key, 0.0))


def _density(c, v, file_dir, p="medium."):
    return _source(c, v, p + "density", file_dir)


def _emission(c, raw, file_dir, p="medium.emission."):
    c.table(raw, p[:-1])
    c.known(raw, EMISSION_KEYS, p)
    if ("radiance" in raw) == ("temperature" in raw):
        c.fail(p[:-1], "give either 'radiance' (with an optional 'field') or 'temperature' "
                       "(with an optional 'scale')")
    if "radiance" in raw:
        if "scale" in raw:
            c.fail(p + "scale", "only 'temperature' emission takes a scale; scale the "
                                "radiance instead")
        if "remap" in raw:
            c.fail(p + "remap", "only 'temperature' emission takes a remap (to kelvin)")
        radiance = c.rgb(raw["radiance"], p + "radiance")
        field = _source(c, raw.get("field", _defaults(Emission)["field"].value), p + "field",
                        file_dir)
        return Emission(radiance=radiance, field=field)
    if "field" in raw:
        c.fail(p + "field", "only 'radiance' emission takes a field")
    temperature = _source(c, raw["temperature"], p + "temperature", file_dir, "temperature")
    scale = c.number(raw.get("scale", _defaults(Emission)["scale"]), p + "scale", 0.0)
    remap = None
    if "remap" in raw:
        r = raw["remap"]
        if not isinstance(r, (list, tuple)) or len(r) != 4:
            c.fail(p + "remap", f"expected [v_min, v_max, T_min, T_max] (grid values to "
                                f"kelvin), got {_show(r)}")
        v0, v1 = (c.number(x, p + "remap") for x in r[:2])
        t0, t1 = (c.number(x, p + "remap", 0.0) for x in r[2:])
        if not v0 < v1:
            c.fail(p + "remap", f"needs v_min < v_max, got {_fmt(v0)} and {_fmt(v1)}")
        if not math.isfinite(1.0 / (v1 - v0)):
            c.fail(p + "remap", "v_max - v_min is too small to divide by")
        remap = (v0, v1, t0, t1)
    return Emission(temperature=temperature, scale=scale, remap=remap)


def _medium(c, raw, file_dir, p="medium."):
    c.known(raw, MEDIUM_KEYS, p)
    density = _density(c, c.required(raw, "density", p), file_dir, p)
    from_file = isinstance(density, FileDensity) and \
        density.path.lower().endswith((".vdb", ".nvdb"))
    if "bounds" in raw or not from_file:
        lo, hi = _bounds(c, c.required(raw, "bounds", p), p)
        bounds = (lo, hi)
    else:
        bounds = None   # from the VDB file's active voxels (loading.py)
    d = _defaults(Medium)
    scale = c.rgb(raw.get("scale", list(d["scale"])), p + "scale")
    if isinstance(density, ConstantDensity) and max(scale) * density.value > FLOAT32_MAX:
        c.fail(p + "scale", f"scale * density = {max(scale) * density.value:g} overflows "
                            f"float32 (at most {FLOAT32_MAX:g})")
    albedo = c.rgb(raw.get("albedo", list(d["albedo"])), p + "albedo", hi=1.0)
    ph = c.table(raw.get("phase", {"type": d["phase"].type}), p + "phase")
    c.known(ph, PHASE_KEYS, p + "phase.")
    ptype = c.choice(c.required(ph, "type", p + "phase."), p + "phase.type", PHASE_TYPES)
    g = 0.0
    if ptype == "hg":
        g = c.number(c.required(ph, "g", p + "phase."), p + "phase.g", -1.0, 1.0,
                     lo_open=True, hi_open=True)
        if abs(struct.unpack("f", struct.pack("f", g))[0]) == 1.0:
            # the kernels' HG sampling divides by 1 - g^2 (OpenCL dropped 64 % of the
            # samples as NaN at g = 0.99999999)
            c.fail(p + "phase.g", f"{g!r} rounds to {math.copysign(1, g):+g} in float32, the "
                                  "kernels' precision: |g| at most 0.99999994")
    elif "g" in ph:
        c.fail(p + "phase.g", "only the 'hg' phase function takes g")
    emission = _emission(c, raw["emission"], file_dir, p + "emission.") \
        if "emission" in raw else None
    transform = parse_transform(c, raw["transform"], p + "transform") \
        if "transform" in raw else None
    if transform is not None and bounds is not None:
        check_placed_box(c.fail, transform, bounds, p + "transform")
    return Medium(bounds, density, scale, albedo, Phase(ptype, g), emission, transform)


def _bounds(c, b, p="medium."):
    if not isinstance(b, list) or len(b) != 2:
        c.fail(p + "bounds", f"expected [[xmin, ymin, zmin], [xmax, ymax, zmax]], got {_show(b)}")
    lo = c.vec3(b[0], p + "bounds")
    hi = c.vec3(b[1], p + "bounds")
    check_box(c.fail, lo, hi, p + "bounds")
    return lo, hi


def check_box(fail, lo, hi, key="medium.bounds"):
    """Every axis of the box [lo, hi] has min < max and an extent whose inverse is finite in
    float32; else fail(key, message)."""
    for a, name in enumerate("xyz"):
        if not lo[a] < hi[a]:
            what = "has zero size" if lo[a] == hi[a] else "is inverted"
            fail(key, f"box {what} along {name} ({_fmt(lo[a])} .. {_fmt(hi[a])});"
                      " need min < max on every axis")
        if 1.0 / (hi[a] - lo[a]) > FLOAT32_MAX:   # the kernels hold 1 / extent in float32
            fail(key, f"box is too thin along {name} (extent {_fmt(hi[a] - lo[a])}); "
                      "1 / extent overflows float32")


def check_placed_box(fail, transform, bounds, key):
    """check_box for the world box around ``bounds`` placed by ``transform``: a translation
    far beyond the box's size rounds its extent to 0 in float64 (1e17 + 1 == 1e17)."""
    from .transform import world_box
    lo, hi = world_box(transform, *bounds)
    check_box(lambda _, msg: fail(key, "the placed " + msg), lo, hi)


def _light(c, raw, i, file_dir):
    p = f"lights[{i}]."
    c.table(raw, p[:-1])
    ltype = c.choice(c.required(raw, "type", p), p + "type", LIGHT_TYPES)
    c.known(raw, LIGHT_KEYS[ltype], p)
    if ltype == "environment":
        return _environment(c, raw, p, file_dir)
    if ltype == "directional":
        direction = _unit(c, raw, "direction", p)
        irradiance = c.rgb(c.required(raw, "irradiance", p), p + "irradiance")
        angle = c.number(raw.get("angle", _defaults(DirectionalLight)["angle"]), p + "angle",
                         0.0)
        if not angle < 180.0:
            c.fail(p + "angle", f"the sun's apex angle must be below 180 degrees, got "
                                f"{_fmt(angle)}")
        if angle > 0.0:
            # Its radiance E / (pi sin^2 theta) reaches the kernels as a float32.
            s = math.sin(math.radians(angle) / 2.0)
            if not max(irradiance) / (math.pi * s * s) < FLOAT32_MAX:
                c.fail(p + "angle", f"a sun of {_fmt(angle)} degrees is so small that its "
                                    "radiance overflows float32; use angle = 0")
        return DirectionalLight(direction, irradiance, angle=angle)
    if ltype == "spot":
        angle = c.number(c.required(raw, "angle", p), p + "angle", 0.0)
        if not 0.0 < angle <= 180.0:
            c.fail(p + "angle", f"the cone's half-angle must be in (0, 180] degrees, got "
                                f"{_fmt(angle)}")
        blend = c.number(raw.get("blend", _defaults(SpotLight)["blend"]), p + "blend", 0.0)
        if blend > 1.0:
            c.fail(p + "blend", f"must be in [0, 1], got {_fmt(blend)}")
        return SpotLight(c.vec3(c.required(raw, "position", p), p + "position"),
                         _unit(c, raw, "direction", p),
                         c.rgb(c.required(raw, "intensity", p), p + "intensity"),
                         angle, blend)
    if ltype == "sphere":
        position = c.vec3(c.required(raw, "position", p), p + "position")
        radius = c.number(c.required(raw, "radius", p), p + "radius", 0.0)
        if not radius > 0.0:
            c.fail(p + "radius", "must be > 0 (a point lamp is type = \"point\")")
        if ("radiance" in raw) == ("power" in raw):
            c.fail(p + "radiance", "give exactly one of 'radiance' and 'power'")
        if "power" in raw:
            power = c.rgb(raw["power"], p + "power")
            radiance = tuple(x / (4.0 * math.pi ** 2 * radius * radius) for x in power)
            if not all(math.isfinite(x) for x in radiance) or max(radiance) > FLOAT32_MAX:
                c.fail(p + "power", "the radiance power / (4 pi^2 radius^2) overflows float32")
        else:
            radiance = c.rgb(raw["radiance"], p + "radiance")
        return SphereLight(position, radius, radiance)
    return PointLight(c.vec3(c.required(raw, "position", p), p + "position"),
                      c.rgb(c.required(raw, "intensity", p), p + "intensity"))


def _unit(c, raw, key, p):
    """The unit vector of the nonzero vector raw[key]."""
    direction = c.vec3(c.required(raw, key, p), p + key, nonzero=True)
    # Scale by a power of two first (exact) so that the squares neither underflow nor
    # overflow: a tiny or huge nonzero direction still normalises to a unit vector. A
    # vector that is already unit to rounding is kept, so that validating a written-out
    # scene (serialize.to_dict) gives back the same direction.
    e = math.frexp(max(abs(x) for x in direction))[1]
    scaled = tuple(math.ldexp(x, -e) for x in direction)
    n = math.sqrt(sum(x * x for x in scaled))
    if abs(math.ldexp(n, e) - 1.0) > 4 * sys.float_info.epsilon:
        direction = tuple(x / n for x in scaled)
    return direction


def _environment(c, raw, p, file_dir):
    """An environment light: constant ``radiance``, or a map ``file`` (radiance, default 1,
    multiplies it) with ``strength`` and ``rotation`` (degrees about +y, or rotations
    written as a medium's ``rotate``)."""
    import os
    import numpy as np
    from .transform import _rotations, compose
    if "file" not in raw:
        for k in ("strength", "rotation"):
            if k in raw:
                c.fail(p + k, "applies to an environment map; give 'file'")
        return EnvironmentLight(c.rgb(c.required(raw, "radiance", p), p + "radiance"))
    path = raw["file"]
    if not isinstance(path, str) or not path:
        c.fail(p + "file", f"expected a path to an image file, got {_show(path)}")
    resolved = path if os.path.isabs(path) else os.path.join(file_dir, path)
    radiance = c.rgb(raw.get("radiance", 1.0), p + "radiance")
    strength = c.number(raw.get("strength", _defaults(EnvironmentLight)["strength"]),
                        p + "strength", 0.0)
    rot = raw.get("rotation", 0.0)
    if isinstance(rot, list):
        rots = _rotations(c, rot, p + "rotation")
    else:
        rots = [((0.0, 1.0, 0.0), c.number(rot, p + "rotation"))]
    m = compose(rotations=rots)[:3, :3]
    if not np.all(np.isfinite(m)):
        c.fail(p + "rotation", "the rotation is not finite")
    rotation = None if np.array_equal(m, np.eye(3)) else \
        tuple(tuple(float(x) for x in row) for row in m)
    return EnvironmentLight(radiance, file=path, resolved=resolved, strength=strength,
                            rotation=rotation)


def render_settings(raw, file):
    """The validated ``[render]`` table of raw scene dict ``raw`` alone (no grid is read):
    the settings a complete frame's files are made with (frames.py)."""
    c = _Checker(file)
    return _render(c, c.table(raw.get("render", {}), "render"))


def _render(c, raw):
    p = "render."
    c.known(raw, RENDER_KEYS, p)
    d = Render()
    return Render(
        spp=c.integer(raw.get("spp", d.spp), p + "spp", lo=1, hi=MAX_SPP),  # uint32 sample
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
        majorant_resolution=_majorant_resolution(c, raw.get("majorant_resolution",
                                                            list(d.majorant_resolution))),
        spectral=c.choice(raw.get("spectral", d.spectral), p + "spectral", SPECTRAL_MODES),
        grid_storage=c.choice(raw.get("grid_storage", d.grid_storage), p + "grid_storage",
                              GRID_STORAGES),
        mis=c.choice(raw.get("mis", d.mis), p + "mis", MIS_HEURISTICS),
        sampler=c.choice(raw.get("sampler", d.sampler), p + "sampler", SAMPLERS),
        light_samples=c.integer(raw.get("light_samples", d.light_samples),
                                p + "light_samples", lo=1, hi=MAX_LIGHT_SAMPLES),
        equiangular=c.boolean(raw.get("equiangular", d.equiangular), p + "equiangular"),
        rr=c.choice(raw.get("rr", d.rr), p + "rr", RR_RULES),
        transparent_background=c.boolean(raw.get("transparent_background",
                                                 d.transparent_background),
                                         p + "transparent_background"),
        env_sampling=c.choice(raw.get("env_sampling", d.env_sampling), p + "env_sampling",
                              ENV_SAMPLINGS),
        env_compensation=c.boolean(raw.get("env_compensation", d.env_compensation),
                                   p + "env_compensation"),
        emission_sampling=c.choice(raw.get("emission_sampling", d.emission_sampling),
                                   p + "emission_sampling", EMISSION_SAMPLINGS),
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
    media = _media(c, raw, file_dir)
    lights_raw = raw.get("lights", [])
    if not isinstance(lights_raw, list):
        c.fail("lights", f"expected an array of tables ([[lights]]), got {_show(lights_raw)}")
    lights = tuple(_light(c, lt, i, file_dir) for i, lt in enumerate(lights_raw))
    envs = [i for i, lt in enumerate(lights) if isinstance(lt, EnvironmentLight)]
    maps = [i for i in envs if lights[i].file is not None]
    if maps and len(envs) > 1:
        other = next(i for i in envs if i != maps[0])
        c.fail(f"lights[{other}]", f"lights[{maps[0]}] is an environment map; a scene has "
                                   "one environment when it has a map (fold a constant sky "
                                   "into the map's radiance)")
    env = [0.0, 0.0, 0.0]   # environment lights are summed into one float32 radiance
    for i, lt in enumerate(lights):
        if isinstance(lt, EnvironmentLight):
            env = [env[k] + lt.radiance[k] for k in range(3)]
            if max(env) > FLOAT32_MAX:
                c.fail(f"lights[{i}].radiance", f"the environment radiances sum to "
                                                f"{max(env):g}, which overflows float32")
    render = _render(c, c.table(raw.get("render", {}), "render"))
    est = ESTIMATORS[render.transmittance]
    if any(m.chromatic for m in media) and not est.chromatic:
        c.fail("render.transmittance", f"'{est.name}' estimates grey transmittance only; "
               "medium.scale differs per channel, so use one of "
               f"{', '.join(chromatic_estimators())}")
    return SceneSpec(str(file), camera, media[0], lights, render, media[1:])


def chroma(scale):
    """Extinction per channel relative to the largest channel ((1, 1, 1) when black)."""
    top = max(scale)
    return tuple(x / top for x in scale) if top > 0.0 else (1.0, 1.0, 1.0)


def _media(c, raw, file_dir):
    """The media of a scene: ``[medium]`` (one) or ``[[media]]`` (1 to MAX_MEDIA), never
    both. Several media share one chroma (the ratios of their scale's channels): the kernels
    keep extinction as one scalar field times one per-channel ratio (pack.py)."""
    if "medium" in raw and "media" in raw:
        c.fail("media", "give either [medium] (one medium) or [[media]] (several), not both")
    if "media" not in raw:
        return (_medium(c, c.table(c.required(raw, "medium", ""), "medium"), file_dir),)
    lst = raw["media"]
    if not isinstance(lst, list) or not lst:
        c.fail("media", f"expected a non-empty array of tables ([[media]]), got {_show(lst)}")
    if len(lst) > MAX_MEDIA:
        c.fail("media", f"{len(lst)} media; a scene holds at most {MAX_MEDIA} (and so at most "
                        f"{MAX_MEDIA} overlap at one point)")
    media = tuple(_medium(c, c.table(m, f"media[{i}]"), file_dir, f"media[{i}].")
                  for i, m in enumerate(lst))
    # The ratios of the first medium with extinction (a black one has none to share)
    dark = [max(m.scale) == 0.0 for m in media]
    first = dark.index(False) if False in dark else 0
    k0 = chroma(media[first].scale)
    for i, m in enumerate(media):
        if i <= first or dark[i]:
            continue
        k = chroma(m.scale)
        if max(abs(a - b) for a, b in zip(k, k0)) > 1e-6 * max(k0):
            c.fail(f"media[{i}].scale", f"per-channel ratios {_show(list(k))} differ from "
                   f"media[{first}]'s {_show(list(k0))}: several media must share the ratios "
                   "of their scale's channels (scale them as a whole)")
    return media
