"""OpenVDB (.vdb) and NanoVDB (.nvdb) float grids against ground truth made by OpenVDB itself.

The fixtures in tests/data/vdb were written by OpenVDB 10.0.1 and NanoVDB 32.4.2
(make_fixtures.py there says how); each NAME.npy holds OpenVDB's value of every voxel of
the active bounding box, NAME.json the bbox, transform and sample voxels with the world
centres OpenVDB computes for them.
"""

import gzip
import json
import random
import shutil
import struct
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

import volmc.scene.vdb as vdb_module
from volmc.scene.errors import SceneError
from volmc.scene.vdb import MAX_TILE_VOXELS, VdbGrid, read_vdb

DATA = Path(__file__).resolve().parent / "data" / "vdb"
KEY = "medium.density"

# (file, grid, ground truth) -- every compression of the same grids.
BLOBS = ["blobs.vdb", "blobs_zip.vdb", "blobs_mask.vdb", "blobs_none.vdb.gz",
         "blobs_zip.nvdb", "blobs_blosc.nvdb", "blobs_none.nvdb.gz"]
CASES = ([(f, "density", "blobs_density") for f in BLOBS]
         + [(f, "temperature", "blobs_temperature")
            for f in ("blobs.vdb", "blobs_zip.vdb", "blobs_zip.nvdb", "blobs_none.nvdb.gz")]
         + [(f, "density", "half") for f in ("half.vdb", "half_zip.vdb")]
         + [(f, "density", "quirks")
            for f in ("quirks.vdb", "quirks_zip.vdb", "quirks_mask.vdb", "quirks.nvdb")]
         + [(f, "density", "nonuniform") for f in ("nonuniform.vdb", "nonuniform.nvdb")]
         + [(f, "density", "levelset") for f in ("levelset.vdb", "levelset.nvdb")]
         + [(f, "density", "inactive") for f in ("inactive.vdb", "inactive.nvdb")])


def fixture_path(name, tmp_path):
    """The fixture's path; a gzipped one is unpacked into tmp_path."""
    if not name.endswith(".gz"):
        return DATA / name
    out = tmp_path / name[:-3]
    with gzip.open(DATA / name, "rb") as fi, open(out, "wb") as fo:
        shutil.copyfileobj(fi, fo)
    return out


def truth(name):
    with open(DATA / f"{name}.json") as f:
        info = json.load(f)
    dense = np.load(DATA / f"{name}.npy") if (DATA / f"{name}.npy").exists() else None
    return dense, info


def block_value(grid, ijk):
    """The value at index ijk from the sparse blocks (None if no block holds it)."""
    ijk = np.asarray(ijk)
    hit = np.flatnonzero(np.all(grid.origins == (ijk & ~7), axis=1))
    if len(hit) == 0:
        return None
    assert len(hit) == 1
    x, y, z = ijk - grid.origins[hit[0]]
    return float(grid.values[hit[0], z, y, x])


def stored_value(grid, ijk):
    """The value at index ijk as the grid stores it: its block's, else a fill box's, else
    the background."""
    v = block_value(grid, ijk)
    if v is not None:
        return v
    inside = np.all((grid.fill_boxes[:, :3] <= ijk) & (np.asarray(ijk) < grid.fill_boxes[:, 3:]),
                    axis=1)
    return float(grid.fill_values[inside][-1]) if inside.any() else grid.background


def raises_scene_error(path, match=None, **kw):
    """read_vdb must raise SceneError naming the file and the key, in one line."""
    with pytest.raises(SceneError) as e:
        read_vdb(path, **kw)
    text = str(e.value)
    assert e.value.file == str(path) and text.startswith(f"{path}: {kw.get('key', KEY)}: ")
    assert "\n" not in text
    if match:
        assert match in text, text
    return text


# ------------------------------------------------------------------ values and bounds

@pytest.mark.parametrize("name,grid,gt", CASES)
def test_matches_openvdb_ground_truth(name, grid, gt, tmp_path):
    g = read_vdb(fixture_path(name, tmp_path), grid)
    dense, info = truth(gt)
    assert isinstance(g, VdbGrid) and g.name == grid
    assert g.bbox == (tuple(info["imin"]), tuple(info["imax"]))
    assert g.background == info["background"]
    np.testing.assert_allclose(g.voxel_size, info["voxel_size"], rtol=1e-14)
    np.testing.assert_allclose(g.index_to_world, info["world_of_index_origin"], atol=1e-14)
    np.testing.assert_allclose(g.world_bounds(), info["world_bounds"], rtol=0, atol=1e-12)
    d = g.to_dense()
    assert d.dtype == np.float32 and d.shape == g.shape == dense.shape
    np.testing.assert_array_equal(d, dense)


