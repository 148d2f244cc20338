"""Sparse brick grid against the dense grid: memory, build time and lookup speed.

A size^3 grid (default 512^3) of a few noisy blobs filling about 3 % of its voxels is
stored dense and as bricks (volmc/reference/sparse_grid.py). The benchmark prints

* memory: dense float32 (kernels) and float64 (reference) against the brick table plus pool;
* build time: bricks from the dense array, bricks from 8^3 blocks whose origins are offset
  from the bricks (as OpenVDB leaves usually are), the brick majorant against
  build_majorant_grid on the dense array;
* lookups per second of grid_lookup (dense) and of the two ways of fetching the sparse
  corners: "fast_path" (one table read when the eight corners share a brick, otherwise one
  per corner) and "every_corner" (one table read per corner, no branch), on PoCL
  (kernels/bench_sparse.cl) and in the Numba reference (float64 arrays, as the reference backend renders), for three
  kinds of points: uniform in the box, uniform in the non-empty bricks, and rays from a point
  in a non-empty brick with lookups half a voxel apart (the coherent reads of tracking).
  Each backend ships the variant that measured faster on it (SHIPPED): the kernel's
  sparse_lookup reads every corner, the Numba one takes the fast path; the other variant is
  a copy kept here (and in bench_sparse.cl) for this measurement.

Configurations alternate within each repeat so that machine drift affects all alike; the
figure is the median. Point generation (a 32-bit hash) is included in every rate alike.
Every configuration sums its lookups per work item: the sparse sums must equal the dense
ones bit for bit on each backend, which the run checks.
"""

import argparse
import math
import time

import numpy as np
from numba import njit, prange

from ..reference.grid import grid_lookup, _axis
from ..reference.majorant import build_majorant_grid
from ..reference.sparse_grid import (bricks_from_blocks, bricks_from_dense,
                                     majorant_from_bricks, sparse_lookup)

_M = 0xFFFFFFFF
MODES = ("box", "active", "rays")
#: Lookup kinds, in the kernel's LOOKUP_KIND order.
LOOKUPS = ("dense", "fast_path", "every_corner")
#: The variant each backend's sparse_lookup is.
SHIPPED = {"opencl": "every_corner", "numba": "fast_path"}


