"""Write the fire fixtures of this folder (tests/data/fire): a Mantaflow smoke-and-fire cache and the grid
layouts of Houdini Pyro and EmberGen, from a small simulation of our own, with OpenVDB.

Run with Blender as a Python module (bpy 5.0, whose OpenVDB 12.0 Python module comes with
it; /tmp/bpyvenv is where it was installed):

    /tmp/bpyvenv/bin/python tests/data/fire/make_fixtures.py

Why not a real Mantaflow bake: with bpy 5.0.1, a minimal gas domain (resolution 16, cache
type All, OpenVDB) and a Fire + Smoke inflow sphere, ``bpy.ops.fluid.bake_all()`` stops
inside Mantaflow with "AttributeError: 'LevelsetGrid' object has no attribute 'setConst'"
and the process aborts ("can't clean grid cache, some grids are still in use"); no cache
file is written. So this script writes the files OpenVDB-side exactly as Mantaflow's
``writeObjectsVDB`` (extern/mantaflow/preprocessed/fileio/iovdb.cpp, Blender 3.x-5.x) does
for a resumable smoke cache with fire, heat and colours
(intern/mantaflow/intern/strings/{fluid,smoke}_script.h, MANTA_main.h):

* one file per frame, ``cache_fluid/data/fluid_data_####.vdb``;
* grids in the order of the save dictionaries: velocity (the MAC grid, Vec3s, class
  staggered), phi_obstacle, phi_inflow, phi_out (level sets), flags (int32), velocity_previous,
  density, shadow, temperature (Mantaflow's heat grid is named "temperature"), flame, color_r,
  color_g, color_b, density_inflow, emission, temperature_inflow, fuel, react, fuel_inflow,
  react_inflow, color_r_inflow, color_g_inflow, color_b_inflow;
* every grid saved as half floats (Blender's default precision: the tree type gets the
  ``_HalfFloat`` suffix, the int32 flags grid included), blosc + active-mask compression
  (Blender's default), the transform ``createLinearTransform(voxel size)`` (a
  UniformScaleMap; index (0, 0, 0) at the domain's corner), grid class fog volume / level
  set / staggered / unknown, and the metadata Mantaflow adds: file_base_resolution (vec3i)
  and file_voxel_size (float);
* sparse grids copied from dense with the clip value 1e-6 as tolerance and then clipped to
  the density's active voxels (``copyFromDense`` + ``tools::clip``), dense ones (shadow,
  flags, the level sets) with tolerance 0, as ``exportVDB`` does.

The simulation is a 16 x 16 x 24 semi-Lagrangian smoke with buoyancy, a fuel inflow sphere
that burns (react decays at the burning rate, flame = react above the ignition point, the
burn heats and adds smoke), four frames. Houdini Pyro's layout is density, temperature,
flame (float) with vel and Cd (Vec3s) and a centred (scale + translate) transform;
EmberGen's is half-float density and temperature. double.vdb holds 64-bit grids (full and
saved as halves).

Beside the files it writes ``truth.npz``: for every float grid of every file, OpenVDB's own
reading of it (``openvdb.readAll``): the active bbox, the background and every voxel of the
bbox (``copyToArray``), which tests/test_fire_fixture.py compares volmc's reader with (bpy
is not installed in CI).
"""

import os
import struct
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = HERE
#: The Mantaflow cache goes with the scenes (the gallery fire renders it).
CACHE_OUT = os.path.join(HERE, "..", "..", "..", "scenes", "data", "fire")
RES = (16, 16, 24)            # x, y, z (z up)
DOMAIN = 2.4                  # longest side, metres: voxel size DOMAIN / 24 = 0.1
CLIP = 1e-6                   # Blender's default OpenVDB clip value
FRAMES = 4
STEPS_PER_FRAME = 5


def openvdb_module():
    import bpy  # (bpy/5.0/scripts/modules/bpy: its python/ holds the bundled modules)
    base = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(bpy.__file__))))
    sys.path.append(os.path.join(base, "python", "lib", "python3.11", "site-packages"))
    import openvdb
    return openvdb


# ----------------------------------------------------------------------------- simulation

def _advect(f, vel, dt):
    """Semi-Lagrangian advection of f [x, y, z] (or [x, y, z, 3]) by vel [x, y, z, 3]."""
    n = np.array(f.shape[:3])
    idx = np.indices(f.shape[:3]).transpose(1, 2, 3, 0).astype(np.float64)
    p = np.clip(idx - dt * vel, 0, n - 1)
    i0 = np.floor(p).astype(int)
    i1 = np.minimum(i0 + 1, n - 1)
    t = p - i0
    out = 0
    for corner in range(8):
        c = [(corner >> a) & 1 for a in range(3)]
        ii = [np.where(c[a], i1[..., a], i0[..., a]) for a in range(3)]
        w = np.prod([np.where(c[a], t[..., a], 1 - t[..., a]) for a in range(3)], axis=0)
        v = f[ii[0], ii[1], ii[2]]
        out = out + (w[..., None] * v if f.ndim == 4 else w * v)
    return out


