"""Loading a scene: TOML file -> ``-D`` overrides -> validation -> grid -> ``Scene``.

``-D`` overrides name a dotted key path and a TOML value: ``render.spp=256``,
``medium.albedo=[0.9, 0.8, 0.7]``, ``medium.phase.g=0.3``, ``lights.1.irradiance=5``
(array elements by 0-based index). A value that is not valid TOML is taken as a string, so
``camera.type=orthographic`` works unquoted.
"""

import math
import os
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Optional

import numpy as np

from .hostmem import require_host
from .errors import SceneError
from .bricks import BrickGrid
from .transform import as_tuple
from .grids import load_grid, load_peak_bytes, shape_text, validate_grid, value_problem
from .schema import (FLOAT32_MAX, GENERATORS, ArrayDensity, ConstantDensity, FileDensity,
                     GeneratedDensity, SceneSpec, TABLE_KEYS, _show, check_box,
                     check_placed_box, validate)


@dataclass(frozen=True)
class Scene:
    """A validated scene with its grids loaded.

    ``grid`` is the float32 [z, y, x] density array, or None for a homogeneous medium;
    ``emission_grid`` the float32 [z, y, x] emission field (radiance emission) or temperature
    (kelvin) spanning the medium box, a 1x1x1 array for a constant one, None without emission.
    A VDB density's bounds are in ``spec.medium.bounds`` once loaded. These describe the
    first medium; a scene of several media (``[[media]]``) has ``parts``, one one-medium
    Scene per medium (the first is grid and emission_grid's), which ``media_scenes`` lists.
    """
    spec: SceneSpec
    grid: Optional[np.ndarray] = field(default=None, compare=False, repr=False)
    emission_grid: Optional[np.ndarray] = field(default=None, compare=False, repr=False)
    parts: tuple = field(default=(), compare=False, repr=False)

    @property
    def media_scenes(self):
        """One Scene per medium, each with this scene's camera, lights and render: the
        scene itself when it has one medium."""
        return self.parts if self.parts else (self,)

    @property
    def media(self):
        return self.spec.media

    @property
    def file(self):
        return self.spec.file

    @property
    def camera(self):
        return self.spec.camera

    @property
    def medium(self):
        return self.spec.medium

    @property
    def lights(self):
        return self.spec.lights

    @property
    def render(self):
        return self.spec.render

    def with_render(self, **keys):
        """This scene with some ``render`` keys replaced (spp, seed, techniques); the
        grid is shared, not copied. The values are taken as given (not re-validated)."""
        spec = replace(self.spec, render=replace(self.spec.render, **keys))
        parts = tuple(p.with_render(**keys) for p in self.parts)
        return Scene(spec, self.grid, self.emission_grid, parts)


def require_one_medium(scene, what):
    """SceneError unless ``scene`` has one medium: for the tools (``what``) that replay or
    analyse one medium's grid."""
    if len(scene.spec.media) > 1:
        raise SceneError(scene.file, "media", f"{what} takes one medium; this scene has "
                                              f"{len(scene.spec.media)}")


def read_toml(path):
    """Parse a TOML file; unreadable or malformed files raise SceneError."""
    try:
        with open(path, "rb") as f:
            data = f.read()
        # A byte-order mark (Windows Notepad writes one) is not TOML, nor text in the file.
        return tomllib.loads(data.removeprefix(b"\xef\xbb\xbf").decode("utf-8"))
    except FileNotFoundError:
        raise SceneError(path, "", "scene file not found") from None
    except IsADirectoryError:
        raise SceneError(path, "", "is a directory, not a scene file") from None
    except OSError as e:
        raise SceneError(path, "", f"cannot read: {e.strerror}") from None
    except UnicodeDecodeError:
        raise SceneError(path, "", "not a text (UTF-8) file") from None
    except tomllib.TOMLDecodeError as e:
        raise SceneError(path, "", f"malformed TOML: {e}") from None
    except ValueError as e:   # e.g. an integer longer than Python's 4300-digit limit
        raise SceneError(path, "", f"malformed TOML: {(str(e).splitlines() or [''])[0]}") from None
    except RecursionError:
        raise SceneError(path, "", "malformed TOML: arrays or tables nested too deeply") \
            from None


