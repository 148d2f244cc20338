"""OpenVDB/NanoVDB densities in scenes: bounds from the file, the same image as the same grid
given as .npy with the equivalent bounds, brick storage equal to dense storage, emission
fields from the same file, and bad files as one-line errors (exit status 2)."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from volmc.render import render
from volmc.scene import scene_from_dict
from volmc.scene.bricks import BrickGrid
from volmc.scene.errors import SceneError

DATA = Path(__file__).parent / "data" / "vdb"


def _scene(density, bounds=None, extra=None, render_keys=None):
    med = {"density": density, "scale": 30.0, "albedo": 0.8,
           "phase": {"type": "hg", "g": 0.3}, **(extra or {})}
    if bounds is not None:
        med["bounds"] = bounds
    return scene_from_dict({
        "camera": {"eye": [0.2, 0.0, 1.4], "target": [0.2, -0.05, 0.3], "fov": 35.0,
                   "resolution": [10, 8]},
        "medium": med,
        "lights": [{"type": "environment", "radiance": [0.2, 0.3, 0.4]},
                   {"type": "directional", "direction": [0.3, -1, -0.2], "irradiance": 2.0}],
        "render": {"spp": 16, **(render_keys or {})}})


def _truth(name="blobs_density"):
    meta = json.loads((DATA / f"{name}.json").read_text())
    return meta, [list(meta["world_bounds"][0]), list(meta["world_bounds"][1])]


@pytest.mark.parametrize("file", ["blobs.vdb", "blobs_zip.nvdb"])
def test_vdb_bounds_come_from_the_file(file):
    meta, bounds = _truth()
    s = _scene({"file": str(DATA / file)})
    assert np.allclose(s.medium.bounds, bounds, rtol=0, atol=1e-12)
    assert isinstance(s.grid, BrickGrid)   # loaded from the leaves, no dense copy
    assert np.array_equal(np.asarray(s.grid), np.load(DATA / "blobs_density.npy"))


@pytest.mark.parametrize("file", ["inactive.vdb", "inactive.nvdb"])
@pytest.mark.parametrize("storage", ["bricks", "dense"])
def test_inactive_tiles_are_in_the_medium(file, storage):
    """Inactive tiles of another value than the background are part of the density in both
    storages, equal to OpenVDB's getValue over the bbox."""
    s = _scene({"file": str(DATA / file)}, render_keys={"grid_storage": storage})
    assert isinstance(s.grid, BrickGrid) == (storage == "bricks")
    assert np.array_equal(np.asarray(s.grid), np.load(DATA / "inactive.npy"))


@pytest.mark.parametrize("file", ["inactive.vdb", "inactive.nvdb"])
def test_a_field_reads_its_values_outside_its_own_active_box(file):
    """A field of the density's file, on its lattice, reads what OpenVDB's getValue gives at
    each density voxel: its inactive tile and inactive leaf voxel beyond its own active box
    too (they were its background)."""
    s = _scene({"file": str(DATA / file)},
               extra={"emission": {"temperature": {"file": str(DATA / file), "grid": "flame"},
                                   "remap": [0.0, 1.0, 0.0, 1000.0], "scale": 1e-4}})
    flame = np.load(DATA / "inactive_flame.npy")
    assert np.count_nonzero(flame == np.float32(0.8)) == 512 and np.any(flame == np.float32(0.9))
    expected = (flame.astype(np.float64) * 1000.0).astype(np.float32)
    assert np.array_equal(s.emission_grid, expected)


@pytest.mark.parametrize("file", ["blobs.vdb", "blobs_blosc.nvdb"])
def test_vdb_renders_the_image_of_the_npy_grid(backend, file):
    """The VDB scene (bricks) and the .npy scene (dense) with the equivalent bounds: the same
    lookups, majorants and random numbers, so the same image bit for bit."""
    _, bounds = _truth()
    a = render(_scene({"file": str(DATA / file)}), backend=backend, progress=False)
    b = render(_scene({"file": str(DATA / "blobs_density.npy")}, bounds), backend=backend,
               progress=False)
    assert np.array_equal(a.film.mean(), b.film.mean())
    assert a.counters == b.counters and a.counters["lookups"] > 0


