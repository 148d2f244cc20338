"""Write the fire fixtures of other applications in this folder (tests/data/fire): the grid
layouts of Houdini Pyro and EmberGen, and 64-bit grids, from a small simulation of our own,
with OpenVDB. The Mantaflow cache is a real bake: bake_mantaflow.py.

Run with Blender as a Python module, whose OpenVDB Python module comes with it (bpy 5.0 with
OpenVDB 12.0 wrote the files; bake_mantaflow.py says how to install bpy):

    /tmp/bpy45/bin/python tests/data/fire/make_fixtures.py

The simulation is a 16 x 16 x 24 semi-Lagrangian smoke with buoyancy, a fuel inflow sphere
that burns (react decays at the burning rate, flame = react above the ignition point, the
burn heats and adds smoke); its last frame is written. Houdini Pyro's layout is density,
temperature, flame (float) with vel and Cd (Vec3s) and a centred (scale + translate)
transform; EmberGen's is half-float density and temperature. double.vdb holds 64-bit grids
(full and saved as halves).

Both scripts keep ``truth.npz`` up to date for the files they write: for every float grid
of every file, OpenVDB's own reading of it (``openvdb.readAll``): the active bbox, the
background and every voxel of the bbox (``copyToArray``), which tests/test_fire_fixture.py
compares volmc's reader with (bpy is not installed in CI).
"""

import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = HERE
RES = (16, 16, 24)            # x, y, z (z up)
DOMAIN = 2.4                  # longest side, metres: voxel size DOMAIN / 24 = 0.1
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
        if np.array_equal(dense.astype(np.float16).astype(np.float32), dense):
            dense = dense.astype(np.float16)   # a half grid's values, in half the bytes
        truth[f"{rel}:{g.name}:bbox"] = np.array([lo, hi], np.int64)
        truth[f"{rel}:{g.name}:background"] = np.float32(g.background)
        # [x, y, z] from copyToArray; volmc's to_dense is [z, y, x].
        truth[f"{rel}:{g.name}:values"] = np.ascontiguousarray(dense.transpose(2, 1, 0))
        truth[f"{rel}:{g.name}:voxel_size"] = np.array(g.transform.voxelSize(), np.float64)
        truth[f"{rel}:{g.name}:origin"] = np.array(g.transform.indexToWorld((0, 0, 0)),
                                                   np.float64)


def update_truth(truth, owned):
    """Replace in truth.npz the entries of the files whose names start with ``owned`` by
    ``truth`` (each script records the files it writes; bake_mantaflow.py the frames)."""
    path = os.path.join(OUT, "truth.npz")
    kept = {}
    if os.path.exists(path):
        with np.load(path) as old:
            kept = {k: old[k] for k in old.files if not k.startswith(owned)}
    np.savez_compressed(path, **kept, **truth)


def main():
    vdb = openvdb_module()
    last = simulate()[-1]
    truth = {}
    writers = {"houdini_pyro.vdb": houdini_grids, "embergen.vdb": embergen_grids,
               "double.vdb": double_grids}
    for rel, grids in writers.items():
        path = os.path.join(OUT, rel)
        vdb.write(path, grids=grids(vdb, last))
        record_truth(vdb, path, rel, truth)
    update_truth(truth, tuple(writers))
    total = sum(os.path.getsize(os.path.join(OUT, rel)) for rel in writers)
    print(f"wrote {OUT}: {total} bytes, OpenVDB {vdb.LIBRARY_VERSION}, file format "
          f"{vdb.FILE_FORMAT_VERSION}")


if __name__ == "__main__":
    main()