def parse_override(text, file):
    """Split ``section.key=value`` into (["section", "key"], python value)."""
    if "=" not in text:
        raise SceneError(file, f"-D {text}", "expected section.key=value")
    key, value = text.split("=", 1)
    key = key.strip()
    parts = key.split(".")
    if len(parts) < 2 or any(not p.strip() for p in parts):
        raise SceneError(file, f"-D {text}", "expected section.key=value")
    value = value.strip()
    if value == "":
        raise SceneError(file, f"-D {text}", "missing value after '='")
    try:
        parsed = tomllib.loads(f"v = {value}")["v"]
    except (ValueError, RecursionError):   # not TOML (or too long/deep for tomllib)
        parsed = value
    return [p.strip() for p in parts], parsed


def _is_index(part):
    """An array index: ASCII digits only ("²".isdigit() is true, but int("²") fails)."""
    return part.isascii() and part.isdigit()


def apply_overrides(raw, overrides, file):
    """Apply overrides to a raw scene dictionary, in order: ``-D`` strings
    (``section.key=value``, the value parsed as TOML), or a mapping of dotted keys to values
    taken as given (``{"render.spp": 16, "lights": [...]}``; a key may then name a whole
    section)."""
    if isinstance(overrides, Mapping):
        for key, value in overrides.items():
            if not isinstance(key, str) or not key or \
                    any(not p.strip() for p in key.split(".")):
                raise SceneError(file, repr(key), "expected a dotted key such as 'render.spp'")
            _set_key(raw, [p.strip() for p in key.split(".")], value, file, key)
        return raw
    for text in overrides:
        parts, value = parse_override(text, file)
        _set_key(raw, parts, value, file, f"-D {text}")
    return raw


def _set_key(raw, parts, value, file, label):
    """Set the dotted key ``parts`` of ``raw`` to ``value``; errors name ``label``."""
    top = parts[0]
    # An override into a table the file gives as something else is the file's error,
    # reported as the schema reports it (not as the override's).
    if len(parts) > 1 and top in TABLE_KEYS and isinstance(raw, dict) and top in raw \
            and not isinstance(raw[top], dict):
        raise SceneError(file, top, f"expected a table, got {_show(raw[top])}")
    node = raw
    for depth, part in enumerate(parts[:-1]):
        shown = ".".join(parts[:depth + 1])
        if isinstance(node, list):
            if not _is_index(part) or int(part) >= len(node):
                raise SceneError(file, label,
                                 f"'{shown}': no element {part} (there are {len(node)})")
            node = node[int(part)]
        elif isinstance(node, dict):
            if part not in node:
                node[part] = {}
            node = node[part]
        else:
            raise SceneError(file, label, f"'{shown}' is not a table")
    last = parts[-1]
    if isinstance(node, list):
        if not _is_index(last) or int(last) >= len(node):
            raise SceneError(file, label, f"no element {last} (there are {len(node)})")
        node[int(last)] = value
    elif isinstance(node, dict):
        node[last] = value
    else:
        raise SceneError(file, label, f"'{'.'.join(parts[:-1])}' is not a table")