def _affine_truth():
    """affine.vdb's OpenVDB ground truth (make_affine.py): its voxels, the index box and the
    4x4 index-to-world matrix OpenVDB's indexToWorld gives."""
    info = json.loads((DATA / "affine.json").read_text())
    m = np.eye(4)
    m[:3, :3] = np.array(info["axes"]).T
    m[:3, 3] = info["origin"]
    lo, hi = np.array(info["bbox"][0]) - 0.5, np.array(info["bbox"][1]) + 0.5
    return np.load(DATA / "affine.npy"), [lo.tolist(), hi.tolist()], m


@pytest.mark.parametrize("turn", [None, {"rotate": [0, 1, 0, 50.0], "translate": [0, 0.1, 0]}])
def test_affine_vdb_renders_as_its_values_placed_by_the_map(backend, turn):
    """A grid whose OpenVDB map turns, mirrors and shears it (an AffineMap, written by
    OpenVDB: make_affine.py) is placed exactly as OpenVDB places it: the same image as its
    voxels (read back by OpenVDB) in the index box under OpenVDB's index-to-world matrix,
    composed with the medium's own transform when it has one."""
    from volmc.check import compare_images
    from volmc.scene.transform import compose
    values, box, m = _affine_truth()
    extra = {} if turn is None else {"transform": turn}
    a_scene = _scene({"file": str(DATA / "affine.vdb")}, extra=extra)
    t = m if turn is None else compose(rotations=[((0, 1, 0), 50.0)],
                                       translate=(0, 0.1, 0)) @ m
    b_scene = _scene(values, box, extra={"transform": {"matrix": t.tolist()}})
    assert np.allclose(a_scene.medium.transform, t, rtol=0, atol=1e-12)
    assert np.allclose(a_scene.medium.bounds, box, rtol=0, atol=0)
    a = render(a_scene, backend=backend, progress=False)
    b = render(b_scene, backend=backend, progress=False)
    c = compare_images(a.image, a.film.variance_of_mean(), b.image, b.film.variance_of_mean())
    assert c.passed, c.summary()
    assert np.abs(a.image - b.image).mean() < 1e-4 * np.abs(b.image).mean()
    assert a.counters["lookups"] > 0 and a.image.std() > 0.01   # the grid is in view


def test_brick_storage_renders_the_dense_image(backend):
    _, bounds = _truth()
    npy = {"file": str(DATA / "blobs_density.npy")}
    a = render(_scene(npy, bounds, render_keys={"grid_storage": "bricks"}), backend=backend,
               progress=False)
    b = render(_scene(npy, bounds, render_keys={"grid_storage": "dense"}), backend=backend,
               progress=False)
    assert np.array_equal(a.film.mean(), b.film.mean()) and a.counters == b.counters


def test_temperature_grid_from_the_same_file_is_placed_by_index():
    """The temperature grid has its own active box; it lands on the density's voxels."""
    meta_d, _ = _truth()
    meta_t, _ = _truth("blobs_temperature")
    s = _scene({"file": str(DATA / "blobs.vdb")},
               extra={"emission": {"temperature": {"file": str(DATA / "blobs.vdb"),
                                                   "grid": "temperature"}, "scale": 1e-4}})
    t = np.load(DATA / "blobs_temperature.npy")
    lo_d, hi_d = np.array(meta_d["imin"]), np.array(meta_d["imax"])
    lo_t = np.array(meta_t["imin"])
    expected = np.full(tuple((hi_d - lo_d + 1)[::-1]), meta_t["background"], np.float32)
    for z in range(t.shape[0]):
        for y in range(t.shape[1]):
            for x in range(t.shape[2]):
                i = np.array([x, y, z]) + lo_t - lo_d
                if np.all(i >= 0) and np.all(i <= hi_d - lo_d):
                    expected[i[2], i[1], i[0]] = t[z, y, x]
    assert np.array_equal(s.emission_grid, expected)


