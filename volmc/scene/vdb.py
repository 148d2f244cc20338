"""Float grids from OpenVDB (.vdb) and NanoVDB (.nvdb) files, read as sparse 8^3 blocks.

API
---
``read_vdb(path, grid_name="density", key="medium.density") -> VdbGrid``
    Reads the float grid named ``grid_name``; the file kind is told by its first bytes,
    not by its suffix. Every failure is a ``SceneError(path, key, message)`` with a
    one-line message (file not found, not an OpenVDB/NanoVDB file, truncated or corrupt
    data, no grid of that name -- the message lists the grids the file has, with their
    kinds --, a grid that is not a float grid -- a vector grid is named as one --, a
    transform volmc cannot represent, unsupported compression or format version, a grid
    with no active voxels, more host memory than there is).

``list_grids(path, key="grid") -> [GridInfo]``
    Every grid of the file in file order, from the headers only: ``name``, ``kind``
    ("float", "half float", "double", "double saved as half", "Vec3s", "int32", "NanoVDB
    Fp16", ...), ``readable`` (read_vdb reads it) and ``note`` (why not: a vector grid, an
    integer grid, points, an instance). ``describe_grid_file(path)`` gives the lines
    ``volmc info FILE.vdb`` prints. Simulation caches hold many grids (Blender's Mantaflow:
    density, flame, temperature, fuel, ... with Vec3s velocity and int32 flags;
    docs/scene_format.md lists them).

``VdbGrid`` (a frozen dataclass):
    name            the grid's name.
    linear          3x3 tuple of rows: the index-to-world map's linear part (any
                    invertible one: scale, rotation, shear, mirror).
    index_to_world  (tx, ty, tz) floats, world units: the world position of index
                    coordinate (0, 0, 0). OpenVDB puts voxel CENTRES at integer index
                    coordinates, so voxel (i, j, k) is centred at
                    index_to_world + linear @ (i, j, k).
    ``voxel_size``      (sx, sy, sz): the world length of one voxel's edge along each index
                        axis (the diagonal of ``linear`` when the map is axis-aligned).
    ``axis_aligned``    True when ``linear`` is diagonal and positive.
    ``placement()``     (lo, hi, M): the box and the transform that place the grid as OpenVDB
                        does: an axis-aligned map gives its world box (``world_bounds``)
                        and M None; any other gives the box in index coordinates
                        [imin - 1/2, imax + 1/2] and M the 4x4 index-to-world matrix.
    bbox            ((imin_x, imin_y, imin_z), (imax_x, imax_y, imax_z)) ints: the index
                    bounding box of the active voxels, both corners inclusive.
    background      float: the value of every voxel outside leaves and tiles.
    origins         int32 array (n, 3): (x, y, z) index of each 8^3 block's minimum
                    voxel (multiples of 8), sorted by (x, y, z).
    values          float32 array (n, 8, 8, 8) indexed [block][z][y][x]. Inactive
                    voxels inside a leaf hold the value the file stores for them
                    (normally the background).
    fill_boxes      int64 array (m, 6): (x0, y0, z0, x1, y1, z1), the corners (lower
                    inclusive, upper exclusive, multiples of 8) of the inactive tiles whose
                    value is not the background, in file order; they hold ``fill_values``
                    (float32 (m,)) and never overlap a block in a valid file (where they
                    do, the block wins).
    ``shape``           (nz, ny, nx) of the active bbox.
    ``dense_box(lo, hi)``  float32 array [z, y, x] of the values OpenVDB's getValue gives
                        over the index box lo..hi (corners inclusive): block values where
                        there are blocks, fill values in the fill boxes, the background
                        elsewhere. ``to_dense()`` is that over the active bbox.
    ``stored_box()``    (lo, hi): the index box of everything stored; the background beyond.
    ``values_in_bbox()``  every stored value the bbox reads (for validation).
    ``fill_blocks()``   (origins, values) of the fill boxes, cut to the 8-aligned hull of
                        the bbox, as 8^3 blocks (``n_fill_blocks`` of them), for a sparse
                        copy; the caller checks the memory.
    ``world_bounds()``  ((xmin, ymin, zmin), (xmax, ymax, zmax)), world units: the box
                        which, under volmc's convention (a grid of n voxels spans its box
                        with voxel i's centre at bmin + (i + 0.5) * extent / n), puts the
                        dense grid's voxel centres exactly where OpenVDB puts them:
                        bmin = world(imin) - voxel_size / 2, bmax = world(imax) +
                        voxel_size / 2.

Reading builds no dense array: the blocks are the file's leaf nodes, plus one block per
8^3 piece of each ACTIVE tile of an internal or root node (a tile stands for a constant
8^3, 128^3 or 4096^3 region); tiles whose blocks would hold more than ``MAX_TILE_VOXELS``
voxels are rejected. Values are OpenVDB's ``getValue``, active or not: an INACTIVE tile
whose value is not the background (a level set's inside, a ``fill(..., active=False)``)
holds that value, as an inactive voxel of a leaf keeps its own. Such tiles are kept as
boxes (``fill_boxes``), not blocks: a file cannot make the reader expand them, and a
corrupt file's garbage tiles cost one array entry each. The blocks'
bytes are checked against the host memory available (hostmem.require_host) before they
are allocated, and a compressed NanoVDB grid's declared size before it is inflated.

Transforms: any affine map (OpenVDB's UniformScaleMap, UniformScaleTranslateMap, ScaleMap,
ScaleTranslateMap, TranslationMap, AffineMap and UnitaryMap; NanoVDB's matrix), including
rotation, shear and mirroring; the medium then carries it as its transform
(scene/transform.py). A singular, non-finite, projective or frustum map is an error.

Formats read (facts from OpenVDB's and NanoVDB's headers; no code of theirs):

* OpenVDB file format versions 222-225 (OpenVDB 3.0 to 13; 225 only adds half-typed
  grids), trees ``Tree_float_5_4_3`` and ``Tree_double_5_4_3`` (held as float32; a
  double beyond float32's range is an error), values stored at full width or as half
  floats (``saveFloatAsHalf``, the ``_HalfFloat`` type suffix), compression none,
  active-mask, zip and blosc (blosc needs the ``blosc`` package, a dependency). Grid
  instances (a grid sharing another's tree) and every other tree type are listed, not
  read.
* NanoVDB files of major version 32 with codec none, zip or blosc, grids of type Float.
  Quantized (Fp4/Fp8/Fp16/FpN), Half and other value types are rejected.

All multi-byte values are little-endian (both formats are written in host order, and
volmc does not read big-endian files). The structure of the file is checked (sizes,
offsets, counts, compressed streams, the nodes a NanoVDB tree reaches against its own
counts), so truncation and most corruption are errors; damaged voxel values are not (no
checksums are verified). Every loop is bounded by the file's bytes or the tree's counts;
tests/test_fuzz_readers.py fuzzes the reader. Tested against files written by OpenVDB
10.0 and 12.0 and NanoVDB 32.4 (tests/data/vdb, tests/data/fire).
"""