def _read_source(spec, src, key, vdb_density=None, cache=None):
    """(float32 [z, y, x] array or None, VdbGrid or None) of a grid source: a file or a
    generator. A VDB grid comes back as its VdbGrid alone (array None: the caller decides
    whether it needs the dense array), unless it is a field placed onto the VDB density's
    voxels (``vdb_density``) by index; ``cache`` (a dict) keeps generator outputs for the
    other fields of one scene."""
    if isinstance(src, FileDensity):
        if not os.path.exists(src.resolved):
            raise SceneError(spec.file, key + ".file", f"grid file not found: {src.path}")
        if not os.path.isfile(src.resolved):   # (a directory or FIFO was "not found" below)
            raise SceneError(spec.file, key + ".file", f"not a regular file: {src.path}")
        if src.resolved.lower().endswith((".vdb", ".nvdb")):
            from .vdb import read_vdb
            vg = read_vdb(src.resolved, src.grid, key)
            if vdb_density is not None:
                return _align_vdb(vg, vdb_density, src.resolved, key), vg
            return None, vg
        return load_grid(src.resolved, key, src.grid), None
    if isinstance(src, GeneratedDensity):
        from . import generators
        key_g = (src.generator, src.resolution, src.seed)
        if cache is not None and key_g in cache:
            out = cache[key_g]
        else:
            shape = generators._parse_resolution(src.resolution)
            n_fields = len(GENERATORS[src.generator])
            # Every field's float32 array; validate_grid adds its masks to the first.
            voxels = math.prod(shape)
            require_host((n_fields - 1) * 4 * voxels + load_peak_bytes(voxels),
                         spec.file, key + ".resolution",
                         f"generating a {'x'.join(map(str, shape))} {src.generator}")
            out = getattr(generators, src.generator)(src.resolution, src.seed)
            if cache is not None:   # density and temperature of one plume: generate once
                cache[key_g] = out
        if isinstance(out, tuple):   # several fields: density first
            out = out[GENERATORS[src.generator].index(src.channel)]
        return out, None
    if isinstance(src, ArrayDensity):
        # Validated here like a grid file; the scene keeps its own copy, so editing the
        # caller's array later cannot invalidate the checks or the majorants.
        grid = validate_grid(src.array, spec.file, key)
        return (grid.copy() if np.shares_memory(grid, src.array) else grid), None
    raise TypeError(src)


def _dense(vg, path, key):
    """The VDB grid ``vg`` expanded over its active bounding box (float32), once the host
    memory is known to hold it."""
    voxels = math.prod(vg.shape)
    require_host(load_peak_bytes(voxels), path, key,
                 f"expanding grid '{vg.name}' to a dense {shape_text(vg.shape)} array")
    return vg.to_dense()


def _align_vdb(vg, density, path, key):
    """Grid ``vg`` on the voxels of the VDB density grid, over the density's active box.
    Where the two share their voxel size and lattice (the grids of one simulation cache),
    each density voxel gets vg's value there exactly, as OpenVDB's getValue gives it (active
    or not: vg's inactive voxels and tiles outside its own active box count). Otherwise (another
    resolution, a shifted or turned lattice: Mantaflow's upres noise grids beside its
    base-resolution ones, a Pyro field at half resolution) vg is resampled at the density's
    voxel centres by trilinear interpolation in world space, as a renderer that samples each
    grid in world space sees it; a finer vg is point-sampled there, not filtered."""
    lin = np.asarray(density.linear)
    shift = np.linalg.solve(lin, np.subtract(vg.index_to_world, density.index_to_world))
    lo_d = np.asarray(density.bbox[0])
    hi_d = np.asarray(density.bbox[1])
    shape = tuple(int(x) for x in (hi_d - lo_d + 1)[::-1])
    what = f"placing grid '{vg.name}' on the density's {shape_text(shape)} voxels"
    same = np.allclose(vg.linear, lin, rtol=1e-6, atol=1e-6 * float(np.abs(lin).max()))
    if same and np.allclose(shift, np.round(shift), atol=1e-4):
        # vg's index of density index j is j - shift: read vg there, active or not (its
        # inactive leaf voxels and tiles outside its own active box hold their values too).
        require_host(load_peak_bytes(math.prod(shape)), path, key, what)
        s = np.round(shift).astype(np.int64)
        return vg.dense_box(lo_d - s, hi_d - s)
    # The box of vg's voxels the density's voxel centres interpolate, cut to where vg
    # stores anything (its background beyond), read with a copy padded by one voxel.
    to_vg = np.linalg.inv(np.asarray(vg.linear, np.float64))
    corners = np.array([[(lo_d, hi_d)[(n >> a) & 1][a] for a in range(3)] for n in range(8)])
    u = (corners @ lin.T + np.subtract(density.index_to_world, vg.index_to_world)) @ to_vg.T
    s_lo, s_hi = vg.stored_box()
    lo_f = np.maximum(np.floor(u.min(axis=0)).astype(np.int64), s_lo)
    hi_f = np.minimum(np.ceil(u.max(axis=0)).astype(np.int64), s_hi)
    if np.any(lo_f > hi_f):
        return np.full(shape, np.float32(vg.background), np.float32)
    require_host(8 * int(np.prod(hi_f - lo_f + 3)) + load_peak_bytes(math.prod(shape)),
                 path, key, what)
    return _resample(vg.dense_box(lo_f, hi_f), lo_f, vg, density, shape)