def _blur(v):
    """A 3-tap box blur along each axis (keeps the velocity field spreading past the hot
    voxels, so smoke is carried rather than sampled away)."""
    for axis in range(3):
        v = (np.roll(v, 1, axis) + v + np.roll(v, -1, axis)) / 3
    return v


def simulate():
    """Frames of {name: float32 array [x, y, z] or [x, y, z, 3]}."""
    nx, ny, nz = RES
    x, y, z = np.indices(RES).astype(np.float64) + 0.5
    centre = np.array([nx / 2, ny / 2, 3.5])
    dist = np.sqrt((x - centre[0]) ** 2 + (y - centre[1]) ** 2 + (z - centre[2]) ** 2)
    source = np.clip(3.0 - dist, 0, 1)           # the inflow sphere, soft edge
    phi_in = (dist - 2.5).astype(np.float32)    # its level set (negative inside)
    wall = np.minimum.reduce([x, nx - x, y, ny - y, z, nz - z])
    phi_obs = (wall - 0.5).astype(np.float32)   # distance to the domain walls
    rng = np.random.default_rng(24)
    swirl = rng.normal(0, 0.3, (nx, ny, nz, 3))
    vel = np.zeros((nx, ny, nz, 3))
    dens, heat, fuel, react, flame = (np.zeros(RES) for _ in range(5))
    colour = np.zeros((nx, ny, nz, 3))
    smoke_rgb = np.array([0.7, 0.7, 0.7])
    burning_rate, ignition, max_temp, dt = 0.75, 1.5, 3.0, 0.8
    frames = []
    for frame in range(1, FRAMES + 1):
        for _ in range(STEPS_PER_FRAME):
            inflow = source * (1.0 + 0.2 * np.sin(frame))
            fuel = np.maximum(fuel, inflow)
            react = np.maximum(react, inflow)
            vel[..., 2] += dt * (0.6 * heat - 0.15 * dens)          # buoyancy
            vel += dt * 0.2 * swirl * (dens[..., None] > 0.01)
            vel = _advect(_blur(vel), vel, dt) * 0.95
            dens, heat, fuel, react = (_advect(f, vel, dt) for f in (dens, heat, fuel, react))
            colour = _advect(colour, vel, dt)
            burnt = np.minimum(fuel, burning_rate * dt * fuel)       # processBurn
            fuel = fuel - burnt
            react = react * (1 - burning_rate * dt * 0.5)
            flame = np.where(react > 0.1, np.minimum(react * ignition, 1.0), 0.0)
            heat = np.minimum(heat * 0.85 + burnt * max_temp, max_temp)
            dens = dens + burnt * 1.0
            colour = colour + burnt[..., None] * smoke_rgb
            dens *= 0.97                                             # dissolve
        shadow = np.exp(-np.cumsum(dens[..., ::-1], axis=2)[..., ::-1] * 0.5)
        emission = np.clip(inflow, 0, None)
        frames.append({
            "velocity": vel.astype(np.float32), "phi_obstacle": phi_obs,
            "phi_inflow": phi_in, "phi_out": np.full(RES, 9999.0, np.float32),
            "flags": np.where(wall < 1, 2, 1).astype(np.int32),
            "velocity_previous": (0.95 * vel).astype(np.float32),
            "density": dens.astype(np.float32), "shadow": shadow.astype(np.float32),
            "temperature": heat.astype(np.float32), "flame": flame.astype(np.float32),
            "color_r": colour[..., 0].astype(np.float32),
            "color_g": colour[..., 1].astype(np.float32),
            "color_b": colour[..., 2].astype(np.float32),
            "density_inflow": inflow.astype(np.float32),
            "emission": emission.astype(np.float32),
            "temperature_inflow": (inflow * max_temp).astype(np.float32),
            "fuel": fuel.astype(np.float32), "react": react.astype(np.float32),
            "fuel_inflow": inflow.astype(np.float32), "react_inflow": inflow.astype(np.float32),
            "color_r_inflow": (inflow * smoke_rgb[0]).astype(np.float32),
            "color_g_inflow": (inflow * smoke_rgb[1]).astype(np.float32),
            "color_b_inflow": (inflow * smoke_rgb[2]).astype(np.float32),
        })
    return frames