@pytest.mark.parametrize("name,grid,gt", CASES)
def test_sparse_blocks(name, grid, gt, tmp_path):
    """origins/values directly: layout, and OpenVDB's value at every sample voxel --
    inactive voxels inside leaves, a leaf with no active voxel, tiles."""
    g = read_vdb(fixture_path(name, tmp_path), grid)
    _, info = truth(gt)
    assert g.origins.dtype == np.int32 and g.origins.shape == (len(g.values), 3)
    assert g.values.dtype == np.float32 and g.values.shape[1:] == (8, 8, 8)
    assert np.all(g.origins % 8 == 0)
    assert len(np.unique(g.origins, axis=0)) == len(g.origins)
    assert np.all(np.diff(g.origins[:, 0]) >= 0)  # sorted by (x, y, z)
    for s in info["samples"]:
        assert stored_value(g, s["index"]) == s["value"], s


def test_inactive_tiles_hold_their_values():
    """Inactive tiles of another value than the background, at each level of the tree (8^3
    in a lower node, 128^3 in an upper node, a 4096^3 root tile), read as OpenVDB's getValue
    gives them, as boxes cut to the bbox's 8-aligned hull: not as blocks, not as 0."""
    _, info = truth("inactive")
    for name in ("inactive.vdb", "inactive.nvdb"):
        g = read_vdb(DATA / name)
        lo, hi = np.array(g.bbox[0]) // 8 * 8, np.array(g.bbox[1]) // 8 * 8 + 8
        sides = g.fill_boxes[:, 3:] - g.fill_boxes[:, :3]
        # Each tile whole (as a box, never expanded): its value and its level's edge.
        assert {(float(v), int(e)) for v, e in zip(g.fill_values, sides[:, 0])} == {
            (float(np.float32(0.6)), 8), (float(np.float32(0.2)), 128),
            (float(np.float32(0.1)), 4096)}
        assert np.all(sides == sides[:, :1]) and np.all(g.fill_boxes % 8 == 0)
        assert len(g.origins) == 4     # the leaves of the four active voxels only
        o, v = g.fill_blocks()         # cut to the bbox's 8-aligned hull
        assert len(o) == len(v) == g.n_fill_blocks
        assert np.all(o >= lo) and np.all(o + 8 <= hi)
        for s in info["samples"]:
            if block_value(g, s["index"]) is not None:
                continue      # a leaf's voxel
            hit = np.flatnonzero(np.all(o == (np.array(s["index"]) & ~7), axis=1))
            x, y, z = np.array(s["index"]) - (o[hit[0]] if len(hit) else 0)
            assert (v[hit[0], z, y, x] if len(hit) else g.background) == s["value"], s


def test_an_unaligned_tile_is_corrupt(tmp_path):
    """A tile origin off the multiples of 8 (only a damaged file has one) is refused: cut to
    the bbox's hull such a fill box was counted as fewer blocks than fill_blocks() made, so
    the memory check of brick storage could be bypassed. The count is a ceiling anyway."""
    import dataclasses
    data = bytearray((DATA / "inactive.vdb").read_bytes())
    i = data.find(struct.pack("<iii", -4096, 0, 0))      # the root tile's record
    struct.pack_into("<i", data, i, -4092)
    (tmp_path / "bad.vdb").write_bytes(bytes(data))
    raises_scene_error(tmp_path / "bad.vdb", "not a multiple of 8")
    g = read_vdb(DATA / "inactive.vdb")
    odd = dataclasses.replace(g, fill_boxes=np.array([[-4, 0, 0, 4, 12, 5]], np.int64),
                              fill_values=np.array([0.5], np.float32))
    assert odd.n_fill_blocks == len(odd.fill_blocks()[0]) == 1 * 2 * 1


def test_quirks_leaf_and_tile_contents():
    """Inactive values stored in leaves are kept; the empty leaf is a block; the
    lower-node tile became one constant 8^3 block."""
    for name in ("quirks.vdb", "quirks.nvdb"):
        g = read_vdb(DATA / name)
        assert block_value(g, (1, 1, 3)) == 0.5  # inactive, in an active voxel's leaf
        assert block_value(g, (40, 41, 42)) == 0.375  # leaf without active voxels
        assert (40, 40, 40) in set(map(tuple, g.origins.tolist()))
        tile = g.values[np.flatnonzero(np.all(g.origins == (8, 0, 0), axis=1))[0]]
        assert np.all(tile == 0.75)