def blobs_grid(size=512, fill=0.03, seed=1, n_blobs=7):
    """Dense float32 [size]^3 grid of n_blobs noisy balls holding about ``fill`` of the voxels
    (density up to 1, falling to 0 at each ball's rim)."""
    rng = np.random.default_rng(seed)
    g = np.zeros((size, size, size), np.float32)
    w = rng.uniform(0.5, 1.5, n_blobs)
    vol = fill * size**3 * w / w.sum() * 1.15      # a little extra: the noise erodes the rims
    for v in vol:
        r = (3.0 * v / (4.0 * math.pi)) ** (1.0 / 3.0)
        # Inside the grid by 2 voxels where it fits; in a grid too small for it, about its
        # middle (the clip below keeps the ball's voxels in the grid).
        c = rng.uniform(min(r + 2, size / 2), max(size - r - 2, size / 2), 3)
        lo = np.maximum(np.floor(c - r).astype(int), 0)
        hi = np.minimum(np.ceil(c + r).astype(int) + 1, size)
        z, y, x = np.meshgrid(*[np.arange(a, b) + 0.5 for a, b in zip(lo[::-1], hi[::-1])],
                              indexing="ij", sparse=True)
        k = rng.uniform(0.05, 0.12, 3)
        ph = rng.uniform(0, 2 * math.pi, 3)
        noise = (np.sin(k[0] * x + ph[0]) * np.sin(k[1] * y + ph[1]) * np.sin(k[2] * z + ph[2]))
        q = ((x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2) / r**2
        d = np.clip(1.0 - q + 0.25 * noise - 0.1, 0.0, None).astype(np.float32)
        box = g[lo[2]:hi[2], lo[1]:hi[1], lo[0]:hi[0]]
        np.maximum(box, d, out=box)
    return g


def offset_blocks(g, offset):
    """The non-empty 8^3 blocks of g whose minimum corners sit at 8 k - offset (x, y, z)."""
    nz, ny, nx = g.shape
    sx, sy, sz = offset
    pad = np.zeros((-(-(nz + sz) // 8) * 8, -(-(ny + sy) // 8) * 8, -(-(nx + sx) // 8) * 8),
                   g.dtype)
    pad[sz:sz + nz, sy:sy + ny, sx:sx + nx] = g
    bz, by, bx = (s // 8 for s in pad.shape)
    blocks = pad.reshape(bz, 8, by, 8, bx, 8).transpose(0, 2, 4, 1, 3, 5)
    keep = np.argwhere(blocks.any(axis=(3, 4, 5)))     # (kz, ky, kx)
    values = np.ascontiguousarray(blocks[keep[:, 0], keep[:, 1], keep[:, 2]])
    origins = 8 * keep[:, ::-1] - np.array([sx, sy, sz])
    return origins, values


# --- Numba twin of kernels/bench_sparse.cl ----------------------------------------------------

@njit(cache=True, inline="always")
def _hash(x):
    s = (x * 747796405 + 2891336453) & _M
    w = (((s >> ((s >> 28) + 4)) ^ s) * 277803737) & _M
    return ((w >> 22) ^ w) & _M


@njit(cache=True, inline="always")
def sparse_lookup_every_corner(table, pool, dims, bmin, inv_extent, p):
    """sparse_lookup with a table read for every corner (no one-brick fast path)."""
    x0, x1, fx = _axis(p[0], bmin[0], inv_extent[0], dims[0])
    y0, y1, fy = _axis(p[1], bmin[1], inv_extent[1], dims[1])
    z0, z1, fz = _axis(p[2], bmin[2], inv_extent[2], dims[2])
    v000 = pool[table[z0 >> 3, y0 >> 3, x0 >> 3], z0 & 7, y0 & 7, x0 & 7]
    v001 = pool[table[z0 >> 3, y0 >> 3, x1 >> 3], z0 & 7, y0 & 7, x1 & 7]
    v010 = pool[table[z0 >> 3, y1 >> 3, x0 >> 3], z0 & 7, y1 & 7, x0 & 7]
    v011 = pool[table[z0 >> 3, y1 >> 3, x1 >> 3], z0 & 7, y1 & 7, x1 & 7]
    v100 = pool[table[z1 >> 3, y0 >> 3, x0 >> 3], z1 & 7, y0 & 7, x0 & 7]
    v101 = pool[table[z1 >> 3, y0 >> 3, x1 >> 3], z1 & 7, y0 & 7, x1 & 7]
    v110 = pool[table[z1 >> 3, y1 >> 3, x0 >> 3], z1 & 7, y1 & 7, x0 & 7]
    v111 = pool[table[z1 >> 3, y1 >> 3, x1 >> 3], z1 & 7, y1 & 7, x1 & 7]
    c00 = v000 * (1.0 - fx) + v001 * fx
    c10 = v010 * (1.0 - fx) + v011 * fx
    c01 = v100 * (1.0 - fx) + v101 * fx
    c11 = v110 * (1.0 - fx) + v111 * fx
    c0 = c00 * (1.0 - fy) + c10 * fy
    c1 = c01 * (1.0 - fy) + c11 * fy
    return c0 * (1.0 - fz) + c1 * fz


@njit(cache=True, inline="always")
def _lookup(kind, grid, table, pool, dims, bmin, inv, p):
    if kind == 0:
        return grid_lookup(grid, bmin, inv, p)
    if kind == 1:
        return sparse_lookup(table, pool, dims, bmin, inv, p)
    return sparse_lookup_every_corner(table, pool, dims, bmin, inv, p)


@njit(cache=True, inline="always")
def _unit(st):
    st = _hash(st)
    return st, (st >> 8) * (1.0 / 16777216.0)


@njit(cache=True, inline="always")
def _brick_point(bricks, dims, st):
    st = _hash(st)
    k = st % bricks.shape[0]
    st, ux = _unit(st)
    st, uy = _unit(st)
    st, uz = _unit(st)
    return st, (min(8.0 * (bricks[k, 0] + ux), dims[0]), min(8.0 * (bricks[k, 1] + uy), dims[1]),
                min(8.0 * (bricks[k, 2] + uz), dims[2]))


@njit(cache=True)
def _item_sum(kind, grid, table, pool, dims, bmin, ext, inv, vox, bricks, mode, n_per_item,
              st):
    """One work item's sum (kept out of the parallel loop: Numba's parfor analysis trips
    on the inlined tuple returns)."""
    acc = 0.0
    if mode == 2:
        st, v = _brick_point(bricks, dims, st)
        o = (bmin[0] + v[0] * vox[0], bmin[1] + v[1] * vox[1], bmin[2] + v[2] * vox[2])
        st, u = _unit(st)
        z = 2.0 * u - 1.0
        st, u = _unit(st)
        phi = 2.0 * math.pi * u
        r = math.sqrt(max(0.0, 1.0 - z * z))
        s = (r * math.cos(phi) * 0.5 * vox[0], r * math.sin(phi) * 0.5 * vox[1],
             z * 0.5 * vox[2])
        for k in range(n_per_item):
            acc += _lookup(kind, grid, table, pool, dims, bmin, inv,
                           (o[0] + k * s[0], o[1] + k * s[1], o[2] + k * s[2]))
        return acc
    for k in range(n_per_item):
        if mode == 0:
            st, ux = _unit(st)
            st, uy = _unit(st)
            st, uz = _unit(st)
            p = (bmin[0] + ux * ext[0], bmin[1] + uy * ext[1], bmin[2] + uz * ext[2])
        else:
            st, v = _brick_point(bricks, dims, st)
            p = (bmin[0] + v[0] * vox[0], bmin[1] + v[1] * vox[1], bmin[2] + v[2] * vox[2])
        acc += _lookup(kind, grid, table, pool, dims, bmin, inv, p)
    return acc


@njit(cache=True, parallel=True)
def bench_sums(kind, grid, table, pool, dims, bmin, bmax, bricks, mode, n_items, n_per_item,
               seed):
    """Per work item, the sum of n_per_item lookups (the kernel's loop, in float64)."""
    out = np.empty(n_items)
    ext = (bmax[0] - bmin[0], bmax[1] - bmin[1], bmax[2] - bmin[2])
    inv = (1.0 / ext[0], 1.0 / ext[1], 1.0 / ext[2])
    vox = (ext[0] / dims[0], ext[1] / dims[1], ext[2] / dims[2])
    for gid in prange(n_items):
        out[gid] = _item_sum(kind, grid, table, pool, dims, bmin, ext, inv, vox, bricks, mode,
                             n_per_item, _hash(gid ^ _hash(seed)))
    return out


# --- OpenCL ----------------------------------------------------------------------------------

def lookup_options(kind):
    """Build option of kernels/bench_sparse.cl for lookup ``kind`` (an index of LOOKUPS);
    the lane options (volmc.cl.lanes.lane_options) come beside it."""
    return (f"-DLOOKUP_KIND={kind}",)


class OpenCLSparseBench:
    """kernels/bench_sparse.cl built for each lookup kind, with the grid uploaded once."""

    def __init__(self, grid, table, pool, bricks, bmin, bmax, device=None, lanes=None):
        from ..cl.context import cl_context
        from ..cl.lanes import lane_options, resolve_gathers, resolve_lanes
        self.clc = cl_context(device)
        self.lanes = resolve_lanes(lanes, self.clc.device)
        opts = lane_options(self.lanes, resolve_gathers(self.clc.device))
        self.kernels = [self.clc.kernel(self.clc.program("bench_sparse.cl",
                                                         [*lookup_options(k), *opts])[0],
                                        "sparse_bench") for k in range(len(LOOKUPS))]
        nz, ny, nx = grid.shape
        self.dims = np.array([nx, ny, nz, 0], np.int32)
        self.bmin = np.array(list(bmin) + [0.0], np.float32)
        self.bmax = np.array(list(bmax) + [0.0], np.float32)
        self.bufs = [self.clc.to_device(grid, np.float32), self.clc.to_device(table, np.int32),
                     self.clc.to_device(pool, np.float32)]
        self.bricks = self.clc.to_device(bricks, np.int32)
        self.n_bricks = np.uint32(len(bricks))

    def sums(self, kind, mode, n_items, n_per_item, seed):
        out, ob = self.clc.output(n_items)
        self.clc.run(self.kernels[kind], -(-n_items // self.lanes), None, *self.bufs, self.dims,
                     self.bmin, self.bmax, self.bricks, self.n_bricks, np.int32(mode),
                     np.uint32(n_per_item), np.uint32(seed), ob, np.int32(n_items),
                     outs=[(out, ob)])
        return out


def _timed(fn):
    t = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t


def _timed_both(fn):
    """(wall seconds, CPU seconds of every thread of the process)."""
    t, c = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - t, time.process_time() - c


def least_bytes(size, lookups, backends, per_item=64):
    """Host bytes ``run`` allocates whatever the fill: the float32 grid, its copy padded into
    8^3 blocks, the float64 grid of the Numba runs, and every configuration's sums (one
    float64 per work item, kept for the bit-for-bit check). The brick pools come on top,
    in proportion to the bricks the blobs touch."""
    voxels = size ** 3
    per_voxel = 4 + 4 + (8 if "numba" in backends else 0)
    n_items = max(1, lookups // per_item)
    return voxels * per_voxel + n_items * 8 * len(MODES) * len(LOOKUPS) * len(backends)


def run(size=512, fill=0.03, lookups=1 << 22, per_item=64, repeats=5, backends=("opencl",
        "numba"), device=None, seed=1, log=print):
    """The benchmark's figures as a dict (see the module docstring)."""
    bmin, bmax = (-1.0, -1.0, -1.0), (1.0, 1.0, 1.0)
    log(f"building a {size}^3 grid of blobs ...")
    g = blobs_grid(size, fill, seed)
    dims = (size, size, size)
    # Compile the Numba builders on a tiny grid so the timings below are of the build alone.
    small = np.zeros((9, 9, 9), np.float32)
    t_small, p_small = bricks_from_dense(small)
    majorant_from_bricks(t_small, p_small, small.shape)
    bricks_from_blocks((9, 9, 9), np.zeros((1, 3), int), np.ones((1, 8, 8, 8), np.float32))
    (table, pool), t_dense = _timed(lambda: bricks_from_dense(g))
    origins, values = offset_blocks(g, (3, 5, 1))
    (tb, pb), t_blocks = _timed(lambda: bricks_from_blocks(dims, origins, values))
    assert np.array_equal(tb, table) and np.array_equal(pb, pool)
    (mx, mn), t_maj = _timed(lambda: majorant_from_bricks(table, pool, dims))
    (bx, bn), t_maj_dense = _timed(lambda: build_majorant_grid(g, table.shape))
    assert np.array_equal(mx, bx) and np.array_equal(mn, bn)
    active = int(np.count_nonzero(g))
    if active == 0:   # the "active" points are drawn in non-empty bricks: none to draw from
        from ..scene.errors import SceneError
        raise SceneError("command line", "--fill", f"a {size}^3 grid at fill {fill} has no "
                         "active voxel; raise --fill or --size")
    bricks = np.ascontiguousarray(np.argwhere(table)[:, ::-1], np.int32)   # (x, y, z)
    report = {
        "size": size, "active_voxels": active, "voxel_fill": active / g.size,
        "bricks": int(table.size), "nonempty_bricks": int(len(pool) - 1),
        "brick_fill": (len(pool) - 1) / table.size,
        "bytes": {"dense_f32": g.nbytes, "dense_f64": 2 * g.nbytes,
                  "table": table.nbytes, "pool_f32": pool.nbytes, "pool_f64": 2 * pool.nbytes,
                  "majorant_grids": mx.nbytes + mn.nbytes},
        "build_s": {"bricks_from_dense": t_dense, "bricks_from_blocks": t_blocks,
                    "blocks": int(len(origins)), "majorant_from_bricks": t_maj,
                    "build_majorant_grid_dense": t_maj_dense},
        "lookups_per_launch": 0, "rates": {}, "cpu_rates": {}, "identical": {},
    }
    n_items = max(1, lookups // per_item)
    total = n_items * per_item
    report["lookups_per_launch"] = total
    runners = {}
    if "opencl" in backends:
        ocl = OpenCLSparseBench(g, table, pool, bricks, bmin, bmax, device)
        for m, mode in enumerate(MODES):
            for k, kind in enumerate(LOOKUPS):
                runners[("opencl", mode, kind)] = (
                    lambda s, k=k, m=m: ocl.sums(k, m, n_items, per_item, s))
    if "numba" in backends:
        g64 = g.astype(np.float64)
        p64 = pool.astype(np.float64)
        for m, mode in enumerate(MODES):
            for k, kind in enumerate(LOOKUPS):
                runners[("numba", mode, kind)] = (
                    lambda s, k=k, m=m: bench_sums(k, g64, table, p64, dims, bmin, bmax,
                                                   bricks, m, n_items, per_item, s))
    del g
    log(f"{len(runners)} configurations x {repeats} repeats of {total} lookups ...")
    first = {key: fn(0) for key, fn in runners.items()}   # compile; results for the check
    for be in backends:
        for mode in MODES:
            ref = first[(be, mode, "dense")]
            report["identical"][f"{be}/{mode}"] = all(
                np.array_equal(first[(be, mode, kind)], ref) for kind in LOOKUPS[1:])
    times = {key: [] for key in runners}
    for rep in range(repeats):       # alternate: drift hits every configuration alike
        for key, fn in runners.items():
            times[key].append(_timed_both(lambda: fn(rep + 1)))
    for (be, mode, kind), ts in times.items():
        wall, cpu = np.median(np.array(ts), axis=0)
        report["rates"][f"{be}/{mode}/{kind}"] = total / float(wall)
        report["cpu_rates"][f"{be}/{mode}/{kind}"] = total / float(cpu)
    return report


def format_report(r):
    """The report as a text table."""
    mib = 1 << 20
    b = r["bytes"]
    lines = [
        f"grid {r['size']}^3: {r['active_voxels']} active voxels ({100 * r['voxel_fill']:.2f} %),"
        f" {r['nonempty_bricks']} of {r['bricks']} bricks non-empty"
        f" ({100 * r['brick_fill']:.2f} %)",
        "",
        f"{'memory':<28}{'float32 (kernels)':>20}{'float64 (reference)':>22}",
        f"{'dense':<28}{b['dense_f32'] / mib:>16.1f} MiB{b['dense_f64'] / mib:>18.1f} MiB",
        f"{'sparse: table + pool':<28}{(b['table'] + b['pool_f32']) / mib:>16.1f} MiB"
        f"{(b['table'] + b['pool_f64']) / mib:>18.1f} MiB",
        f"{'  of which table':<28}{b['table'] / mib:>16.1f} MiB{b['table'] / mib:>18.1f} MiB",
        f"{'sparse / dense':<28}{(b['table'] + b['pool_f32']) / b['dense_f32']:>20.4f}"
        f"{(b['table'] + b['pool_f64']) / b['dense_f64']:>22.4f}",
        f"{'majorant grids (both)':<28}{b['majorant_grids'] / mib:>16.1f} MiB",
        "",
        "build (s): " + ", ".join(
            f"{k} {v:.2f}" if isinstance(v, float) else f"{k} {v}"
            for k, v in r["build_s"].items()),
    ]
    for title, rates_of in (("wall", r["rates"]), ("CPU", r["cpu_rates"])):
        lines += [
            "",
            f"lookups per {title} second (M/s), median of the repeats, "
            f"{r['lookups_per_launch']} lookups per launch"
            + ("" if title == "wall" else " (CPU time of all the process's threads)"),
            f"{'backend':<8}{'points':<8}" + "".join(f"{k:>14}" for k in LOOKUPS)
            + f"{'shipped/dense':>15}{'fast/every':>12}",
        ]
        keys = sorted({k.rsplit("/", 1)[0] for k in rates_of},
                      key=lambda s: (s.split("/")[0], MODES.index(s.split("/")[1])))
        for key in keys:
            be, mode = key.split("/")
            x = [rates_of[f"{key}/{k}"] for k in LOOKUPS]
            shipped = x[LOOKUPS.index(SHIPPED[be])]
            lines.append(f"{be:<8}{mode:<8}" + "".join(f"{v / 1e6:>14.2f}" for v in x)
                         + f"{shipped / x[0]:>15.2f}{x[1] / x[2]:>12.2f}")
    lines += ["", "shipped sparse_lookup: " + ", ".join(f"{b} {v}" for b, v in SHIPPED.items()),
              "sparse sums equal to dense sums bit for bit: "
              + ", ".join(f"{k} {'yes' if v else 'NO'}" for k, v in r["identical"].items())]
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="volmc bench sparse", description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--fill", type=float, default=0.03, help="fraction of active voxels")
    ap.add_argument("--lookups", type=int, default=1 << 22, help="lookups per timed launch")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--backends", default="opencl,numba")
    ap.add_argument("--device", default=None)
    ap.add_argument("--json", default=None, help="also write the figures to this file")
    a = ap.parse_args(argv)
    return report(a.size, a.fill, a.lookups, a.repeats, a.backends.split(","), a.device,
                  a.json)


def report(size, fill, lookups, repeats, backends, device=None, json_path=None):
    """Run the benchmark, print its table (the log to stderr) and write ``json_path``;
    returns the exit status 0. ``volmc bench sparse`` calls it with its checked options."""
    import sys
    r = run(size, fill, lookups, repeats=repeats, backends=tuple(backends), device=device,
            log=lambda s: print(s, file=sys.stderr))
    print(format_report(r))
    if json_path:
        from ..outputs import write_json
        write_json(json_path, r, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