def _resample(dense, lo_f, vg, density, shape):
    """vg's values (``dense``, [z, y, x] over its index box from ``lo_f``, outside which it
    holds its background) trilinearly interpolated at the centres of the density's voxels
    (``shape``, [z, y, x] over its active box), one z-slab at a time."""
    to_vg = np.linalg.inv(np.asarray(vg.linear, np.float64))
    lin_d = np.asarray(density.linear, np.float64)
    # vg's index of density index j: A j + c, as an offset from the dense box's corner.
    A = to_vg @ lin_d
    c = to_vg @ (np.asarray(density.index_to_world, np.float64)
                 - np.asarray(vg.index_to_world, np.float64)) - np.asarray(lo_f)
    n_vg = np.array(dense.shape[::-1])               # x, y, z
    padded = np.pad(dense, 1, constant_values=np.float32(vg.background))
    out = np.empty(shape, np.float32)
    nz, ny, nx = shape
    lo = np.asarray(density.bbox[0], np.float64)
    y, x = np.mgrid[0:ny, 0:nx].astype(np.float64)
    for k in range(nz):
        j = np.stack([x + lo[0], y + lo[1], np.full_like(x, lo[2] + k)], axis=-1)
        u = j @ A.T + c                                # [ny, nx, 3] in vg's box, x y z
        # One voxel of background all round: indices clipped into the padding read it.
        u = np.clip(u, -1.0, n_vg.astype(np.float64))
        i0 = np.floor(u).astype(np.int64)
        t = u - i0
        i0 += 1                                        # into the padded array
        acc = np.zeros((ny, nx))
        for corner in range(8):
            d = [(corner >> axis) & 1 for axis in range(3)]
            w = np.ones((ny, nx))
            for axis in range(3):
                w = w * (t[..., axis] if d[axis] else 1.0 - t[..., axis])
            idx = [np.minimum(i0[..., axis] + d[axis], n_vg[axis] + 1) for axis in range(3)]
            acc += w * padded[idx[2], idx[1], idx[0]]
        out[k] = acc
    return out


def _vdb_bricks(vg, path, key):
    """A VDB grid (background 0) as a BrickGrid straight from its 8^3 leaves and tiles, its
    stored values checked as validate_grid checks an array. Inactive tiles of another value
    than the background become blocks here, under a memory check, before the leaves (which
    win where a corrupt file overlaps them)."""
    problem = value_problem(vg.values_in_bbox())   # what the bricks keep, as dense reads
    if problem:
        raise SceneError(path, key, f"grid '{vg.name}' contains {problem}")
    lo, hi = (np.asarray(c) for c in vg.bbox)
    dims = tuple(int(x) for x in hi - lo + 1)
    origins, values = np.asarray(vg.origins), vg.values
    if len(vg.fill_boxes):
        # The fill blocks, their concatenation with the leaves (held meanwhile) and the
        # brick pool, at most a brick per block.
        n = vg.n_fill_blocks
        require_host(3 * (n + len(values)) * 512 * 4, path, key,
                     f"grid '{vg.name}': {n} blocks of inactive tiles")
        fo, fv = vg.fill_blocks()
        origins = np.concatenate([fo, origins])
        values = np.concatenate([fv, values])
    return BrickGrid.from_blocks(dims, origins - lo, values)