@pytest.mark.parametrize("group", [
    BLOBS, ["quirks.vdb", "quirks_zip.vdb", "quirks_mask.vdb", "quirks.nvdb"],
    ["nonuniform.vdb", "nonuniform.nvdb"], ["bigtile.vdb", "bigtile.nvdb"],
    ["levelset.vdb", "levelset.nvdb"], ["inactive.vdb", "inactive.nvdb"]])
def test_vdb_equals_nvdb_exactly(group, tmp_path):
    grids = [read_vdb(fixture_path(n, tmp_path)) for n in group]
    a = grids[0]
    for b in grids[1:]:
        np.testing.assert_array_equal(a.origins, b.origins)
        np.testing.assert_array_equal(a.values, b.values)
        np.testing.assert_array_equal(a.fill_boxes, b.fill_boxes)
        np.testing.assert_array_equal(a.fill_values, b.fill_values)
        assert (a.bbox, a.background) == (b.bbox, b.background)
        np.testing.assert_allclose(a.voxel_size, b.voxel_size, rtol=1e-15)
        np.testing.assert_allclose(a.index_to_world, b.index_to_world, atol=1e-15)


def test_half_floats_are_openvdbs_halves():
    """half.vdb holds the unrounded blob values saved as halves: its values are the
    float16-rounded ones (OpenVDB rounds as numpy does), not those of blobs.vdb."""
    half, _ = truth("half")
    g = read_vdb(DATA / "half.vdb")
    d = g.to_dense()
    np.testing.assert_array_equal(d, d.astype(np.float16).astype(np.float32))
    np.testing.assert_array_equal(d, half)


def test_upper_node_tile_expands_to_blocks():
    """A 128^3 active tile is read as 16^3 = 4096 constant blocks."""
    _, info = truth("bigtile")
    for name in ("bigtile.vdb", "bigtile.nvdb"):
        g = read_vdb(DATA / name)
        assert g.bbox == (tuple(info["imin"]), tuple(info["imax"]))
        assert len(g.origins) == 4096 + 1
        for s in info["samples"]:
            v = block_value(g, s["index"])
            assert (v if v is not None else g.background) == s["value"], s
        d = g.to_dense()
        assert d.shape == g.shape and d[0, 0, 0] == 0.625 and d[-1, 127, -1] == 0.625


# --------------------------------------------------------- index -> world voxel centres

@pytest.mark.parametrize("name,gt", [("blobs.vdb", "blobs_density"),
                                     ("blobs_zip.nvdb", "blobs_density"),
                                     ("nonuniform.vdb", "nonuniform"),
                                     ("nonuniform.nvdb", "nonuniform"),
                                     ("quirks.vdb", "quirks"), ("half.vdb", "half")])
def test_voxel_centres_where_openvdb_puts_them(name, gt):
    """Under volmc's convention (voxel i of n centred at bmin + (i + 0.5) * extent / n)
    the dense grid over world_bounds() has each voxel's centre at the world position
    OpenVDB's transform gives that voxel (indexToWorld of its integer index)."""
    g = read_vdb(DATA / name)
    _, info = truth(gt)
    lo, hi = (np.array(b) for b in g.world_bounds())
    n = np.array(g.shape[::-1])  # (nx, ny, nz)
    imin = np.array(g.bbox[0])
    for s in info["samples"]:
        ijk = np.array(s["index"])
        if np.any(ijk < imin) or np.any(ijk > np.array(g.bbox[1])):
            continue
        centre = lo + (ijk - imin + 0.5) * (hi - lo) / n
        np.testing.assert_allclose(centre, s["world_centre"], rtol=0, atol=1e-12)
        # ... and the dense voxel there holds OpenVDB's value of that voxel.
        x, y, z = ijk - imin
        assert g.to_dense()[z, y, x] == s["value"]
        np.testing.assert_allclose(np.add(g.index_to_world, ijk * np.array(g.voxel_size)),
                                   s["world_centre"], rtol=0, atol=1e-12)


