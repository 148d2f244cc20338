"""Octree majorants: per-node bounds of a trilinear density grid, split where they are loose,
and the walk of a ray through the leaves in order (twin of ``kernels/octree.h``).

**Nodes.** The root is the medium box; a node splits into eight equal halves along every
axis, so a node at level l covers whole cells of the regular 2^D-per-axis grid of the finest
level D (``m.octree_depth``), cells [c 2^(D-l), (c + 1) 2^(D-l)) along each axis. Its
bounds are the extremes over every voxel trilinear interpolation can read inside it: the
finest level's are ``build_majorant_grid`` / ``majorant_from_bricks`` at 2^D cells per axis
(majorant.py, sparse_grid.py), and a parent's influence range is the union of its children's
(the ranges of adjacent cells meet), so every coarser level is the 2x2x2 maximum (minimum)
of the one below: exact, not a looser bound.

**Split criterion.** A node splits while its level is below D and

    (max - min) x scale x |node diagonal| > OCTREE_SPLIT_THRESHOLD = 1.442,

the criterion of Blender Cycles' volume octree (Cycles 5.0, ``OctreeNode::should_split``:
a node stays a leaf when (sigma_max - sigma_min) x len(bbox.size()) x scale < 1.442f or it
is at the maximum depth), which Cycles credits to "Volume Rendering for Pixar's Elemental".
1.442 is about 1 / ln 2: the spread of extinction across the node, times the longest path
through it, is an optical-depth excess of about one e-fold in two, beyond which null
collisions from the loose majorant cost more than the extra segments of splitting. An empty
node (max 0) and a homogeneous one (max = min) never split. D is chosen so the finest leaves
are about ``OCTREE_MIN_VOXELS`` voxels along the longest axis, at most OCTREE_MAX_DEPTH.

**Flat layout** (what the kernels read): nodes in breadth-first order, root at 0, the eight
children of a node contiguous in octant order k = x + 2 y + 4 z (bit set: the upper half);
``children[n]`` is the index of node n's first child, 0 for a leaf (the root is no one's
child); the density bounds travel as the medium's ``maj`` and ``mnr`` arrays, shape
(1, 1, n_nodes).

**Walk** (``octree_init`` / ``octree_next``): the state holds the ray and the finest-level
cell (ix, iy, iz) of the current point. Each step descends from the root to the leaf holding
that cell (integer bit tests, no floating point: at most D reads, no stack), yields
[t, t_exit] where t_exit is the nearest exit face of the leaf, and moves the cell index to
the neighbour leaf: one past the leaf along the exit axis, and along the other axes the cell
of the exit point clamped into the leaf's range and never backwards. So every index moves
monotonically along its direction, each step leaves the leaf along one axis, and a walk
takes at most 3 x 2^D steps. Robustness (case 6), as the DDA (dda.py): a zero direction
component (+0.0 or -0.0) never crosses its axis; the start cell is the clamped cell of the
point at t0, so rays starting on box, node or cell faces start in a valid leaf; segments
tile [t0, t1] (t_exit of one is t_enter of the next, clamped to [t, t1]); zero-length
segments can occur at edges and corners and callers skip them.

Walk state (float64 array of OCTREE_STATE_SIZE): [t, t1, ox, oy, oz, dx, dy, dz, ix, iy, iz,
done].
"""

import math

import numpy as np
from numba import njit

from ..constants import OCTREE_MAX_DEPTH

#: Leaves are split no finer than about this many voxels along the longest axis.
OCTREE_MIN_VOXELS = 8
#: Split a node while (max - min) x scale x diagonal exceeds this (Cycles, Pixar's Elemental).
OCTREE_SPLIT_THRESHOLD = 1.442

OCTREE_STATE_SIZE = 12


def octree_depth(shape_zyx, min_voxels=OCTREE_MIN_VOXELS):
    """Depth D whose cells are about ``min_voxels`` voxels along the longest axis (0 to
    OCTREE_MAX_DEPTH)."""
    n = max(int(s) for s in shape_zyx)
    return int(min(OCTREE_MAX_DEPTH, max(0, math.ceil(math.log2(max(n / min_voxels, 1.0))))))


def _pool(a, fn):
    """2x2x2 reduction of a cubic array of even side."""
    h = a.shape[0] // 2
    return fn(a.reshape(h, 2, h, 2, h, 2), axis=(1, 3, 5))