def load_density(spec: SceneSpec, cache=None, p="medium."):
    """(density grid or None for a homogeneous medium, VdbGrid or None) of spec.medium (keys
    named with prefix ``p``). The grid is a float32 [z, y, x] array, or a BrickGrid for a
    VDB file whose background is 0 (unless render.grid_storage = "dense"): its leaves become
    bricks without a dense copy."""
    d = spec.medium.density
    if isinstance(d, ConstantDensity):
        return None, None
    raw, vg = _read_source(spec, d, p + "density", cache=cache)
    where = d.resolved if isinstance(d, FileDensity) else spec.file
    if raw is None and spec.render.grid_storage != "dense" and vg.background == 0.0:
        grid = _vdb_bricks(vg, where, p + "density")
    else:
        grid = validate_grid(_dense(vg, where, p + "density") if raw is None else raw, where,
                             p + "density", None if vg is None else vg.name)
    # The float32 kernels hold the global majorant scale * max(density).
    top = max(spec.medium.scale) * float(grid.max())
    if top > FLOAT32_MAX:
        raise SceneError(spec.file, p + "scale",
                         f"scale * max(density) = {top:g} overflows float32 (at most "
                         f"{FLOAT32_MAX:g})")
    return grid, vg


def load_emission(spec: SceneSpec, vdb_density=None, cache=None, p="medium."):
    """The emission field or temperature grid (float32 [z, y, x]; 1x1x1 when constant) of
    spec.medium, or None without emission."""
    e = spec.medium.emission
    if e is None:
        return None
    src, key = (e.field, p + "emission.field") if e.radiance is not None else \
        (e.temperature, p + "emission.temperature")
    if isinstance(src, ConstantDensity):
        values = np.full((1, 1, 1), src.value, np.float32)
    else:
        raw, vg = _read_source(spec, src, key, vdb_density, cache)
        where = src.resolved if isinstance(src, FileDensity) else spec.file
        values = validate_grid(_dense(vg, where, key) if raw is None else raw, where, key,
                               None if vg is None else vg.name)
    grid = remap_temperature(values, e.remap)
    if e.radiance is None:
        _check_blackbody_range(grid, spec.file, key)
    return grid


def _check_blackbody_range(grid, file, key):
    """The kernels keep the blackbody table unscaled in float32 (scale multiplies after the
    lookup): a temperature whose radiance passes FLOAT32_MAX (about 2.3e31 K) made every
    sample there infinite, and dropped, in the kernels alone."""
    from ..emission import blackbody_rgb
    hottest = float(grid.max())
    top = float(blackbody_rgb(np.array(hottest)).max())
    if not top <= FLOAT32_MAX:
        raise SceneError(file, key, f"the hottest temperature, {hottest:g} K, radiates "
                                    f"{top:g} nits, past float32 (the kernels' blackbody "
                                    "table, before scale)")


def remap_temperature(grid, remap):
    """The kelvin of a flame-style grid (schema.Emission.remap), voxel by voxel; the grid
    itself without a remap. Computed in float64, stored as float32."""
    if remap is None:
        return grid
    v0, v1, t0, t1 = remap
    x = np.clip((grid.astype(np.float64) - v0) / (v1 - v0), 0.0, 1.0)
    return np.ascontiguousarray(t0 + x * (t1 - t0), np.float32)


def load_env_map(spec: SceneSpec):
    """The spec with its environment map, if any, read into its light (``texels``), after
    checking that its radiance stays in float32."""
    from .envmap import read_env_map
    from .schema import EnvironmentLight
    lights = list(spec.lights)
    for i, lt in enumerate(lights):
        if isinstance(lt, EnvironmentLight) and lt.file is not None:
            px = read_env_map(lt.resolved, spec.file, f"lights[{i}].file")
            top = float(px.max()) * max(lt.radiance) * lt.strength
            if top > FLOAT32_MAX:
                raise SceneError(spec.file, f"lights[{i}].strength",
                                 f"the map's brightest texel x radiance x strength = {top:g} "
                                 "overflows float32")
            lights[i] = replace(lt, texels=px)
    return replace(spec, lights=tuple(lights))