def test_world_bounds_formula():
    g = VdbGrid("g", ((0.5, 0, 0), (0, 0.25, 0), (0, 0, 2.0)), (1.0, -2.0, 3.0),
                ((-2, 0, 4), (5, 3, 4)), 0.0,
                np.zeros((0, 3), np.int32), np.zeros((0, 8, 8, 8), np.float32))
    (x0, y0, z0), (x1, y1, z1) = g.world_bounds()
    assert (x0, y0, z0) == (1.0 - 2.5 * 0.5, -2.0 - 0.5 * 0.25, 3.0 + 3.5 * 2.0)
    assert (x1, y1, z1) == (1.0 + 5.5 * 0.5, -2.0 + 3.5 * 0.25, 3.0 + 4.5 * 2.0)
    assert g.shape == (1, 4, 8)
    assert np.all(g.to_dense() == 0.0) and g.to_dense().shape == (1, 4, 8)
    assert g.placement() == ((x0, y0, z0), (x1, y1, z1), None)


@pytest.mark.parametrize("name", ["rotated.vdb", "rotated.nvdb", "negscale.vdb",
                                  "negscale.nvdb", "affine.vdb"])
def test_affine_maps_are_read_as_openvdb_places_them(name):
    """Turned, mirrored and sheared maps (written by OpenVDB: make_fixtures.py,
    make_affine.py): the voxel at index i is centred at M @ (i, 1); the box is the index box
    and M the map. rotated.vdb: 30 degrees about z after a 0.05 voxel and a translation;
    negscale.vdb: x mirrored; affine.vdb: its json holds OpenVDB's indexToWorld."""
    import math
    g = read_vdb(DATA / name)
    lo, hi, m = g.placement()
    assert lo == tuple(i - 0.5 for i in g.bbox[0]) and hi == tuple(i + 0.5 for i in g.bbox[1])
    if name.startswith("rotated"):
        c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
        expect = [[0.05 * c, -0.05 * s, 0, 0.3], [0.05 * s, 0.05 * c, 0, -0.2],
                  [0, 0, 0.05, 0.15], [0, 0, 0, 1]]
    elif name.startswith("negscale"):
        expect = [[-0.05, 0, 0, 0.1], [0, 0.05, 0, 0.2], [0, 0, 0.05, 0.3], [0, 0, 0, 1]]
    else:
        info = json.loads((DATA / "affine.json").read_text())
        expect = np.eye(4)
        expect[:3, :3], expect[:3, 3] = np.array(info["axes"]).T, info["origin"]
        assert [list(b) for b in g.bbox] == info["bbox"]
        assert np.array_equal(g.to_dense(), np.load(DATA / "affine.npy"))
    assert np.allclose(m, expect, rtol=0, atol=1e-12)


# ------------------------------------------------------------------ grid selection

def test_grid_name_selection():
    for name in ("blobs.vdb", "blobs_zip.nvdb"):
        dens = read_vdb(DATA / name)  # default grid_name="density"
        temp = read_vdb(DATA / name, grid_name="temperature")
        assert (dens.name, temp.name) == ("density", "temperature")
        assert temp.bbox == ((0, 0, -4), (5, 6, 1)) and dens.bbox != temp.bbox
        assert temp.to_dense().max() == 350.5


def test_missing_grid_lists_the_grids(tmp_path):
    for name in ("blobs.vdb", "blobs_zip.nvdb"):
        text = raises_scene_error(DATA / name, "no grid named 'smoke'", grid_name="smoke")
        kind = "Vec3s" if name.endswith(".vdb") else "NanoVDB Vec3f"
        assert (f"(the file has: 'density' (float), 'temperature' (float), 'velocity' "
                f"({kind}, skipped))") in text, text


def test_key_is_used_in_messages():
    raises_scene_error(DATA / "blobs.vdb", grid_name="smoke", key="medium.temperature")


# ------------------------------------------------------------------ bad grids

@pytest.mark.parametrize("name,grid,match", [
    ("blobs.vdb", "velocity", "grid 'velocity' is a vector grid (Vec3s: vector grid; volmc "
                              "reads scalar grids); the file's float grids: 'density', "
                              "'temperature'"),
    ("blobs_zip.nvdb", "velocity", "grid 'velocity' is a vector grid (NanoVDB Vec3f: "),
    ("blobs_fp16.nvdb", "density", "grid 'density' is not a float grid (NanoVDB Fp16: "
                                   "quantized or non-float grid"),
    ("roottile.vdb", "density", f"active tiles cover more than {MAX_TILE_VOXELS} voxels"),
    ("roottile.nvdb", "density", f"active tiles cover more than {MAX_TILE_VOXELS} voxels"),
])
def test_unsupported_grids(name, grid, match):
    raises_scene_error(DATA / name, match, grid_name=grid)