@pytest.mark.parametrize("file, grid, words", [
    ("blobs.vdb", "smoke", "smoke"),
    ("blobs.vdb", "velocity", "velocity"),
    ("levelset.vdb", "density", "negative"),
])
def test_bad_vdb_density_is_a_scene_error(file, grid, words):
    with pytest.raises(SceneError) as e:
        _scene({"file": str(DATA / file), "grid": grid})
    assert words in str(e.value).lower() and file in str(e.value)


def test_bounds_required_without_a_vdb_file():
    with pytest.raises(SceneError, match="medium.bounds"):
        _scene({"file": str(DATA / "blobs_density.npy")})


def test_truncated_vdb_cli_exit_status_2(tmp_path):
    data = (DATA / "blobs.vdb").read_bytes()
    bad = tmp_path / "cut.vdb"
    bad.write_bytes(data[: len(data) // 2])
    scene = tmp_path / "s.toml"
    scene.write_text(f'[camera]\nresolution = [4, 4]\n[medium]\ndensity = {{ file = "{bad}" }}\n'
                     '[[lights]]\ntype = "environment"\nradiance = 1\n')
    r = subprocess.run([sys.executable, "-m", "volmc.cli", "render", str(scene), "-o",
                        str(tmp_path / "x.exr"), "--quiet"], capture_output=True, text=True)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "cut.vdb" in r.stderr


def _vdb_grid(name, linear, translation, lo, dense, background=0.0):
    """A VdbGrid holding ``dense`` ([z, y, x]) from index ``lo`` on, in 8^3 blocks."""
    from volmc.scene.vdb import VdbGrid
    nz, ny, nx = dense.shape
    origins, blocks = [], []
    for z in range(0, nz, 8):
        for y in range(0, ny, 8):
            for x in range(0, nx, 8):
                b = np.full((8, 8, 8), background, np.float32)
                part = dense[z:z + 8, y:y + 8, x:x + 8]
                b[:part.shape[0], :part.shape[1], :part.shape[2]] = part
                origins.append(np.add(lo, (x, y, z)))
                blocks.append(b)
    hi = tuple(int(a + n - 1) for a, n in zip(lo, (nx, ny, nz)))
    return VdbGrid(name, linear, translation, (tuple(lo), hi), background,
                   np.array(origins, np.int32), np.array(blocks, np.float32))


def test_a_field_on_another_lattice_is_resampled_in_world_space():
    """A field whose voxels differ from the density's (twice as large, turned 30 degrees
    about z, shifted) is interpolated trilinearly in world space at the density's voxel
    centres: a field linear in world space comes out exactly, and outside the field's box
    its background is read."""
    from volmc.scene.loading import _align_vdb
    c, s_ = np.cos(np.pi / 6), np.sin(np.pi / 6)
    lin_f = np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1]]) * 0.1
    origin_f = np.array([-1.3, -1.5, -0.35])
    field = lambda w: 2.0 + w[..., 0] - 0.5 * w[..., 1] + 0.25 * w[..., 2]   # noqa: E731
    idx = np.stack(np.meshgrid(np.arange(30), np.arange(28), np.arange(12), indexing="ij"),
                   -1).transpose(2, 1, 0, 3)          # [z, y, x, (x, y, z)]
    f = _vdb_grid("temperature", lin_f, origin_f, (0, 0, 0),
                  field(idx @ lin_f.T + origin_f).astype(np.float32), background=-1.0)
    lin_d = np.eye(3) * 0.05
    lo_d = np.array([-4, 2, 3])
    d = _vdb_grid("density", lin_d, (0.02, -0.01, 0.0), lo_d, np.ones((12, 10, 14), np.float32))
    out = _align_vdb(f, d, "f.vdb", "medium.emission.temperature")
    assert out.shape == (12, 10, 14)
    jz, jy, jx = np.indices(out.shape)
    world = np.stack([jx, jy, jz], -1) @ lin_d.T + (lo_d @ lin_d.T + (0.02, -0.01, 0.0))
    np.testing.assert_allclose(out, field(world), rtol=2e-6, atol=2e-6)
    # Moved far from the field's box, the density's voxels read its background.
    far = _vdb_grid("density", lin_d, (50.0, 0.0, 0.0), lo_d, np.ones((4, 4, 4), np.float32))
    assert np.all(_align_vdb(f, far, "f.vdb", "medium.emission.temperature") == -1.0)


