"""Fire data as users have it: two Mantaflow caches baked by Blender with
tests/data/fire/bake_mantaflow.py (the gallery fire's frames in scenes/data/fire, Blender's
default cache; a resumable one's frame, with every grid Mantaflow saves, in tests/data/fire),
and the Houdini Pyro and EmberGen layouts of tests/data/fire (written by OpenVDB 12.0 with
make_fixtures.py there): several grids a file, half floats, vector and integer grids. Every
float grid reads equal to OpenVDB's own reading of it (truth.npz, recorded when the files
were written), every grid is listed, vector and integer grids are skipped with a note, and
`volmc info FILE.vdb` prints them."""

import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from volmc.scene.errors import SceneError
from volmc.resources import scenes_dir
from volmc.scene.vdb import VDB_MAX_VERSION, list_grids, read_vdb

FIRE = Path(__file__).resolve().parent / "data" / "fire"
#: The Mantaflow cache ships with the scenes (the gallery fire renders it); the rest stays here.
CACHE = scenes_dir() / "data" / "fire"


def fixture(rel):
    """The path of fixture ``rel`` (as truth.npz names it)."""
    return (CACHE if rel.startswith("cache_fluid/") else FIRE) / rel


TRUTH = np.load(FIRE / "truth.npz")
FRAMES = [f"cache_fluid/data/fluid_data_{i:04d}.vdb" for i in range(13, 17)]
RESUMABLE = "resumable/cache_fluid/data/fluid_data_0016.vdb"
FILES = FRAMES + [RESUMABLE, "houdini_pyro.vdb", "embergen.vdb", "double.vdb"]
FLOAT_GRIDS = sorted({tuple(k.split(":")[:2]) for k in TRUTH.files if k.endswith(":values")})
#: The grids of Blender's default cache (not resumable), and of a resumable one.
MANTAFLOW_RENDER = ["velocity", "density", "shadow", "temperature", "flame", "color_r",
                    "color_g", "color_b"]
MANTAFLOW = ["velocity", "phi_obstacle", "phi_inflow", "phi_out", "flags", "velocity_previous",
             "density", "shadow", "temperature", "flame", "color_r", "color_g", "color_b",
             "density_inflow", "emission", "temperature_inflow", "fuel", "react", "fuel_inflow",
             "react_inflow", "color_r_inflow", "color_g_inflow", "color_b_inflow"]


def test_truth_covers_every_grid_of_every_file():
    """The ground truth has an entry (values, or the skipped type) per grid of each file, so
    the comparison below leaves no grid out."""
    for rel in FILES:
        recorded = {k.split(":")[1] for k in TRUTH.files if k.startswith(rel + ":")}
        assert recorded == {g.name for g in list_grids(fixture(rel))}, rel
    assert len(FLOAT_GRIDS) == 4 * 7 + 20 + 3 + 2 + 2