def test_missing_empty_and_foreign_files(tmp_path):
    raises_scene_error(tmp_path / "nope.vdb", "grid file not found")
    (tmp_path / "empty.vdb").write_bytes(b"")
    raises_scene_error(tmp_path / "empty.vdb", "empty file")
    raises_scene_error(DATA / "blobs_density.npy", "not an OpenVDB or NanoVDB file")
    raises_scene_error(tmp_path, "cannot read grid file")  # a directory


def _grid_pos(data):
    """Offset of the first grid of an OpenVDB file (after its descriptor)."""
    pos = 8 + 4 + 8 + 1 + 36
    pos += 4  # file metadata count (0 in the fixtures)
    pos += 4  # grid count
    for _ in range(3):  # name, type, instance parent
        n, = struct.unpack_from("<I", data, pos)
        pos += 4 + n
    grid_pos, = struct.unpack_from("<q", data, pos)
    return grid_pos


def test_unsupported_compression_and_versions(tmp_path):
    data = bytearray((DATA / "quirks.vdb").read_bytes())
    p = tmp_path / "bad.vdb"
    g = _grid_pos(data)
    for flags, match in ((0x8, "unsupported compression flags 0x8"),
                         (0x5, "unsupported compression flags 0x5 (zip and blosc)")):
        bad = bytearray(data)
        struct.pack_into("<I", bad, g, flags)
        p.write_bytes(bad)
        raises_scene_error(p, match)
    bad = bytearray(data)
    struct.pack_into("<I", bad, 8, 219)
    p.write_bytes(bad)
    raises_scene_error(p, "OpenVDB file format version 219 unsupported")

    nano = bytearray((DATA / "quirks.nvdb").read_bytes())
    q = tmp_path / "bad.nvdb"
    bad = bytearray(nano)
    struct.pack_into("<H", bad, 14, 3)  # segment codec
    q.write_bytes(bad)
    raises_scene_error(q, "unsupported NanoVDB codec 3")
    bad = bytearray(nano)
    struct.pack_into("<I", bad, 8, 31 << 21)  # segment version 31.0.0
    q.write_bytes(bad)
    raises_scene_error(q, "NanoVDB version 31.0 unsupported")


def test_blosc_package_missing(monkeypatch):
    monkeypatch.setitem(sys.modules, "blosc", None)  # import blosc -> ImportError
    raises_scene_error(DATA / "blobs.vdb", "needs the Python package 'blosc'")
    raises_scene_error(DATA / "blobs_blosc.nvdb", "needs the Python package 'blosc'")
    read_vdb(DATA / "blobs_zip.vdb")  # zip needs no blosc


# ------------------------------------------------------------------ truncated and corrupt

TRUNCATE = ["blobs.vdb", "blobs_zip.vdb", "blobs_mask.vdb", "half.vdb", "quirks.vdb",
            "levelset.vdb",
            "blobs_zip.nvdb", "blobs_blosc.nvdb", "blobs_none.nvdb.gz", "blobs_none.vdb.gz"]


def _nano_segment_ends(data):
    """Offsets where a NanoVDB file's segments (header, grid metadata, grids) end."""
    ends, pos = [], 0
    while pos < len(data):
        count, = struct.unpack_from("<H", data, pos + 12)
        pos += 16
        sizes = []
        for _ in range(count):
            sizes.append(struct.unpack_from("<Q", data, pos + 8)[0])
            pos += 176 + struct.unpack_from("<I", data, pos + 136)[0]
        pos += sum(sizes)
        ends.append(pos)
    return ends