def test_a_resampled_field_reads_its_tiles_beyond_its_active_box():
    """On another lattice too, the field's values are its getValue: an inactive tile of 0.7
    beyond the field's active box, under the density's voxels, interpolates to 0.7 (it was
    the field's background, 0)."""
    import dataclasses
    from volmc.scene.loading import _align_vdb
    f = _vdb_grid("temperature", np.eye(3) * 0.1, (0.033, 0.0, 0.0), (0, 0, 0),
                  np.full((8, 8, 8), 0.5, np.float32), background=0.0)
    f = dataclasses.replace(f, fill_boxes=np.array([[16, 0, 0, 32, 16, 16]], np.int64),
                            fill_values=np.array([0.7], np.float32))
    d = _vdb_grid("density", np.eye(3) * 0.1, (0.0, 0.0, 0.0), (17, 1, 1),
                  np.ones((10, 10, 10), np.float32))
    out = _align_vdb(f, d, "f.vdb", "medium.emission.temperature")
    np.testing.assert_allclose(out, 0.7, rtol=1e-6)


def test_a_mantaflow_base_grid_lands_on_its_upres_density():
    """Mantaflow's upres noise writes the density at twice the resolution of the heat grid,
    both from the domain's corner: a density voxel at even indices holds the heat voxel at
    half its index, and one between two heat voxels along x their mean. (Frame 16 of the
    gallery bake, 5 cm voxels, with the heat grid of the resumable bake's frame 16, 10 cm:
    the same simulation set-up at half the resolution.)"""
    from volmc.scene.vdb import read_vdb
    fire = Path(__file__).parent / "data" / "fire"
    from volmc.resources import scenes_dir
    fine = scenes_dir() / "data" / "fire" / "cache_fluid" / "data" / "fluid_data_0016.vdb"
    coarse = fire / "resumable" / "cache_fluid" / "data" / "fluid_data_0016.vdb"
    s = _scene({"file": str(fine)},
               extra={"emission": {"temperature": {"file": str(coarse), "grid": "temperature"},
                                   "remap": [0.0, 3.0, 0.0, 3.0], "scale": 1e-4}})
    d, h = read_vdb(fine), read_vdb(coarse, "temperature")
    assert np.allclose(d.voxel_size, 0.05, rtol=1e-6) and np.allclose(h.voxel_size, 0.1,
                                                                        rtol=1e-6)
    heat = h.to_dense()
    lo_d, lo_h = np.array(d.bbox[0]), np.array(h.bbox[0])

    def heat_at(i):   # the heat voxel of absolute index i (x, y, z), background outside
        k = np.asarray(i) - lo_h
        if np.any(k < 0) or np.any(k >= heat.shape[::-1]):
            return h.background
        return heat[k[2], k[1], k[0]]

    checked = 0
    for z in range(0, s.emission_grid.shape[0], 3):
        for y in range(0, s.emission_grid.shape[1], 3):
            for x in range(0, s.emission_grid.shape[2]):
                j = lo_d + (x, y, z)
                if np.any(j % 2):
                    if j[1] % 2 or j[2] % 2:
                        continue
                    want = 0.5 * (heat_at((j - (1, 0, 0)) // 2) + heat_at((j + (1, 0, 0)) // 2))
                else:
                    want = heat_at(j // 2)
                got = s.emission_grid[z, y, x]
                assert got == pytest.approx(min(max(want, 0.0), 3.0), rel=1e-5, abs=1e-5), j
                checked += 1
    assert checked > 500 and s.emission_grid.max() > 2.0