def _complete(spec: SceneSpec):
    """Load every grid; a VDB density without bounds gives the box. Several media load one
    by one (a Scene part each; generated grids are shared through one cache)."""
    spec = load_env_map(spec)
    cache = {}
    if not spec.others:
        return _complete_one(spec, cache)
    parts = tuple(_complete_one(replace(spec, medium=m, others=()), cache, f"media[{i}].")
                  for i, m in enumerate(spec.media))
    media = tuple(p.spec.medium for p in parts)
    whole = replace(spec, medium=media[0], others=media[1:])
    return Scene(whole, parts[0].grid, parts[0].emission_grid, parts)


def _complete_one(spec, cache, p="medium."):
    grid, vg = load_density(spec, cache, p)
    if spec.medium.bounds is None:
        # The file's own placement: its world box, or (a turned, mirrored or sheared map) its
        # index box with the map as a transform, under the medium's transform if any.
        lo, hi, vdb_map = vg.placement()
        transform = spec.medium.transform
        if vdb_map is not None:
            transform = as_tuple(vdb_map if transform is None else np.array(transform) @ vdb_map)

        def fail(key, msg):
            raise SceneError(spec.medium.density.resolved, key, msg)
        check_box(fail, lo, hi, p + "bounds")
        if transform is not None:
            check_placed_box(fail, transform, (lo, hi), p + "transform")
        spec = replace(spec, medium=replace(spec.medium, bounds=(tuple(lo), tuple(hi)),
                                            transform=transform))
    return Scene(spec, grid, load_emission(spec, vg, cache, p))


def load_scene(path, overrides=(), frame=None):
    """Read, override, validate and load a scene file. Raises SceneError on bad input.
    ``overrides``: ``-D`` strings or a mapping of dotted keys (``apply_overrides``).
    ``frame``: the number put into grid file patterns (frames.py); None if there are none."""
    path = str(path)
    return scene_from_raw(read_raw(path, overrides), path, frame=frame)


def read_raw(path, overrides=()):
    """The scene file's TOML as a dict, with the overrides applied (not validated)."""
    return apply_overrides(read_toml(path), _listed(overrides), path)


def scene_from_raw(raw, file, file_dir=None, frame=None):
    """The Scene of a raw scene dict: frame patterns substituted, validated, grids loaded.
    ``raw`` itself is not changed."""
    from .frames import substitute
    raw = substitute(raw, frame, file, file_dir)
    return _complete(validate(raw, file, file_dir))


def raw_from_dict(raw, file="<dict>", overrides=()):
    """A copy of a scene dict built in Python, with the overrides applied (not validated);
    numpy grids are shared, not copied."""
    import copy
    memo = {id(a): a for a in _arrays(raw)}   # deepcopy the tables, not the grids
    return apply_overrides(copy.deepcopy(raw, memo), _listed(overrides), file)


def scene_from_dict(raw, file="<dict>", base_dir=".", overrides=(), frame=None):
    """Build a Scene from an in-memory dictionary (relative paths resolve against base_dir).
    A grid source (``medium.density``, an emission field) may be a numpy array [z, y, x],
    validated as a grid file is; arrays are not copied until validated. ``frame`` as for
    ``load_scene``."""
    return scene_from_raw(raw_from_dict(raw, file, overrides), file, os.path.abspath(base_dir),
                          frame)


def _listed(overrides):
    """Overrides as apply_overrides takes them: a mapping as is, else a list of strings."""
    return overrides if isinstance(overrides, Mapping) else list(overrides)


def _arrays(node):
    """The numpy arrays anywhere in a nested dict/list."""
    if isinstance(node, np.ndarray):
        yield node
    elif isinstance(node, dict):
        for v in node.values():
            yield from _arrays(v)
    elif isinstance(node, (list, tuple)):
        for v in node:
            yield from _arrays(v)
