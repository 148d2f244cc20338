"""Mutation fuzzing of the OpenVDB / NanoVDB reader, the EXR map reader, the grid readers
(.npy, .npz, .vol) and the checkpoint reader over the committed fixtures and files volmc
writes (volmc/bench/fuzz.py: truncations, bit flips, byte bursts, 4- and 8-byte
words overwritten with huge values, half of them on words that hold counts, lengths and
offsets). Every case ends in a grid (map) or the one-line SceneError naming the key: never
another exception, a case past the time limit, or a peak allocation above what the memory
check allows. Hypothesis draws the cases (derandomized, so CI runs the same ones);
``python -m volmc.bench.fuzz --cases N`` runs more. Then one regression test per bug the
fuzzing (and the review around it) found."""

import gzip
import struct
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from volmc.bench import fuzz
from volmc.film import write_exr
from volmc.scene import envmap
from volmc.scene.errors import SceneError
from volmc.scene.vdb import read_vdb

DATA = Path(__file__).resolve().parent / "data"
VDB_CASES, EXR_CASES, GRID_CASES, CHECKPOINT_CASES = 6000, 3000, 2000, 1000
SETTINGS = dict(deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@pytest.fixture(scope="module")
def fixtures():
    with fuzz.scratch_dir() as tmp:
        yield fuzz.load_fixtures(tmp, DATA), Path(tmp)


def _case(fixtures, data, kind):
    pool = [f for f in fixtures[0] if f.kind == kind]
    fx = pool[data.draw(st.integers(0, len(pool) - 1), label="fixture")]

    def draw(lo, hi):
        return data.draw(st.integers(lo, hi))

    damaged, what = fuzz.mutate(fx.data, fx.structural, draw)
    path = fixtures[1] / f"case{Path(fx.name).suffix}"
    out = fuzz.run_case(fx, damaged, path, draw(0, len(fx.grids)))
    assert out.status in ("ok", "refused"), f"{fx.name}: {what}: {out.status}: {out.message}"
    assert out.seconds < fuzz.CASE_SECONDS


@settings(max_examples=VDB_CASES, **SETTINGS)
@given(data=st.data())
def test_vdb_reader_survives_mutations(fixtures, data):
    _case(fixtures, data, "vdb")


@settings(max_examples=EXR_CASES, **SETTINGS)
@given(data=st.data())
def test_exr_reader_survives_mutations(fixtures, data):
    _case(fixtures, data, "exr")


@settings(max_examples=GRID_CASES, **SETTINGS)
@given(data=st.data())
def test_grid_readers_survive_mutations(fixtures, data):
    _case(fixtures, data, "grid")


@settings(max_examples=CHECKPOINT_CASES, **SETTINGS)
@given(data=st.data())
def test_checkpoint_reader_survives_mutations(fixtures, data):
    _case(fixtures, data, "checkpoint")


def test_the_mutations_reach_the_structure():
    """The seeded run the benchmark makes: no failure, and the damage is found often
    (counts, sizes and offsets are hit, not only voxel values) but not always."""
    counts, failures, _ = fuzz.fuzz(700, seed=3, folder=DATA)
    assert not failures, failures[:3]
    assert counts["refused"] > 0.3 * 700 and counts["ok"] > 0.1 * 700, counts


# ------------------------------------------------------------------ regressions

def _exr_with_data_window(tmp_path, x1, y1):
    path = tmp_path / "map.exr"
    write_exr(path, np.full((4, 8, 3), 0.5, np.float32))
    data = bytearray(path.read_bytes())
    at = data.index(b"dataWindow\0box2i\0") + len(b"dataWindow\0box2i\0") + 4
    struct.pack_into("<4i", data, at, 0, 0, x1, y1)
    path.write_bytes(data)
    envmap._cache.clear()
    return path


def test_a_huge_exr_data_window_is_refused_before_openexr_allocates(tmp_path):
    """Found by the fuzzing: a damaged dataWindow made OpenEXR's bindings allocate the
    planes it declares (terabytes) before any check; the header is now read first."""
    path = _exr_with_data_window(tmp_path, 0x40000000, 7)
    tracemalloc.start()
    try:
        with pytest.raises(SceneError, match=r"8589934600 texels; at most 536870912 are read"):
            envmap.read_env_map(str(path), "s.toml", "lights[0].file")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 4 << 20


def test_an_exr_larger_than_memory_is_refused_by_the_memory_check(tmp_path, monkeypatch):
    monkeypatch.setenv("VOLMC_MEMORY_LIMIT", "16M")
    path = _exr_with_data_window(tmp_path, 2047, 1023)
    with pytest.raises(SceneError, match=r"lights\[0\]\.file: reading a map of 2097152 "
                                         r"texels needs 72\.0 MiB of host memory, 16\.0 MiB"):
        envmap.read_env_map(str(path), "s.toml", "lights[0].file")


def test_a_damaged_exr_header_is_one_line(tmp_path):
    path = tmp_path / "map.exr"
    write_exr(path, np.full((4, 8, 3), 0.5, np.float32))
    data = path.read_bytes()
    path.write_bytes(data[:40])
    envmap._cache.clear()
    with pytest.raises(SceneError, match="not a readable OpenEXR file: damaged header"):
        envmap.read_env_map(str(path), "s.toml", "lights[0].file")


def test_vdb_blocks_are_checked_against_host_memory(monkeypatch):
    """Reading allocates its blocks only after the memory check: bigtile.vdb's 128^3 tile
    expands into 4096 blocks (about 12 MiB), refused under a 4 MiB limit; before, tiles of
    up to 2^28 voxels (1 GiB) were expanded unchecked."""
    read_vdb(DATA / "vdb" / "bigtile.vdb")
    monkeypatch.setenv("VOLMC_MEMORY_LIMIT", "4M")
    for name in ("bigtile.vdb", "bigtile.nvdb"):
        with pytest.raises(SceneError, match=r"medium\.density: reading grid 'density' "
                                             r"\(1 leaves, 4097 blocks\) needs 12\.1 MiB"):
            read_vdb(DATA / "vdb" / name)


def test_a_compressed_nanovdb_grid_is_checked_before_it_is_inflated(monkeypatch):
    monkeypatch.setenv("VOLMC_MEMORY_LIMIT", "64K")
    with pytest.raises(SceneError, match=r"reading NanoVDB grid 'density' \(\d+ bytes\) "
                                         r"needs .* of host memory, 64\.0 KiB available"):
        read_vdb(DATA / "vdb" / "blobs_zip.nvdb")


def test_a_double_beyond_float32_is_an_error(tmp_path, monkeypatch):
    """A 64-bit grid's value beyond float32's range was cast to inf (with a numpy warning);
    it is now a one-line error. The root's background, stored unhalved, is set to 1e300."""
    import volmc.scene.vdb as vdb_module
    src = DATA / "fire" / "double.vdb"
    seen = []
    original = vdb_module._VdbReader._value

    def spy(self):
        seen.append(self.cur.pos)
        return original(self)

    monkeypatch.setattr(vdb_module._VdbReader, "_value", spy)
    read_vdb(src, "density")
    monkeypatch.undo()
    data = bytearray(src.read_bytes())
    struct.pack_into("<d", data, seen[0], 1e300)
    bad = tmp_path / "double.vdb"
    bad.write_bytes(data)
    with pytest.raises(SceneError, match="grid value 1e\\+300 overflows float32"):
        read_vdb(bad, "density")


def test_nanovdb_children_reached_twice_are_refused(tmp_path):
    """A root table whose tiles point at one upper node many times made the walk repeat
    that node's subtree per tile (its lists growing past the grid's size) before the
    duplicate leaves were noticed; nodes reached are now counted against the tree's own
    counts. Here the root's second tile is made a copy of its first."""
    data = bytearray(gzip.decompress((DATA / "vdb" / "blobs_none.nvdb.gz").read_bytes()))
    assert struct.unpack_from("<H", data, 14)[0] == 0   # codec none
    # The first grid follows the 16-byte segment header and the 176-byte metadata
    # with its name; the root follows the tree's offsets at 672 in the grid.
    name_len, = struct.unpack_from("<I", data, 16 + 136)
    grid = 16 + 176 + name_len
    tree = grid + 672
    root = tree + struct.unpack_from("<Q", data, tree + 24)[0]
    table, = struct.unpack_from("<I", data, root + 24)
    assert table >= 1
    first = bytes(data[root + 64:root + 96])
    key, child, state = struct.unpack_from("<QqI", first)
    assert child != 0   # the first tile holds an upper node
    struct.pack_into("<I", data, root + 24, table + 1)
    # The copy goes right after the table, over the first bytes of the upper node stored
    # there (its bounding box, which the reader does not use).
    at = root + 64 + table * 32
    data[at:at + 32] = first
    bad = tmp_path / "twice.nvdb"
    bad.write_bytes(data)
    with pytest.raises(SceneError, match="more upper nodes reached than the tree holds"):
        read_vdb(bad)


def test_a_transform_beyond_float_range_is_an_error(tmp_path):
    """Found by the fuzzing: a scale of 1e300 made numpy overflow (a warning) computing the
    voxel size, and bounds of inf; transforms beyond 1e30 world units are now refused."""
    import warnings
    data = bytearray((DATA / "fire" / "double.vdb").read_bytes())
    at = data.index(b"UniformScaleMap") + len(b"UniformScaleMap")
    struct.pack_into("<d", data, at, 1e300)     # the map's first scale factor
    bad = tmp_path / "huge.vdb"
    bad.write_bytes(data)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(SceneError, match="grid 'density': transform values beyond 1e\\+30 "
                                             "world units"):
            read_vdb(bad, "density")


def _grid_file(tmp_path, suffix, version=None):
    from volmc.scene.grids import save_grid
    path = tmp_path / f"g{suffix}"
    g = np.arange(210, dtype=np.float32).reshape(5, 6, 7)
    if version is None:
        save_grid(path, g)
    else:
        with open(path, "wb") as f:
            np.lib.format.write_array(f, g, version=version)
    return path, bytearray(path.read_bytes())


def _damage_npy(data, how):
    if how == "length":      # a v2.0 header's 4-byte length: 0x27000000
        data[8:12] = (0x27000000).to_bytes(4, "little")
    elif how == "version":   # a version numpy never wrote
        data[7] = 8
    else:                    # the dtype ',f4', which numpy's parser rejects with SyntaxError
        at = data.index(b"'<f4'")
        data[at + 1] = ord(",")
    return data


@pytest.mark.parametrize("how,words", [
    ("length", r"\.npy header of 654311424 bytes in a stream of"),
    ("version", "unsupported .npy format version 2.8"),
    ("dtype", "cannot read grid: "),
])
def test_a_damaged_npy_header_is_one_line_and_allocates_nothing(tmp_path, how, words):
    """Found by fuzzing the grid readers: a flipped bit in a header's length made numpy
    read (allocate) 660 MB for it, and a damaged dtype raised SyntaxError past the one-line
    error."""
    from volmc.scene.grids import load_grid
    path, data = _grid_file(tmp_path, ".npy", (2, 0))
    path.write_bytes(_damage_npy(data, how))
    tracemalloc.start()
    try:
        with pytest.raises(SceneError, match=words) as e:
            load_grid(path, "medium.density")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert str(e.value).startswith(f"{path}: medium.density: ")
    assert peak < 4 << 20


@pytest.mark.parametrize("field,value,words", [
    (10, 99, "compression method"),          # NotImplementedError in zipfile
    (8, 1, "encrypted"),                     # RuntimeError in zipfile
])
def test_an_npz_member_zipfile_cannot_open_is_one_line(tmp_path, field, value, words):
    """Found by fuzzing: zipfile raises NotImplementedError and RuntimeError for members it
    cannot open; both are the damaged file's one-line error."""
    from volmc.scene.grids import load_grid
    path, data = _grid_file(tmp_path, ".npz")
    at = data.index(b"PK\x01\x02") + field    # the member's central directory entry
    data[at:at + 2] = value.to_bytes(2, "little")
    path.write_bytes(data)
    with pytest.raises(SceneError, match=words) as e:
        load_grid(path, "medium.density")
    assert str(e.value).startswith(f"{path}: medium.density: cannot read grid: ")


def test_a_checkpoint_member_declaring_more_than_the_file_is_refused(tmp_path):
    """A checkpoint's arrays are read only after their headers are checked against the
    file's size: a shape damaged to gigabytes is refused, not allocated (zip's CRC catches
    the damage only once a member is read to its end)."""
    from volmc import checkpoint
    from volmc.film import Film
    from volmc.params import COUNTER_NAMES
    from volmc.resources import scenes_dir
    from volmc.scene import load_scene
    scene = load_scene(scenes_dir() / "tests" / "absorber.toml", ["camera.resolution=[32, 32]"])
    film = Film(32, 32)
    film.spp = 1
    good = tmp_path / "good.ckpt"
    checkpoint.save(good, film, {n: 0 for n in COUNTER_NAMES}, 1.0,
                    checkpoint.identity(scene, "numba"))
    old = b"(32, 32, 4), }        "
    assert good.read_bytes().count(old) == 2             # sum and sum_sq
    path = tmp_path / "damaged.ckpt"
    path.write_bytes(good.read_bytes().replace(old, b"(32, 32, 400000000), }", 1))
    tracemalloc.start()
    try:
        with pytest.raises(SceneError, match="declares more bytes than the file holds") as e:
            checkpoint.load(path, scene, "numba")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert str(e.value).startswith(f"{path}: --resume: not a volmc checkpoint (its member ")
    assert peak < 4 << 20