import mmap
import os
import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

from .errors import SceneError
from .hostmem import require_host

# Tiles expand into 8^3 blocks: refuse files whose active tiles would need more voxels
# than this (2^28 voxels = 1 GiB of float32).
MAX_TILE_VOXELS = 1 << 28

# Inactive tiles of a value other than the background are kept as boxes until the active
# bbox is known: at most this many (each costs 40 bytes; a 32^3 upper node has 32768).
MAX_FILL_TILES = 1 << 22

# Peak host bytes per leaf read (its float32 values, its mask, the mask's [z][y][x] copy)
# and per 8^3 block built (sorted float32 values, origin, the bbox pass's bool masks).
BYTES_PER_LEAF = 512 * 4 + 2 * 512
BYTES_PER_BLOCK = 512 * 4 + 12 + 2 * 512

# Transforms are refused beyond this many world units: volmc's bounds, voxel sizes and the
# device's float32 arithmetic stay finite below it.
MAX_WORLD = 1e30

VDB_MAGIC = 0x56444220  # " BDV" as a little-endian int64
VDB_MIN_VERSION = 222  # node-mask compression: the per-node metadata byte
VDB_MAX_VERSION = 225  # 224: multi-pass I/O; 225 (OpenVDB 13) adds half-typed grids and
#                        leaves the layout of float grids as it was
VDB_FLOAT_TREE = "Tree_float_5_4_3"
HALF_SUFFIX = "_HalfFloat"
COMPRESS_ZIP, COMPRESS_ACTIVE_MASK, COMPRESS_BLOSC = 0x1, 0x2, 0x4

NANO_MAGICS = (0x304244566F6E614E, 0x314244566F6E614E)  # "NanoVDB0", "NanoVDB1"
NANO_MAJOR = 32
NANO_CODECS = {0: "none", 1: "zip", 2: "blosc"}
NANO_TYPES = ("Unknown", "Float", "Double", "Int16", "Int32", "Int64", "Vec3f", "Vec3d",
              "Mask", "Half", "UInt32", "Boolean", "RGBA8", "Fp4", "Fp8", "Fp16", "FpN",
              "Vec4f", "Vec4d", "Index", "OnIndex", "IndexMask", "OnIndexMask", "PointIndex",
              "Vec3u8", "Vec3u16", "UInt8")
NANO_FLOAT = 1