@pytest.mark.parametrize("name", TRUNCATE)
def test_truncated_copies(name, tmp_path):
    """Every truncation (at the header, in metadata, in the tree, in the last bytes) is
    a SceneError, whichever grid is asked for. (A NanoVDB file cut exactly between two
    segments is a valid file of fewer grids: those cuts are left out.)"""
    data = fixture_path(name, tmp_path).read_bytes()
    p = tmp_path / ("cut" + Path(name.removesuffix(".gz")).suffix)
    cuts = set(list(range(0, 200, 7)) + list(range(200, len(data), len(data) // 40))
               + [len(data) - k for k in (1, 2, 8, 100)])
    if p.suffix == ".nvdb":
        ends = _nano_segment_ends(data)
        assert ends[-1] == len(data) and len(ends) == 3  # one segment per grid
        cuts = (cuts | {e + d for e in ends[:-1] for d in (-1, 1, 16)}) - set(ends)
    for cut in sorted(cuts):
        p.write_bytes(data[:cut])
        raises_scene_error(p)
        raises_scene_error(p, grid_name="temperature" if "blobs" in name else "density")


@pytest.mark.parametrize("name", TRUNCATE)
def test_corrupt_bytes_never_raise_another_exception(name, tmp_path, monkeypatch):
    """Random bit flips and byte bursts: a SceneError or a grid, never another exception
    (nor a crash). Flips in stored values cannot be detected (no checksums are read).
    Bits set in an internal node's value mask are active tiles, each up to 2^21 voxels;
    a lower tile cap keeps their expansion quick here."""
    monkeypatch.setattr(vdb_module, "MAX_TILE_VOXELS", 1 << 22)
    data = fixture_path(name, tmp_path).read_bytes()
    p = tmp_path / ("bad" + Path(name.removesuffix(".gz")).suffix)
    rng = random.Random(name)
    errors = 0
    for _ in range(60):
        b = bytearray(data)
        if rng.random() < 0.5:
            for _ in range(rng.randint(1, 4)):
                b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
        else:
            at, n = rng.randrange(len(b)), rng.randint(1, 16)
            b[at:at + n] = bytes(rng.randrange(256) for _ in range(n))
        p.write_bytes(b)
        try:
            read_vdb(p)
        except SceneError as e:
            errors += 1
            assert str(e).startswith(f"{p}: {KEY}: ") and "\n" not in str(e)
    if "none" not in name:  # in an uncompressed file random bytes mostly hit values
        assert errors > 0


# ------------------------------------------------------------------ memory

def test_reading_builds_no_dense_array():
    """sparse.vdb: two voxels 1200 apart (a dense bbox of ~1.4e9 voxels, 5.6 GB); reading
    keeps two blocks and allocates little."""
    for name in ("sparse.vdb", "sparse.nvdb"):
        tracemalloc.start()
        try:
            g = read_vdb(DATA / name)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert len(g.origins) == 2 and g.values.nbytes == 2 * 512 * 4
        assert np.prod(g.shape, dtype=np.int64) > 10 ** 9
        assert peak < 16 * 2 ** 20, peak


def test_values_outside_the_bbox_are_not_read():
    """Brick storage keeps, and checks, only the voxels of the active bbox, as dense storage
    does: a leaf's inactive NaN or negative voxel outside it is not refused by one and
    accepted by the other."""
    import dataclasses
    from volmc.scene.loading import _vdb_bricks
    vg = read_vdb(DATA / "blobs.vdb")
    out = np.flatnonzero(np.any(vg.origins < vg.bbox[0], axis=1))[0]
    x, y, z = np.array(vg.bbox[0]) - vg.origins[out] - 1    # outside along an axis at least
    values = vg.values.copy()
    values[out, max(z, 0), max(y, 0), max(x, 0)] = np.nan
    bad = dataclasses.replace(vg, values=values)
    assert np.array_equal(np.asarray(_vdb_bricks(bad, "f.vdb", KEY)),
                          np.asarray(_vdb_bricks(vg, "f.vdb", KEY)))
    assert np.array_equal(bad.to_dense(), vg.to_dense())


def test_bad_values_are_named_all_at_once():
    """A VDB's stored values are checked as an array's are (validate_grid): NaN, infinite
    and negative voxels counted in one message, a negative infinity as infinite."""
    import dataclasses
    from volmc.scene.loading import _vdb_bricks
    vg = read_vdb(DATA / "blobs.vdb")
    values = vg.values.copy()
    whole = np.flatnonzero(np.all((vg.origins >= vg.bbox[0]) & (vg.origins + 7 <= vg.bbox[1]),
                                  axis=1))      # blocks inside the bbox: every voxel is read
    values[whole[:3], 1, 2, 3] = [np.nan, -np.inf, -0.25]
    with pytest.raises(SceneError) as e:
        _vdb_bricks(dataclasses.replace(vg, values=values), "f.vdb", "medium.density")
    assert str(e.value) == ("f.vdb: medium.density: grid 'density' contains 1 NaN, 1 infinite "
                            "and 1 negative values (minimum -0.25)")