# ------------------------------------------------------------------------- Mantaflow files

# (name, Mantaflow grid type, saveSparse) in the save dictionaries' order.
MANTAFLOW_GRIDS = [
    ("velocity", "mac", True), ("phi_obstacle", "levelset", False),
    ("phi_inflow", "levelset", False), ("phi_out", "levelset", False),
    ("flags", "int", False), ("velocity_previous", "mac", True),
    ("density", "real", True), ("shadow", "real", False), ("temperature", "real", True),
    ("flame", "real", True), ("color_r", "real", True), ("color_g", "real", True),
    ("color_b", "real", True), ("density_inflow", "real", True), ("emission", "real", True),
    ("temperature_inflow", "real", True), ("fuel", "real", True), ("react", "real", True),
    ("fuel_inflow", "real", True), ("react_inflow", "real", True),
    ("color_r_inflow", "real", True), ("color_g_inflow", "real", True),
    ("color_b_inflow", "real", True),
]


def mantaflow_grids(vdb, fields):
    voxel = DOMAIN / max(RES)
    clip_mask = fields["density"] > CLIP    # copyFromDense(density, clip) topology
    grids = []
    for name, kind, sparse in MANTAFLOW_GRIDS:
        a = fields[name].copy()
        if kind == "int":
            g = vdb.Int32Grid(0)
            g.copyFromArray(a, (0, 0, 0), 0)
        elif kind == "mac":
            g = vdb.Vec3SGrid((0.0, 0.0, 0.0))
            a[~clip_mask] = 0.0             # tools::clip to the density's active voxels
            g.copyFromArray(a, (0, 0, 0), (CLIP, CLIP, CLIP))
        else:
            g = vdb.FloatGrid(0.0)
            if sparse and name != "density":
                a[~clip_mask] = 0.0
            g.copyFromArray(a, (0, 0, 0), CLIP if sparse else 0.0)
        g.name = name
        g.transform = vdb.createLinearTransform(voxel)
        g.gridClass = {"levelset": vdb.GridClass.LEVEL_SET, "real": vdb.GridClass.FOG_VOLUME,
                       "mac": vdb.GridClass.STAGGERED}.get(kind, vdb.GridClass.UNKNOWN)
        g.saveFloatAsHalf = True
        g["file_base_resolution"] = RES     # written as vec3d; fix_vec3i makes it vec3i
        g["file_voxel_size"] = voxel
        grids.append(g)
    return grids


def fix_vec3i(path, key=b"file_base_resolution"):
    """Rewrite every ``key`` metadata entry from vec3d to vec3i (Mantaflow's
    Vec3IMetadata; the Python binding writes a tuple as vec3d) and move the grid offsets of
    the descriptors that follow by the bytes saved."""
    data = bytearray(open(path, "rb").read())
    old = (struct.pack("<I", len(key)) + key + struct.pack("<I", 5) + b"vec3d"
           + struct.pack("<I", 24))
    out, pos, starts = bytearray(), 0, []
    while True:
        at = data.find(old, pos)
        if at < 0:
            break
        x, y, z = struct.unpack_from("<3d", data, at + len(old))
        out += data[pos:at] + old[:-9] + b"vec3i" + struct.pack("<I3i", 12, int(x), int(y),
                                                                 int(z))
        starts.append(at)
        pos = at + len(old) + 24
    out += data[pos:]

    def shift(offset):   # bytes removed before ``offset`` of the old file
        return offset - 12 * sum(1 for s in starts if s < offset)

    def skip_strings(p, n):   # n length-prefixed strings (a metadata value is one too)
        for _ in range(n):
            p += 4 + struct.unpack_from("<I", out, p)[0]
        return p

    # Walk the descriptors (header 57 bytes, file metadata, grid count) of the new file.
    p = 8 + 4 + 8 + 1 + 36
    n_meta, = struct.unpack_from("<i", out, p)
    p = skip_strings(p + 4, 3 * n_meta)
    count, = struct.unpack_from("<i", out, p)
    p += 4
    for _ in range(count):
        p = skip_strings(p, 3)   # name, type, instance parent
        offs = [shift(v) for v in struct.unpack_from("<3q", out, p)]
        struct.pack_into("<3q", out, p, *offs)
        p = offs[2]
    open(path, "wb").write(bytes(out))


# --------------------------------------------------------------------- other applications