@dataclass(frozen=True, eq=False)
class VdbGrid:
    """A sparse float grid read from a .vdb or .nvdb file (see the module docstring)."""

    name: str
    linear: tuple
    index_to_world: tuple
    bbox: tuple
    background: float
    origins: np.ndarray
    values: np.ndarray
    fill_boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 6), np.int64))
    fill_values: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))

    @property
    def shape(self):
        """(nz, ny, nx) of the active bounding box."""
        (x0, y0, z0), (x1, y1, z1) = self.bbox
        return (z1 - z0 + 1, y1 - y0 + 1, x1 - x0 + 1)

    def to_dense(self):
        """float32 [z, y, x] over the active bbox; the background outside blocks and fills."""
        return self.dense_box(*self.bbox)

    def dense_box(self, lo, hi):
        """float32 [z, y, x] over the index box lo..hi (corners inclusive): OpenVDB's
        getValue of each voxel, active or not."""
        lo = np.array(lo, np.int64)
        hi = np.array(hi, np.int64) + 1  # exclusive
        out = np.full(tuple((hi - lo)[::-1]), self.background, np.float32)
        for box, value in zip(self.fill_boxes, self.fill_values):
            a = np.maximum(box[:3], lo) - lo
            b = np.minimum(box[3:], hi) - lo
            if np.all(a < b):
                out[a[2]:b[2], a[1]:b[1], a[0]:b[0]] = value
        for origin, block in zip(self.origins.astype(np.int64), self.values):
            a = np.maximum(origin, lo)
            b = np.minimum(origin + 8, hi)
            if np.any(a >= b):
                continue
            (ax, ay, az), (bx, by, bz) = a - lo, b - lo
            (sx, sy, sz), (ex, ey, ez) = a - origin, b - origin
            out[az:bz, ay:by, ax:bx] = block[sz:ez, sy:ey, sx:ex]
        return out

    def stored_box(self):
        """(lo, hi) int64, corners inclusive: the index box of everything the grid stores
        (the active bbox, its blocks, its fill boxes); every voxel beyond holds the
        background."""
        lo = [np.asarray(self.bbox[0], np.int64)[None]]
        hi = [np.asarray(self.bbox[1], np.int64)[None]]
        lo += [self.origins.astype(np.int64), self.fill_boxes[:, :3]]
        hi += [self.origins.astype(np.int64) + 7, self.fill_boxes[:, 3:] - 1]
        return np.concatenate(lo).min(axis=0), np.concatenate(hi).max(axis=0)

    def values_in_bbox(self):
        """float32 (k,): every stored value the active bbox reads (the voxels of blocks
        inside it, the values of fill boxes that meet it), for validation."""
        lo = np.asarray(self.bbox[0], np.int64)
        hi = np.asarray(self.bbox[1], np.int64)
        o = self.origins.astype(np.int64)[:, :, None] + np.arange(8)   # (n, axis, 8)
        inside = (o >= lo[None, :, None]) & (o <= hi[None, :, None])
        mask = (inside[:, 2, :, None, None] & inside[:, 1, None, :, None]
                & inside[:, 0, None, None, :])                        # [n][z][y][x]
        meet = np.all((self.fill_boxes[:, :3] <= hi) & (self.fill_boxes[:, 3:] > lo), axis=1)
        return np.concatenate([self.values[mask], self.fill_values[meet]])

    def _fills_in_hull(self):
        """(boxes, values) of the fill boxes cut to the 8-aligned hull of the bbox, those
        that meet it."""
        lo = np.asarray(self.bbox[0], np.int64) // 8 * 8
        hi = np.asarray(self.bbox[1], np.int64) // 8 * 8 + 8
        a = np.maximum(self.fill_boxes[:, :3], lo)
        b = np.minimum(self.fill_boxes[:, 3:], hi)
        meet = np.all(a < b, axis=1)
        return np.concatenate([a, b], 1)[meet], self.fill_values[meet]

    @property
    def n_fill_blocks(self):
        """How many 8^3 blocks ``fill_blocks()`` makes."""
        boxes, _ = self._fills_in_hull()
        return int(np.prod(-((boxes[:, :3] - boxes[:, 3:]) // 8), axis=1).sum())  # ceiling

    def fill_blocks(self):
        """(origins int64 (k, 3), values float32 (k, 8, 8, 8)): the fill boxes within the
        bbox's 8-aligned hull as 8^3 blocks, in file order."""
        origins, values = [np.zeros((0, 3), np.int64)], [np.zeros(0, np.float32)]
        for box, value in zip(*self._fills_in_hull()):
            g = np.meshgrid(*[np.arange(box[i], box[i + 3], 8, dtype=np.int64)
                              for i in range(3)], indexing="ij")
            origins.append(np.stack([x.ravel() for x in g], 1))
            values.append(np.full(g[0].size, value, np.float32))
        v = np.concatenate(values)
        return (np.concatenate(origins),
                np.broadcast_to(v[:, None, None, None], (len(v), 8, 8, 8)).copy())

    @property
    def voxel_size(self):
        return tuple(float(v) for v in np.linalg.norm(np.asarray(self.linear), axis=0))

    @property
    def axis_aligned(self):
        m = np.asarray(self.linear)
        return bool(np.all(m == np.diag(np.diag(m))) and np.all(np.diag(m) > 0))

    def placement(self):
        """(lo, hi, M or None): see the module docstring."""
        if self.axis_aligned:
            return (*self.world_bounds(), None)
        lo = tuple(i - 0.5 for i in self.bbox[0])
        hi = tuple(i + 0.5 for i in self.bbox[1])
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = self.linear, self.index_to_world
        return lo, hi, m

    def world_bounds(self):
        """((xmin, ymin, zmin), (xmax, ymax, zmax)) in world units (module docstring) of an
        axis-aligned grid."""
        lo = tuple(t + (i - 0.5) * s for t, i, s in
                   zip(self.index_to_world, self.bbox[0], self.voxel_size))
        hi = tuple(t + (i + 0.5) * s for t, i, s in
                   zip(self.index_to_world, self.bbox[1], self.voxel_size))
        return lo, hi


def read_vdb(path, grid_name="density", key="medium.density"):
    """Read float grid ``grid_name`` of an OpenVDB or NanoVDB file as a VdbGrid."""
    return _with_reader(path, key, lambda r: r.read(grid_name))


def list_grids(path, key="grid"):
    """Every grid of an OpenVDB or NanoVDB file, in file order, as GridInfo records
    (name, kind, whether volmc reads it, and why not). Reads only the headers."""
    return _with_reader(path, key, lambda r: r.grids())


@dataclass(frozen=True)
class GridInfo:
    """One grid of a file: ``name``; ``kind`` ("float", "half float", "double", "Vec3s",
    "int32", ...); ``readable`` when read_vdb reads it; ``note`` says why not."""

    name: str
    kind: str
    readable: bool
    note: str = ""

    def text(self):
        tail = "" if self.readable else f" -- skipped: {self.note}"
        return f"'{self.name}' ({self.kind}){tail}"


def describe_grid_file(path, key="file"):
    """The lines ``volmc info FILE.vdb`` prints: the file's format and grid count, then one
    line per grid (GridInfo.text)."""
    infos = list_grids(path, key)   # raises for anything that is not a readable file
    with open(path, "rb") as f:
        nano = struct.unpack("<Q", f.read(8))[0] in NANO_MAGICS
    fmt = "NanoVDB" if nano else "OpenVDB"
    n = sum(g.readable for g in infos)
    return ([f"{path}: {fmt}, {len(infos)} grid{'s' * (len(infos) != 1)} ({n} read by volmc)"]
            + [f"  {g.text()}" for g in infos])


def _grid_list_text(infos):
    """"'density' (half float), 'velocity' (Vec3s, skipped)" for error messages."""
    return ", ".join(f"'{g.name}' ({g.kind}{'' if g.readable else ', skipped'})"
                     for g in infos) or "none"


def _with_reader(path, key, action):
    path = os.fspath(path)
    if os.path.exists(path) and not os.path.isdir(path) and not os.path.isfile(path):
        # A FIFO or device: open() would wait for a writer, and the reader maps the file.
        raise SceneError(path, key, "not a regular file")
    try:
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            if size == 0:
                raise SceneError(path, key, "empty file: not an OpenVDB or NanoVDB file")
            with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
                # Slicing an mmap copies, so nothing keeps the mapping after the read.
                head = mm[:8]
                if len(head) == 8 and struct.unpack("<Q", head)[0] in NANO_MAGICS:
                    return action(_NanoReader(mm, path, key))
                if len(head) == 8 and struct.unpack("<q", head)[0] == VDB_MAGIC:
                    return action(_VdbReader(mm, path, key))
                raise SceneError(path, key, "not an OpenVDB or NanoVDB file (unknown magic "
                                            "number)")
    except SceneError:
        raise
    except FileNotFoundError:
        raise SceneError(path, key, "grid file not found") from None
    except (OSError, ValueError, IndexError, KeyError, OverflowError, MemoryError,
            struct.error, zlib.error) as e:
        text = (str(e).splitlines() or [type(e).__name__])[0]
        raise SceneError(path, key, f"cannot read grid file: {text}") from None


# ---------------------------------------------------------------------------- helpers

class _Cursor:
    """Bounds-checked little-endian reads from a buffer."""

    def __init__(self, buf, path, key, what, pos=0):
        self.buf, self.path, self.key, self.what, self.pos = buf, path, key, what, pos

    def error(self, message):
        return SceneError(self.path, self.key, message)

    def take(self, n):
        if n < 0 or self.pos + n > len(self.buf):
            raise self.error(f"truncated or corrupt {self.what}: {n} bytes needed at offset "
                             f"{self.pos}, the data ends at {len(self.buf)}")
        data = self.buf[self.pos:self.pos + n]
        self.pos += n
        return data

    def unpack(self, fmt):
        return struct.unpack("<" + fmt, self.take(struct.calcsize("<" + fmt)))

    def u8(self):
        return self.unpack("B")[0]

    def i32(self):
        return self.unpack("i")[0]

    def u32(self):
        return self.unpack("I")[0]

    def i64(self):
        return self.unpack("q")[0]

    def string(self):
        return self.take(self.u32()).decode("utf-8", "replace")

    def array(self, dtype, count):
        dtype = np.dtype(dtype)
        return np.frombuffer(self.take(dtype.itemsize * count), dtype).copy()


def _bits(mask_bytes):
    """NodeMask bytes -> bool array; bit n is bit n % 8 of byte n // 8."""
    return np.unpackbits(np.frombuffer(mask_bytes, np.uint8), bitorder="little").astype(bool)


def _blosc_decompress(chunk, nbytes, cur):
    """Decompress one blosc frame that must hold exactly ``nbytes``."""
    if len(chunk) < 16:
        raise cur.error(f"corrupt blosc data in {cur.what} (frame of {len(chunk)} bytes)")
    declared, _, cbytes = struct.unpack("<III", chunk[4:16])
    if declared != nbytes or cbytes != len(chunk):
        raise cur.error(f"corrupt blosc data in {cur.what} (frame declares {declared} bytes "
                        f"in {cbytes}, expected {nbytes} in {len(chunk)})")
    try:
        import blosc
    except ImportError:
        raise cur.error("reading blosc-compressed data needs the Python package 'blosc' "
                        "(pip install blosc)") from None
    try:
        out = blosc.decompress(chunk)
    except Exception as e:  # the extension's own error class (blosc_extension.error)
        raise cur.error(f"corrupt blosc data in {cur.what} ({e})") from None
    if len(out) != nbytes:
        raise cur.error(f"corrupt blosc data in {cur.what}")
    return out


def _zlib_decompress(chunk, nbytes, cur):
    try:
        d = zlib.decompressobj()
        out = d.decompress(chunk, nbytes)
    except zlib.error as e:
        raise cur.error(f"corrupt zip data in {cur.what} ({e})") from None
    if len(out) != nbytes:
        raise cur.error(f"corrupt zip data in {cur.what} ({len(out)} of {nbytes} bytes)")
    return out


def _check_transform(m, t, cur, grid):
    """m: 3x3 with world = m @ index + t. Returns (linear, index_to_world) as tuples; an
    off-diagonal entry below 1e-9 of the largest (rounding in a file's AffineMap) is 0."""
    from .transform import singularity
    m = np.array(m, np.float64)
    if not np.all(np.isfinite(m)) or not np.all(np.isfinite(t)):
        raise cur.error(f"grid '{grid}': transform holds NaN or infinite values")
    scale = float(np.max(np.abs(m)))
    if scale > MAX_WORLD or float(np.max(np.abs(t))) > MAX_WORLD:
        raise cur.error(f"grid '{grid}': transform values beyond {MAX_WORLD:g} world units")
    m[np.abs(m) <= 1e-9 * scale] = 0.0
    full = np.eye(4)
    full[:3, :3] = m
    why = singularity(full) if scale > 0 else "it is zero"
    if why:
        raise cur.error(f"grid '{grid}': singular transform: {why}")
    return tuple(tuple(float(v) for v in row) for row in m), tuple(float(v) for v in t)


class _Blocks:
    """Collects leaf blocks, active tiles and the inactive tiles that are not the
    background, then builds the sorted arrays."""

    def __init__(self, cur, grid, background):
        self.cur, self.grid = cur, grid
        self.background = np.float32(background)
        self.leaf_origins, self.leaf_values = [], []  # lists of arrays
        self.tiles = []  # (origin xyz, size, value)
        self.tile_voxels = 0
        self.fills = []  # (boxes (k, 6) int64, values (k,) float32)
        self.n_fills = 0

    def add_tiles(self, origins, size, values, active):
        """One node's tiles: origins (k, 3), their edge ``size`` in voxels, values (k,),
        active (k,) bool. Active tiles become blocks; inactive ones of another value than
        the background are kept as fill boxes."""
        values = np.asarray(values, np.float32).reshape(-1)
        active = np.asarray(active, bool).reshape(-1)
        origins = np.asarray(origins, np.int64).reshape(-1, 3)
        # Every tile of a valid tree starts on a multiple of its own size, 8 at least: an
        # unaligned one would straddle blocks (and the fill blocks' count).
        if np.any(origins % 8):
            raise self.cur.error(f"corrupt {self.cur.what} (grid '{self.grid}': a tile origin "
                                 "is not a multiple of 8)")
        for n in np.flatnonzero(active):
            self.add_tile(origins[n], size, values[n])
        # NaN != background too: kept, so validation refuses it where it is read.
        keep = ~active & (values != self.background)
        if keep.any():
            self.n_fills += int(keep.sum())
            if self.n_fills > MAX_FILL_TILES:
                raise self.cur.error(f"grid '{self.grid}': more than {MAX_FILL_TILES} "
                                     "inactive tiles")
            o = origins[keep]
            self.fills.append((np.concatenate([o, o + size], 1), values[keep]))

    def add_tile(self, origin, size, value):
        self.tile_voxels += size ** 3
        if self.tile_voxels > MAX_TILE_VOXELS:
            raise self.cur.error(f"grid '{self.grid}': active tiles cover more than "
                                 f"{MAX_TILE_VOXELS} voxels; volmc expands tiles into 8^3 "
                                 "blocks and refuses this much")
        self.tiles.append((tuple(int(v) for v in origin), size, float(value)))

    def require_memory(self, n_leaves):
        """Check with the host memory available (hostmem.require_host) before the blocks
        are allocated: the leaves' values and masks as read, the sorted blocks (leaves and
        expanded tiles) and the masks of the bbox pass."""
        n_blocks = n_leaves + self.tile_voxels // 512
        require_host(n_leaves * BYTES_PER_LEAF + n_blocks * BYTES_PER_BLOCK, self.cur.path,
                     self.cur.key, f"reading grid '{self.grid}' ({n_leaves} leaves, "
                                   f"{n_blocks} blocks)")

    def to_grid(self, leaf_origins, values, active, linear, translation, background):
        """The VdbGrid of these tiles and the leaves at ``leaf_origins`` (n index triples),
        whose ``values`` (float, (n, 512)) and ``active`` masks (bool, (n, 512)) come in the
        files' leaf order, x-major ((x << 6) | (y << 3) | z). The active bbox covers the
        leaves' active voxels and the tiles (all active)."""
        n = len(leaf_origins)
        leaf_origins = np.array(leaf_origins, np.int64).reshape(-1, 3)
        self.leaf_origins.append(leaf_origins)
        self.leaf_values.append(np.asarray(values, np.float32).reshape(n, 8, 8, 8)
                                .transpose(0, 3, 2, 1))   # to [z][y][x]
        act_blocks = [np.asarray(active).reshape(n, 8, 8, 8).transpose(0, 3, 2, 1)]
        act_origins = [leaf_origins]
        origins, vals = self.build()
        for origin, size, _ in self.tiles:
            act_origins.append(np.array([origin, np.add(origin, size - 8)], np.int64))
            act_blocks.append(np.ones((2, 8, 8, 8), bool))
        bbox = _bbox_of_active(np.concatenate(act_origins), np.concatenate(act_blocks),
                               self.cur, self.grid)
        boxes = np.concatenate([np.zeros((0, 6), np.int64)] + [f[0] for f in self.fills])
        fill_values = np.concatenate([np.zeros(0, np.float32)] + [f[1] for f in self.fills])
        return VdbGrid(self.grid, linear, translation, bbox, background, origins, vals,
                       boxes, fill_values)

    def build(self):
        """(origins int32 (n, 3), values float32 (n, 8, 8, 8)) sorted by (x, y, z); each
        value is copied once, into its sorted place, and tiles are filled in place."""
        pieces = [(np.asarray(o, np.int64).reshape(-1, 3), v)
                  for o, v in zip(self.leaf_origins, self.leaf_values)]
        for origin, size, value in self.tiles:
            r = np.arange(0, size, 8, dtype=np.int64)
            gx, gy, gz = np.meshgrid(r, r, r, indexing="ij")
            o = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], 1) + np.array(origin, np.int64)
            pieces.append((o, np.float32(value)))
        o = np.concatenate([p[0] for p in pieces] + [np.zeros((0, 3), np.int64)])
        if np.any(o < np.iinfo(np.int32).min) or np.any(o > np.iinfo(np.int32).max - 8):
            raise self.cur.error(f"grid '{self.grid}': block origin out of range")
        order = np.lexsort((o[:, 2], o[:, 1], o[:, 0]))
        rank = np.empty_like(order)
        rank[order] = np.arange(len(order))
        values = np.empty((len(o), 8, 8, 8), np.float32)
        start = 0
        for origins, v in pieces:
            values[rank[start:start + len(origins)]] = v
            start += len(origins)
        return o[order].astype(np.int32), values


def _bbox_of_active(origins, active, cur, grid):
    """Inclusive index bbox of the active voxels: active is bool (n, 8, 8, 8) [z][y][x]."""
    any_z = active.any(axis=(2, 3))  # (n, 8) over z
    any_y = active.any(axis=(1, 3))
    any_x = active.any(axis=(1, 2))
    has = any_x.any(axis=1)
    if not has.any():
        raise cur.error(f"grid '{grid}' has no active voxels")
    lo, hi = [], []
    for axis, a in enumerate((any_x, any_y, any_z)):
        first = np.argmax(a, axis=1)
        last = 7 - np.argmax(a[:, ::-1], axis=1)
        o = origins[has, axis].astype(np.int64)
        lo.append(int((o + first[has]).min()))
        hi.append(int((o + last[has]).max()))
    return tuple(lo), tuple(hi)


# ---------------------------------------------------------------------------- OpenVDB

# OpenVDB tree value types (the X of Tree_X_5_4_3): (kind, bytes per value when volmc reads
# the grid, else None, why a grid of that kind is skipped).
_VDB_VALUES = {
    "float": ("float", 4, ""), "double": ("double", 8, ""),
    "vec3s": ("Vec3s", None, "vector grid; volmc reads scalar grids"),
    "vec3d": ("Vec3d", None, "vector grid; volmc reads scalar grids"),
    "vec3i": ("Vec3i", None, "vector grid; volmc reads scalar grids"),
    "half": ("half", None, "OpenVDB 13 half-typed grid; volmc reads float and double grids"),
    "int32": ("int32", None, "integer grid (Mantaflow's flags)"),
    "int64": ("int64", None, "integer grid"), "bool": ("bool", None, "boolean grid"),
    "mask": ("mask", None, "mask grid"),
    "ptdataidx32": ("points", None, "point data"), "ptdataidx64": ("points", None, "point data"),
    "ptidx32": ("point index", None, "point index"),
    "ptidx64": ("point index", None, "point index"),
}


class _VdbReader:
    def __init__(self, buf, path, key):
        self.cur = _Cursor(buf, path, key, "OpenVDB file")
        self.path, self.key = path, key

    def _descriptors(self):
        """[(name, type string, instance parent, grid offset)] of every grid, checking the
        header and that each grid lies inside the file."""
        cur = self.cur
        cur.pos = 8
        version = cur.u32()
        if not VDB_MIN_VERSION <= version <= VDB_MAX_VERSION:
            raise cur.error(f"OpenVDB file format version {version} unsupported (volmc reads "
                            f"{VDB_MIN_VERSION}-{VDB_MAX_VERSION}: OpenVDB 3.0 and later)")
        cur.u32(), cur.u32()  # library major, minor
        if not cur.u8():
            raise cur.error("OpenVDB file without grid offsets (written as a stream) is "
                            "unsupported")
        cur.take(36)  # UUID
        self._skip_metadata()
        count = cur.i32()
        if count < 0 or count > len(cur.buf) // 28:
            raise cur.error(f"corrupt OpenVDB file: grid count {count}")
        # Each grid descriptor is followed by its grid; the descriptor's end offset is
        # where the next descriptor starts.
        grids = []
        for _ in range(count):
            unique = cur.string()
            gtype = cur.string()
            parent = cur.string()
            grid_pos, _, end_pos = cur.i64(), cur.i64(), cur.i64()
            name = unique.split("\x1e")[0]
            if not cur.pos <= end_pos <= len(cur.buf):
                raise cur.error(f"truncated or corrupt OpenVDB file: grid '{name}' "
                                f"ends at offset {end_pos}, the file at {len(cur.buf)}")
            if not cur.pos <= grid_pos <= end_pos:
                raise cur.error(f"corrupt OpenVDB file: grid '{name}' at offset {grid_pos}")
            grids.append((name, gtype, parent, grid_pos))
            cur.pos = end_pos
        return grids

    @staticmethod
    def _info(name, gtype, parent):
        """(GridInfo, bytes per value or None, stored as halves)."""
        half = gtype.endswith(HALF_SUFFIX)
        base = gtype[:-len(HALF_SUFFIX)] if half else gtype
        value = base[len("Tree_"):-len("_5_4_3")] \
            if base.startswith("Tree_") and base.endswith("_5_4_3") else None
        kind, vsize, note = _VDB_VALUES.get(value, (base[:60], None, "unknown tree type"))
        if vsize and half:
            kind = "half float" if value == "float" else f"{kind} saved as half"
        if vsize and parent:
            vsize, note = None, f"instance of grid '{parent}' (shares its tree)"
        return GridInfo(name, kind, vsize is not None, note), vsize, half

    def grids(self):
        return [self._info(n, t, p)[0] for n, t, p, _ in self._descriptors()]

    def read(self, grid_name):
        cur = self.cur
        grids = self._descriptors()
        match = [g for g in grids if g[0] == grid_name]
        infos = [self._info(n, t, p)[0] for n, t, p, _ in grids]
        if not match:
            raise cur.error(f"no grid named '{grid_name}' (the file has: "
                            f"{_grid_list_text(infos)})")
        name, gtype, parent, grid_pos = match[0]
        info, vsize, half = self._info(name, gtype, parent)
        if not info.readable:
            floats = ", ".join(f"'{g.name}'" for g in infos if g.readable) or "none"
            what = "a vector grid" if "vector" in info.note else "not a float grid"
            raise cur.error(f"grid '{name}' is {what} ({info.kind}: {info.note}); the "
                            f"file's float grids: {floats}")
        cur.pos = grid_pos
        self.cur.what = f"OpenVDB grid '{name}'"
        return self._read_grid(name, half, vsize)

    def _skip_metadata(self):
        cur = self.cur
        n = cur.i32()
        if n < 0 or n > len(cur.buf) // 12:
            raise cur.error(f"corrupt OpenVDB metadata (count {n})")
        for _ in range(n):
            cur.string()  # name
            cur.string()  # type
            cur.take(cur.u32())

    def _read_grid(self, name, half, vsize):
        cur = self.cur
        comp = cur.u32()
        if comp & ~(COMPRESS_ZIP | COMPRESS_ACTIVE_MASK | COMPRESS_BLOSC):
            raise cur.error(f"grid '{name}': unsupported compression flags {comp:#x}")
        if comp & COMPRESS_ZIP and comp & COMPRESS_BLOSC:
            raise cur.error(f"grid '{name}': unsupported compression flags {comp:#x} (zip "
                            "and blosc)")
        self.comp, self.half, self.vsize = comp, half, vsize
        self.vtype = "<f4" if vsize == 4 else "<f8"
        self._skip_metadata()
        linear, translation = self._read_transform(name)

        # Topology: buffer count, root (background, tiles, children), internal nodes
        # depth first, leaf value masks.
        if cur.i32() != 1:
            raise cur.error(f"grid '{name}': unsupported tree (buffer count is not 1)")
        self.background = self._value()
        blocks = _Blocks(cur, name, self.background)
        n_tiles, n_children = cur.u32(), cur.u32()
        if n_tiles > len(cur.buf) // (13 + vsize) or n_children > len(cur.buf) // 12:
            raise cur.error(f"corrupt OpenVDB grid '{name}' (root counts {n_tiles}, "
                            f"{n_children})")
        for _ in range(n_tiles):
            x, y, z = cur.unpack("iii")
            value = self._value()
            blocks.add_tiles((x, y, z), 4096, value, cur.u8() != 0)
        uppers = []
        for _ in range(n_children):
            origin = cur.unpack("iii")
            uppers.append((origin, self._read_internal(origin, 5, blocks)))
        # Buffers come in the root's table order: children sorted by origin (x, y, z).
        uppers.sort(key=lambda u: u[0])
        leaf_origins = [o for _, lowers in uppers for leaves in lowers for o in leaves]
        n = len(leaf_origins)
        blocks.require_memory(n)
        values = np.empty((n, 512), np.float32)
        active = np.empty((n, 512), bool)
        for i in range(n):
            mask = _bits(cur.take(64))
            active[i] = mask
            values[i] = self._read_values(512, mask)
        return blocks.to_grid(leaf_origins, values, active, linear, translation,
                              self.background)

    def _value(self):
        """One value at full width (a background, tile or inactive value: OpenVDB writes
        these unhalved even in a half-float grid)."""
        return float(self._float32(np.frombuffer(self.cur.take(self.vsize), self.vtype))[0])

    def _float32(self, vals):
        """``vals`` as float32; a double beyond float32's range is an error, not an inf."""
        with np.errstate(over="ignore", invalid="ignore"):
            out = vals.astype(np.float32)
        if vals.dtype.itemsize == 8:
            lost = np.isinf(out) & np.isfinite(vals)
            if lost.any():
                raise self.cur.error(f"grid value {float(vals[lost][0]):g} overflows float32 "
                                     "(volmc holds grids as float32)")
        return out

    def _read_transform(self, name):
        cur = self.cur
        kind = cur.string()
        if kind in ("UniformScaleMap", "ScaleMap"):
            scale = cur.unpack("3d")
            cur.take(4 * 24)  # voxel size, inverse scale, 1/scale^2, 1/(2 scale)
            return _check_transform(np.diag(scale), (0.0, 0.0, 0.0), cur, name)
        if kind in ("UniformScaleTranslateMap", "ScaleTranslateMap"):
            translation = cur.unpack("3d")
            scale = cur.unpack("3d")
            cur.take(4 * 24)
            return _check_transform(np.diag(scale), translation, cur, name)
        if kind == "TranslationMap":
            return _check_transform(np.eye(3), cur.unpack("3d"), cur, name)
        if kind in ("AffineMap", "UnitaryMap"):
            # Row-vector convention: world = [i j k 1] . M, translation in the last row.
            m = np.array(cur.unpack("16d")).reshape(4, 4)
            if np.any(m[:3, 3] != 0) or m[3, 3] != 1:
                raise cur.error(f"grid '{name}': projective transform ({kind}) unsupported")
            return _check_transform(m[:3, :3].T, m[3, :3], cur, name)
        if kind == "NonlinearFrustumMap":
            raise cur.error(f"grid '{name}': frustum transform unsupported; volmc needs an "
                            "affine one")
        raise cur.error(f"grid '{name}': unknown transform type '{kind[:40]}'")

    def _read_internal(self, origin, log2, blocks):
        """Read an internal node's topology (log2 5: upper, 4: lower). Returns, for an
        upper node, a list per lower child of its leaf origins; for a lower node, its
        leaf origins."""
        cur = self.cur
        nbytes = (1 << 3 * log2) // 8
        child = _bits(cur.take(nbytes))
        value_on = _bits(cur.take(nbytes))
        tiles = self._read_values(1 << 3 * log2, value_on)
        child_log2 = 7 if log2 == 5 else 3  # log2 of a child's extent in voxels
        idx = np.arange(1 << 3 * log2)
        local = np.stack([idx >> 2 * log2, (idx >> log2) & ((1 << log2) - 1),
                          idx & ((1 << log2) - 1)], 1)
        coords = np.asarray(origin, np.int64) + (local << child_log2)
        blocks.add_tiles(coords[~child], 1 << child_log2, tiles[~child], value_on[~child])
        kids = coords[child]
        if log2 == 5:
            return [self._read_internal(tuple(c), 4, blocks) for c in kids]
        for _ in range(len(kids)):
            cur.take(64)  # the leaf's value mask (read again with its buffer)
        return [tuple(int(v) for v in c) for c in kids]

    def _read_values(self, count, value_on):
        """One node's value array (float32, count), stored with the grid's compression."""
        cur = self.cur
        meta = cur.u8()
        if meta > 6:
            raise cur.error(f"corrupt {cur.what} (value metadata {meta})")
        bg = self.background
        inactive0 = bg if meta == 0 else -bg
        inactive1 = bg
        if meta in (2, 4, 5):
            inactive0 = self._value()
            if meta == 5:
                inactive1 = self._value()
        select = _bits(cur.take(count // 8)) if meta in (3, 4, 5) else None
        stored = count
        if self.comp & COMPRESS_ACTIVE_MASK and meta != 6:
            stored = int(value_on.sum())
        itemsize = 2 if self.half else self.vsize
        data = self._read_data(stored * itemsize)
        vals = self._float32(np.frombuffer(data, "<f2" if self.half else self.vtype))
        if stored == count:
            return vals
        out = np.where(select, np.float32(inactive1), np.float32(inactive0)) \
            if select is not None else np.full(count, inactive0, np.float32)
        out = out.astype(np.float32)
        out[value_on] = vals
        return out

    def _read_data(self, nbytes):
        cur = self.cur
        if nbytes == 0 and self.half:
            return b""  # half floats: no values, nothing written (not even a size)
        if not self.comp & (COMPRESS_ZIP | COMPRESS_BLOSC):
            return cur.take(nbytes)
        size = cur.i64()
        if size <= 0:  # stored uncompressed (compression did not pay)
            if -size != nbytes:
                raise cur.error(f"corrupt {cur.what} ({-size} raw bytes, expected {nbytes})")
            return cur.take(nbytes)
        chunk = cur.take(size)
        if self.comp & COMPRESS_BLOSC:
            return _blosc_decompress(chunk, nbytes, cur)
        return _zlib_decompress(chunk, nbytes, cur)


# ---------------------------------------------------------------------------- NanoVDB

class _NanoReader:
    META = struct.Struct("<QQQQII6d6i3dI4I3IHHI")  # 176 bytes: one grid's file metadata

    def __init__(self, buf, path, key):
        self.cur = _Cursor(buf, path, key, "NanoVDB file")

    def _segments(self):
        """[(name, grid type, grid size, bytes in the file, codec, offset)] of every grid.
        Walks every segment (header, grid metadata, grid data), so a truncated file is an
        error whichever grid is read."""
        cur = self.cur
        grids = []
        while cur.pos < len(cur.buf):
            magic, version, count, codec = cur.unpack("QIHH")
            if magic not in NANO_MAGICS:
                raise cur.error(f"corrupt NanoVDB file (bad segment magic at offset "
                                f"{cur.pos - 16})")
            major = version >> 21
            if major != NANO_MAJOR:
                raise cur.error(f"NanoVDB version {major}.{(version >> 10) & 2047} "
                                f"unsupported (volmc reads {NANO_MAJOR}.x)")
            metas = []
            for _ in range(count):
                m = self.META.unpack(cur.take(self.META.size))
                name = cur.take(m[21]).split(b"\0")[0].decode("utf-8", "replace")
                metas.append((name, m))
            for name, m in metas:
                grid_size, file_size, gtype = m[0], m[1], m[4]
                grids.append((name, gtype, grid_size, file_size, codec, cur.pos))
                cur.take(file_size)  # skip (bounds-checked)
        return grids

    @staticmethod
    def _info(name, gtype):
        if gtype == NANO_FLOAT:
            return GridInfo(name, "float", True)
        tname = NANO_TYPES[gtype] if gtype < len(NANO_TYPES) else f"type {gtype}"
        why = ("vector grid; volmc reads scalar grids" if tname.startswith("Vec")
               else "quantized or non-float grid; volmc reads NanoVDB Float grids")
        return GridInfo(name, f"NanoVDB {tname}", False, why)

    def grids(self):
        return [self._info(g[0], g[1]) for g in self._segments()]

    def read(self, grid_name):
        cur = self.cur
        grids = self._segments()
        infos = [self._info(g[0], g[1]) for g in grids]
        found = next((g for g in grids if g[0] == grid_name), None)
        if found is None:
            raise cur.error(f"no grid named '{grid_name}' (the file has: "
                            f"{_grid_list_text(infos)})")
        name, gtype, grid_size, file_size, codec, pos = found
        info = self._info(name, gtype)
        if not info.readable:
            floats = ", ".join(f"'{g.name}'" for g in infos if g.readable) or "none"
            what = "a vector grid" if "vector" in info.note else "not a float grid"
            raise cur.error(f"grid '{name}' is {what} ({info.kind}: {info.note}); the "
                            f"file's float grids: {floats}")
        if codec not in NANO_CODECS:
            raise cur.error(f"grid '{name}': unsupported NanoVDB codec {codec}")
        cur.pos = pos
        cur.what = f"NanoVDB grid '{name}'"
        end = pos + file_size
        # A compressed grid declares its own size: check it before inflating (a small
        # zip stream can declare, and inflate to, a thousand times its bytes).
        require_host(2 * grid_size, cur.path, cur.key, f"reading NanoVDB grid '{name}' "
                                                       f"({grid_size} bytes)")
        if codec == 0:
            if file_size != grid_size:
                raise cur.error(f"corrupt {cur.what} (size {file_size}, expected {grid_size})")
            data = cur.take(grid_size)
        elif codec == 1:
            data = _zlib_decompress(cur.take(cur.i64()), grid_size, cur)
        else:
            parts, left = [], grid_size
            while left > 0:
                n = min(left, 1 << 30)
                parts.append(_blosc_decompress(cur.take(cur.i64()), n, cur))
                left -= n
            data = b"".join(parts)
        if cur.pos != end:
            raise cur.error(f"corrupt {cur.what} (compressed size mismatch)")
        return _NanoGrid(data, cur).parse(name)


class _NanoGrid:
    """Parses one NanoVDB Float grid buffer (offsets from NanoVDB 32's GridData etc.)."""

    ROOT_TILES, TILE_SIZE = 64, 32
    UPPER_SIZE, UPPER_VMASK, UPPER_CMASK, UPPER_TABLE = 270400, 32, 4128, 8256
    LOWER_SIZE, LOWER_VMASK, LOWER_CMASK, LOWER_TABLE = 33856, 32, 544, 1088
    LEAF_SIZE, LEAF_VALUES = 2144, 96

    def __init__(self, data, parent_cur):
        self.buf = data
        self.cur = _Cursor(data, parent_cur.path, parent_cur.key, parent_cur.what)

    def at(self, pos, fmt):
        self.cur.pos = pos
        return self.cur.unpack(fmt)

    def parse(self, name):
        cur = self.cur
        magic, = self.at(0, "Q")
        version, = self.at(16, "I")
        grid_size, = self.at(32, "Q")
        if magic not in NANO_MAGICS or version >> 21 != NANO_MAJOR or grid_size != len(self.buf):
            raise cur.error(f"corrupt {cur.what} (bad grid header)")
        mat = np.array(self.at(296 + 88, "9d")).reshape(3, 3)  # world = mat @ index + vec
        vec = self.at(296 + 232, "3d")
        taper, = self.at(296 + 256, "d")
        if taper != 1.0:
            raise cur.error(f"grid '{name}': frustum (tapered) transform unsupported")
        linear, translation = _check_transform(mat, vec, cur, name)
        gtype, = self.at(636, "I")
        if gtype != NANO_FLOAT:
            raise cur.error(f"corrupt {cur.what} (grid type {gtype} in the grid, Float in "
                            "the file header)")
        tree = 672
        off_leaf, off_lower, off_upper, off_root = self.at(tree, "4Q")
        n_leaf, n_lower, n_upper = self.at(tree + 32, "3I")
        root = tree + off_root
        table_size, = self.at(root + 24, "I")
        background = float(np.frombuffer(self.buf, "<f4", 1, root + 28)[0])
        if table_size > len(self.buf) // self.TILE_SIZE:
            raise cur.error(f"corrupt {cur.what} (root table size {table_size})")
        self.leaf_base, self.n_leaf = tree + off_leaf, n_leaf
        if n_leaf and self.leaf_base + n_leaf * self.LEAF_SIZE > len(self.buf):
            raise cur.error(f"corrupt {cur.what} (leaf array outside the grid)")
        blocks = _Blocks(cur, name, background)
        leaf_index, leaf_origin = [], []
        # Child offsets are free to point at one node many times: count the nodes reached
        # against the tree's own counts, so a corrupt table cannot make the walk (or its
        # lists) grow past the grid's size.
        self.budget = {5: n_upper, 4: n_lower}
        for t in range(table_size):
            tile = root + self.ROOT_TILES + t * self.TILE_SIZE
            key, child, state = self.at(tile, "QqI")
            value = float(np.frombuffer(self.buf, "<f4", 1, tile + 20)[0])
            # Key: x, y, z >> 12 as 21-bit fields (x highest); back to int32 coordinates.
            origin = [(((key >> s) & 0x1FFFFF) << 12) & 0xFFFFFFFF for s in (42, 21, 0)]
            origin = [v - (1 << 32) if v >= 1 << 31 else v for v in origin]
            if child == 0:
                blocks.add_tiles(origin, 4096, value, state != 0)
                continue
            self._internal(root + child, origin, 5, blocks, leaf_index, leaf_origin)
        idx = np.array(leaf_index, np.int64)
        if len(idx) != len(np.unique(idx)):
            raise cur.error(f"corrupt {cur.what} (a leaf is referenced twice)")
        blocks.require_memory(len(idx))
        leaves = np.ndarray((n_leaf, 536), "<f4", self.buf, self.leaf_base,
                            (self.LEAF_SIZE, 4)) if n_leaf else np.zeros((0, 536), "<f4")
        vals = leaves[idx, self.LEAF_VALUES // 4:self.LEAF_VALUES // 4 + 512]
        masks = np.ndarray((n_leaf, 64), np.uint8, self.buf, self.leaf_base + 16,
                           (self.LEAF_SIZE, 1)) if n_leaf else np.zeros((0, 64), np.uint8)
        active = np.unpackbits(masks[idx], axis=1, bitorder="little").astype(bool)
        return blocks.to_grid(leaf_origin, vals, active, linear, translation, background)

    def _internal(self, node, origin, log2, blocks, leaf_index, leaf_origin):
        cur = self.cur
        if log2 == 5:
            size, vmask, cmask, table = (self.UPPER_SIZE, self.UPPER_VMASK, self.UPPER_CMASK,
                                         self.UPPER_TABLE)
        else:
            size, vmask, cmask, table = (self.LOWER_SIZE, self.LOWER_VMASK, self.LOWER_CMASK,
                                         self.LOWER_TABLE)
        if node < 0 or node + size > len(self.buf):
            raise cur.error(f"corrupt {cur.what} (node offset {node} outside the grid)")
        self.budget[log2] -= 1
        if self.budget[log2] < 0:
            raise cur.error(f"corrupt {cur.what} (more {'upper' if log2 == 5 else 'lower'} "
                            "nodes reached than the tree holds)")
        count = 1 << 3 * log2
        value_on = _bits(self.buf[node + vmask:node + vmask + count // 8])
        child = _bits(self.buf[node + cmask:node + cmask + count // 8])
        entries = np.frombuffer(self.buf, "<i8", count, node + table)
        tile_vals = np.frombuffer(self.buf, "<f4", 2 * count, node + table)[::2]
        idx = np.arange(count)
        local = np.stack([idx >> 2 * log2, (idx >> log2) & ((1 << log2) - 1),
                          idx & ((1 << log2) - 1)], 1)
        child_log2 = 7 if log2 == 5 else 3
        coords = np.asarray(origin, np.int64) + (local << child_log2)
        blocks.add_tiles(coords[~child], 1 << child_log2, tile_vals[~child],
                         value_on[~child])
        kids = np.flatnonzero(child)
        if log2 == 5:
            for n in kids:
                self._internal(node + int(entries[n]), coords[n], 4, blocks, leaf_index,
                               leaf_origin)
            return
        rel = node + entries[kids] - self.leaf_base
        k = rel // self.LEAF_SIZE
        if np.any(rel % self.LEAF_SIZE) or np.any(k < 0) or np.any(k >= self.n_leaf):
            raise cur.error(f"corrupt {cur.what} (leaf offset outside the leaf array)")
        if len(leaf_index) + len(k) > self.n_leaf:
            raise cur.error(f"corrupt {cur.what} (more leaves reached than the tree holds)")
        leaf_index.extend(k.tolist())
        leaf_origin.extend(coords[kids].tolist())
