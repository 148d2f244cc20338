"""Held-out clouds for the benchmarks: ``python -m volmc.bench.fbm OUTDIR [--seeds 1,2]``.

The shipped clouds come from volmc's own generator, which the kernels were tuned on. These
are made another way: five octaves of trilinearly upsampled white noise (4^3 to 64^3 values,
each octave 0.55 of the last's amplitude, normalised to a mean near 0.5) on a 128^3 grid,
its contrast raised 4x, minus the distance from the centre (squashed 1.3x along y) less
0.6, clipped at 0 and scaled to a maximum of 1: a lumpy cloud filling about a fifth of its
box. Each seed writes ``fbm<seed>.npy`` and ``fbm<seed>.toml``: the grid in the unit box at
extinction 40, albedo 0.98, HG g = 0.7, under the default cloud's sky and sun, 96x96.
docs/lanes.md measures the lane widths on them (`volmc bench lanes OUTDIR/fbm1.toml
OUTDIR/fbm2.toml`).
"""

import argparse
from pathlib import Path

import numpy as np

#: Grid resolution and the octaves' lattice sizes.
SIZE = 128
OCTAVES = (4, 8, 16, 32, 64)
GAIN = 0.55
#: density = max(0, CONTRAST (noise - 0.5) + REACH - r), r the squashed distance.
CONTRAST, REACH = 4.0, 0.6

SCENE = """# A held-out fbm-noise cloud (python -m volmc.bench.fbm, seed {seed}).
[camera]
type = "perspective"
eye = [0.0, 0.0, 4.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fov = 36.0
resolution = [96, 96]

[medium]
bounds = [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]
density = {{ file = "{grid}" }}
scale = 40.0
albedo = 0.98
phase = {{ type = "hg", g = 0.7 }}

[[lights]]
type = "environment"
radiance = [0.08, 0.12, 0.22]

[[lights]]
type = "directional"
direction = [0.8, -0.5, -0.3]
irradiance = [3.6, 3.45, 3.2]

[render]
spp = 256
max_depth = 64
rr_depth = 5
"""


def _upsample(lattice, n):
    """Trilinear interpolation of a (m, m, m) lattice spanning [0, 1]^3 at n^3 points."""
    m = lattice.shape[0]
    t = np.linspace(0.0, m - 1.0, n)
    i = np.minimum(t.astype(np.int64), m - 2)
    f = t - i
    out = lattice
    for axis in range(3):
        shape = [1, 1, 1]
        shape[axis] = n
        lo = np.take(out, i, axis=axis)
        hi = np.take(out, i + 1, axis=axis)
        w = f.reshape(shape)
        out = lo * (1.0 - w) + hi * w
    return out


def fbm_cloud(seed, size=SIZE):
    """The density grid (z, y, x) of seed ``seed``, float32 in [0, 1] with maximum 1."""
    rng = np.random.default_rng(seed)
    noise = np.zeros((size,) * 3)
    amp, total = 1.0, 0.0
    for m in OCTAVES:
        noise += amp * _upsample(rng.random((m, m, m)), size)
        total += amp
        amp *= GAIN
    noise /= total
    c = np.linspace(-1.0, 1.0, size)
    z, y, x = np.meshgrid(c, c, c, indexing="ij")
    r = np.sqrt(x * x + (1.3 * y) ** 2 + z * z)
    d = np.clip(CONTRAST * (noise - 0.5) + REACH - r, 0.0, None)
    return (d / d.max()).astype(np.float32)


def write_clouds(outdir, seeds):
    """Write fbm<seed>.npy and fbm<seed>.toml into ``outdir``; returns the scene paths."""
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    paths = []
    for seed in seeds:
        grid = outdir / f"fbm{seed}.npy"
        np.save(grid, fbm_cloud(seed))
        scene = outdir / f"fbm{seed}.toml"
        scene.write_text(SCENE.format(seed=seed, grid=grid.name))
        paths.append(scene)
    return paths


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m volmc.bench.fbm",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("outdir")
    p.add_argument("--seeds", default="1,2", help="comma-separated seeds (default 1,2)")
    args = p.parse_args(argv)
    try:
        seeds = [int(s) for s in args.seeds.split(",")]
    except ValueError:
        seeds = [-1]
    if min(seeds) < 0:
        p.error(f"--seeds: comma-separated integers from 0, got {args.seeds!r}")
    for path in write_clouds(args.outdir, seeds):
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