def houdini_grids(vdb, fields):
    voxel = DOMAIN / max(RES)
    out = []
    for name, src in (("density", "density"), ("temperature", "temperature"),
                      ("flame", "flame"), ("vel", "velocity"), ("Cd", "colour")):
        if name == "Cd":
            a = np.stack([fields[f"color_{c}"] for c in "rgb"], axis=-1)
        else:
            a = fields[src]
        if a.ndim == 4:
            g = vdb.Vec3SGrid((0.0, 0.0, 0.0))
            g.copyFromArray(a.copy(), (0, 0, 0), (0.0, 0.0, 0.0))
        else:
            g = vdb.FloatGrid(0.0)
            g.copyFromArray(a.copy(), (0, 0, 0), 0.0)
        g.name = name
        t = vdb.createLinearTransform(voxel)
        t.postTranslate((-RES[0] / 2 * voxel, -RES[1] / 2 * voxel, 0.5 * voxel))
        g.transform = t
        g.gridClass = vdb.GridClass.FOG_VOLUME if a.ndim == 3 else vdb.GridClass.UNKNOWN
        out.append(g)
    return out


def embergen_grids(vdb, fields):
    out = []
    for name in ("density", "temperature"):
        g = vdb.FloatGrid(0.0)
        g.copyFromArray(fields[name].copy(), (0, 0, 0), 0.0)
        g.name = name
        g.transform = vdb.createLinearTransform(0.05)
        g.gridClass = vdb.GridClass.FOG_VOLUME
        g.saveFloatAsHalf = True
        out.append(g)
    return out


def double_grids(vdb, fields):
    """64-bit grids (Houdini writes them when a volume's precision is 64-bit), one saved
    as halves."""
    out = []
    for name, half in (("density", False), ("temperature", True)):
        g = vdb.DoubleGrid(0.0)
        g.copyFromArray(fields[name].astype(np.float64) * (1 + 1e-9), (0, 0, 0), 0.0)
        g.name = name
        g.transform = vdb.createLinearTransform(0.1)
        g.saveFloatAsHalf = half
        out.append(g)
    return out


# ------------------------------------------------------------------------------- truth

def record_truth(vdb, path, rel, truth):
    """OpenVDB's reading of every float grid of ``path``, under keys "<rel>:<grid>:..."."""
    grids, _ = vdb.readAll(path)
    for g in grids:
        if g.valueTypeName not in ("float", "double"):
            truth[f"{rel}:{g.name}:skipped"] = np.array(g.valueTypeName)
            continue
        lo, hi = g.evalActiveVoxelBoundingBox()
        shape = tuple(h - l + 1 for l, h in zip(lo, hi))
        dense = np.empty(shape, np.float32 if g.valueTypeName == "float" else np.float64)
        g.copyToArray(dense, lo)
        dense = dense.astype(np.float32)   # volmc holds every grid as float32
        truth[f"{rel}:{g.name}:bbox"] = np.array([lo, hi], np.int64)
        truth[f"{rel}:{g.name}:background"] = np.float32(g.background)
        # [x, y, z] from copyToArray; volmc's to_dense is [z, y, x].
        truth[f"{rel}:{g.name}:values"] = np.ascontiguousarray(dense.transpose(2, 1, 0))
        truth[f"{rel}:{g.name}:voxel_size"] = np.array(g.transform.voxelSize(), np.float64)
        truth[f"{rel}:{g.name}:origin"] = np.array(g.transform.indexToWorld((0, 0, 0)),
                                                   np.float64)


def main():
    vdb = openvdb_module()
    frames = simulate()
    data = os.path.join(CACHE_OUT, "cache_fluid", "data")
    os.makedirs(data, exist_ok=True)
    truth = {}
    for i, fields in enumerate(frames, start=1):
        rel = f"cache_fluid/data/fluid_data_{i:04d}.vdb"
        path = os.path.join(CACHE_OUT, rel)
        vdb.write(path, grids=mantaflow_grids(vdb, fields))
        fix_vec3i(path)
        record_truth(vdb, path, rel, truth)
    for rel, grids in (("houdini_pyro.vdb", houdini_grids(vdb, frames[-1])),
                       ("embergen.vdb", embergen_grids(vdb, frames[-1])),
                       ("double.vdb", double_grids(vdb, frames[-1]))):
        path = os.path.join(OUT, rel)
        vdb.write(path, grids=grids)
        record_truth(vdb, path, rel, truth)
    np.savez_compressed(os.path.join(OUT, "truth.npz"), **truth)
    total = sum(os.path.getsize(os.path.join(r, f)) for r, _, fs in os.walk(OUT) for f in fs
                if f.endswith((".vdb", ".npz")))
    print(f"wrote {OUT}: {total} bytes, OpenVDB {vdb.LIBRARY_VERSION}, file format "
          f"{vdb.FILE_FORMAT_VERSION}")


if __name__ == "__main__":
    main()