@pytest.mark.parametrize("rel,name", FLOAT_GRIDS, ids=[f"{r}:{n}" for r, n in FLOAT_GRIDS])
def test_every_float_grid_reads_as_openvdb_reads_it(rel, name):
    g = read_vdb(fixture(rel), name, key="medium.density")
    key = f"{rel}:{name}"
    assert g.name == name
    assert g.bbox == tuple(map(tuple, TRUTH[key + ":bbox"].tolist()))
    assert g.background == float(TRUTH[key + ":background"])
    np.testing.assert_allclose(g.voxel_size, TRUTH[key + ":voxel_size"], rtol=1e-15)
    np.testing.assert_allclose(g.index_to_world, TRUTH[key + ":origin"], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(g.to_dense(), TRUTH[key + ":values"])


def test_mantaflow_frames_are_half_floats_with_mantaflows_names():
    """Every float grid of a Mantaflow frame is stored as halves (the values are exactly
    float16 values), and the grids come in Mantaflow's order with its types."""
    for rel in FRAMES + [RESUMABLE]:
        infos = list_grids(fixture(rel))
        names = MANTAFLOW if rel == RESUMABLE else MANTAFLOW_RENDER
        assert [g.name for g in infos] == names
        kinds = {g.name: g.kind for g in infos}
        vectors = {"velocity", "velocity_previous"} & set(names)
        assert {kinds[n] for n in vectors} == {"Vec3s"}
        assert kinds.get("flags", "int32") == "int32"
        assert {kinds[n] for n in names if n not in vectors | {"flags"}} == {"half float"}
        d = read_vdb(fixture(rel), "flame").to_dense()
        assert d.max() > 0.5
        np.testing.assert_array_equal(d, d.astype(np.float16).astype(np.float32))
    # A burning inflow: the smoke grows and its top climbs frame by frame.
    smoke = [read_vdb(fixture(rel)) for rel in FRAMES]
    tops = [g.bbox[1][2] for g in smoke]
    assert tops == sorted(tops) and tops[-1] > tops[0], tops
    mass = [float(g.to_dense().sum()) for g in smoke]
    assert mass == sorted(mass) and mass[-1] > 1.1 * mass[0], mass


def test_listing_notes_why_grids_are_skipped():
    infos = {g.name: g for g in list_grids(FIRE / "houdini_pyro.vdb")}
    assert [n for n, g in infos.items() if g.readable] == ["density", "temperature", "flame"]
    assert infos["vel"].kind == infos["Cd"].kind == "Vec3s"
    assert "vector grid" in infos["vel"].note
    assert infos["vel"].text() == ("'vel' (Vec3s) -- skipped: vector grid; volmc reads "
                                   "scalar grids")
    flags = next(g for g in list_grids(fixture(RESUMABLE)) if g.name == "flags")
    assert not flags.readable and "integer grid" in flags.note
    assert [g.kind for g in list_grids(FIRE / "embergen.vdb")] == ["half float"] * 2
    assert [g.kind for g in list_grids(FIRE / "double.vdb")] == ["double",
                                                                  "double saved as half"]


@pytest.mark.parametrize("rel,name", [(FRAMES[0], "velocity"), ("houdini_pyro.vdb", "Cd"),
                                      ("houdini_pyro.vdb", "vel")])
def test_a_vector_grid_named_as_a_density_is_a_one_line_error(rel, name):
    with pytest.raises(SceneError) as e:
        read_vdb(fixture(rel), name, key="medium.density")
    text = str(e.value)
    assert text.startswith(f"{fixture(rel)}: medium.density: grid '{name}' is a vector grid "
                           "(Vec3s")
    assert "\n" not in text
    floats = text.split("the file's float grids: ")[1].split(", ")
    assert "'density'" in floats and f"'{name}'" not in floats


def test_a_missing_grid_lists_the_grids_with_their_types():
    with pytest.raises(SceneError) as e:
        read_vdb(FIRE / "houdini_pyro.vdb", "heat", key="medium.emission.temperature")
    assert str(e.value).endswith(
        "no grid named 'heat' (the file has: 'density' (float), 'temperature' (float), "
        "'flame' (float), 'vel' (Vec3s, skipped), 'Cd' (Vec3s, skipped))")


def test_file_format_225_reads_as_224(tmp_path):
    """OpenVDB 13 writes file version 225 (it adds half-typed grids; float grids are laid
    out as before): a frame stamped 225 reads the same, 226 is refused."""
    data = bytearray((fixture(FRAMES[1])).read_bytes())
    assert struct.unpack_from("<I", data, 8)[0] == 224
    p = tmp_path / "v225.vdb"
    struct.pack_into("<I", data, 8, 225)
    p.write_bytes(data)
    a, b = read_vdb(fixture(FRAMES[1]), "temperature"), read_vdb(p, "temperature")
    np.testing.assert_array_equal(a.values, b.values)
    assert VDB_MAX_VERSION == 225
    struct.pack_into("<I", data, 8, 226)
    p.write_bytes(data)
    with pytest.raises(SceneError, match="OpenVDB file format version 226 unsupported"):
        read_vdb(p, "temperature")


def test_volmc_info_lists_the_grids_of_a_file():
    out = subprocess.run([sys.executable, "-m", "volmc.cli", "info", str(fixture(RESUMABLE))],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0] == f"{fixture(RESUMABLE)}: OpenVDB, 23 grids (20 read by volmc)"
    assert "  'velocity' (Vec3s) -- skipped: vector grid; volmc reads scalar grids" in lines
    assert "  'flame' (half float)" in lines


def test_volmc_info_refuses_a_bad_file_with_one_line(tmp_path):
    bad = tmp_path / "cut.vdb"
    bad.write_bytes((fixture(RESUMABLE)).read_bytes()[:300])
    out = subprocess.run([sys.executable, "-m", "volmc.cli", "info", str(bad)],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2 and out.stdout == ""
    assert out.stderr.startswith(f"volmc: error: {bad}: file: corrupt OpenVDB file: grid "
                                 "count 23")
    assert out.stderr.count("\n") == 1 and "Traceback" not in out.stderr


def test_a_mantaflow_frame_loads_as_a_fire_scene():
    """The documented use: density from a frame, emission from its flame grid through a
    temperature remap; the box is the density's, and the kelvin grid is the flame placed on
    the density's voxels by index, remapped."""
    from volmc.scene import scene_from_dict
    f = str(fixture(FRAMES[-1]))
    s = scene_from_dict({
        "camera": {"eye": [0.8, 0.8, 6], "target": [0.8, 0.8, 1], "fov": 40,
                   "resolution": [8, 8]},
        "medium": {"density": {"file": f}, "scale": 20.0, "albedo": 0.8,
                   "emission": {"temperature": {"file": f, "grid": "flame"},
                                "remap": [0.0, 1.0, 0.0, 1800.0]}},
        "lights": [{"type": "environment", "radiance": [0.1, 0.1, 0.1]}],
        "render": {"spp": 4}})
    dens = read_vdb(f)
    np.testing.assert_allclose(s.medium.bounds, dens.world_bounds(), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(np.asarray(s.grid), dens.to_dense())
    flame = read_vdb(f, "flame")
    on_density = np.zeros(dens.shape, np.float32)
    (x0, y0, z0), (x1, y1, z1) = (np.subtract(c, dens.bbox[0]) for c in flame.bbox)
    on_density[z0:z1 + 1, y0:y1 + 1, x0:x1 + 1] = flame.to_dense()
    np.testing.assert_allclose(s.emission_grid, np.clip(on_density, 0, 1) * 1800.0,
                               rtol=1e-6, atol=1e-3)
    assert s.emission_grid.max() > 1000.0