def build_octree(finest_max, finest_min, extent, scale, threshold=OCTREE_SPLIT_THRESHOLD):
    """(maxima, minima, children) of the octree over per-cell density bounds of the finest
    level (cubic arrays [2^D, 2^D, 2^D] from build_majorant_grid or majorant_from_bricks).

    extent: the box size (x, y, z) and scale the extinction per unit density, in one frame
    (the product scale x diagonal is frame-independent). maxima, minima: float32 [n_nodes];
    children: int32 [n_nodes] (module docstring)."""
    n = finest_max.shape[0]
    depth = int(round(math.log2(n)))
    if finest_max.shape != (n, n, n) or 2 ** depth != n or depth > OCTREE_MAX_DEPTH:
        raise ValueError(f"octree finest level must be cubic of side 2^D <= "
                         f"2^{OCTREE_MAX_DEPTH}, got {finest_max.shape}")
    levels = [(np.asarray(finest_max, np.float32), np.asarray(finest_min, np.float32))]
    for _ in range(depth):
        mx, mn = levels[0]
        levels.insert(0, (_pool(mx, np.max), _pool(mn, np.min)))
    diag = float(np.linalg.norm(np.asarray(extent, np.float64)))
    maxima, minima, children = [], [], []
    coords = np.zeros((1, 3), np.int64)      # (iz, iy, ix) of the frontier's nodes
    total = 1
    for level in range(depth + 1):
        mx, mn = levels[level]
        fmx = mx[coords[:, 0], coords[:, 1], coords[:, 2]]
        fmn = mn[coords[:, 0], coords[:, 1], coords[:, 2]]
        spread = (fmx.astype(np.float64) - fmn) * scale * (diag / 2 ** level)
        split = (spread > threshold) if level < depth else np.zeros(len(coords), bool)
        first = np.zeros(len(coords), np.int32)
        first[split] = total + 8 * np.arange(int(split.sum()))
        total += 8 * int(split.sum())
        maxima.append(fmx)
        minima.append(fmn)
        children.append(first)
        k = np.arange(8)
        octant = np.stack([(k >> 2) & 1, (k >> 1) & 1, k & 1], 1)    # (z, y, x) bits
        coords = (2 * coords[split][:, None, :] + octant[None, :, :]).reshape(-1, 3)
    return (np.concatenate(maxima).astype(np.float32), np.concatenate(minima).astype(np.float32),
            np.concatenate(children).astype(np.int32))


def octree_leaf_of(children, depth, cells):
    """(leaf index, leaf level) of finest-level cells [n, 3] (ix, iy, iz) (host, numpy)."""
    cells = np.asarray(cells, np.int64)
    node = np.zeros(len(cells), np.int64)
    level = np.zeros(len(cells), np.int64)
    for lv in range(depth):
        inner = children[node] != 0
        s = depth - 1 - lv
        octant = (((cells[:, 0] >> s) & 1) | (((cells[:, 1] >> s) & 1) << 1)
                  | (((cells[:, 2] >> s) & 1) << 2))
        node = np.where(inner, children[node] + octant, node)
        level += inner
    return node, level


@njit(cache=True)
def octree_init(state, o, d, t0, t1, bmin, bmax, depth):
    """Start a walk of ray o + t d over [t0, t1] (already clipped to the box [bmin, bmax])
    through the leaves of an octree of depth ``depth``."""
    n = 1 << depth
    state[0] = t0
    state[1] = t1
    state[11] = 1.0 if not t1 > t0 else 0.0
    for a in range(3):
        state[2 + a] = o[a]
        state[5 + a] = d[a]
        size = (bmax[a] - bmin[a]) / n
        i = int(math.floor(min(max((o[a] + t0 * d[a] - bmin[a]) / size, 0.0), n - 1.0)))
        state[8 + a] = i


@njit(cache=True)
def octree_next(state, children, bmin, bmax, depth):
    """Next leaf: (ok, t_enter, t_exit, node). ok is False once the walk is over."""
    if state[11] != 0.0:
        return False, 0.0, 0.0, 0
    ix, iy, iz = int(state[8]), int(state[9]), int(state[10])
    node = 0
    level = 0
    while level < depth and children[node] != 0:
        s = depth - 1 - level
        node = children[node] + (((ix >> s) & 1) | (((iy >> s) & 1) << 1)
                                 | (((iz >> s) & 1) << 2))
        level += 1
    span = 1 << (depth - level)
    n = 1 << depth
    a_exit = 0
    t_face = math.inf
    for a in range(3):
        da = state[5 + a]
        lo = (int(state[8 + a]) // span) * span
        if da != 0.0:
            face = lo + span if da > 0.0 else lo
            size = (bmax[a] - bmin[a]) / n
            tf = (bmin[a] + face * size - state[2 + a]) / da
            if tf < t_face:
                t_face = tf
                a_exit = a
    t_enter = state[0]
    t_exit = min(max(t_face, t_enter), state[1])
    if t_exit >= state[1]:
        state[11] = 1.0
    else:
        da = state[5 + a_exit]
        lo = (int(state[8 + a_exit]) // span) * span
        i = lo + span if da > 0.0 else lo - 1
        if i < 0 or i >= n:
            state[11] = 1.0
            t_exit = state[1]   # rounding left the box early: the last leaf ends the segment
        else:
            for a in range(3):
                if a == a_exit:
                    continue
                db = state[5 + a]
                if db == 0.0:
                    continue
                cur = int(state[8 + a])
                lo = (cur // span) * span
                size = (bmax[a] - bmin[a]) / n
                x = (state[2 + a] + t_exit * db - bmin[a]) / size
                x = min(max(x, float(lo)), lo + span - 1.0)
                j = int(math.floor(x))
                j = max(j, cur) if db > 0.0 else min(j, cur)
                state[8 + a] = j
            state[8 + a_exit] = i
    state[0] = t_exit
    return True, t_enter, t_exit, node


@njit(cache=True)
def octree_segments(o, d, t0, t1, bmin, bmax, children, depth, out):
    """Fill out[k] = (t_enter, t_exit, node) for the whole walk; returns the count."""
    state = np.empty(OCTREE_STATE_SIZE)
    octree_init(state, o, d, t0, t1, bmin, bmax, depth)
    k = 0
    while k < out.shape[0]:
        ok, ta, tb, node = octree_next(state, children, bmin, bmax, depth)
        if not ok:
            break
        out[k, 0], out[k, 1], out[k, 2] = ta, tb, node
        k += 1
    return k
