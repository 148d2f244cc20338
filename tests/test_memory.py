"""Memory limits checked before any work (volmc/memory.py), and banded renders."""

import re
import time
import tracemalloc
import types

import numpy as np
import pytest

from volmc import memory
from volmc.cli import main
from volmc.film import Film, write_exr, write_png
from volmc.params import launch_spp, sample_counts
from volmc.resources import default_scene
from volmc.scene import load_scene, scene_from_dict
from volmc.scene.errors import SceneError
from volmc.scene.serialize import dict_to_toml

from test_cli import TINY   # a 10x8 homogeneous absorber: loads in milliseconds

FIGURE = r"[\d.]+ (?:[KMGT]iB|B)"


@pytest.fixture(scope="module")
def cloud():
    return load_scene(default_scene())


@pytest.fixture(scope="module")
def cloud256():
    return load_scene(default_scene(), ["medium.density.resolution=256"])


def test_parse_size():
    assert memory.parse_size("100M") == 100 << 20
    assert memory.parse_size("2g") == 2 << 30
    assert memory.parse_size("1.5GiB") == 3 << 29
    assert memory.parse_size("12345") == 12345
    for bad in ("", "lots", "-5M", "0", "nanG"):
        with pytest.raises(SceneError, match="VOLMC_MEMORY_LIMIT"):
            memory.parse_size(bad)


def test_host_available(monkeypatch):
    monkeypatch.delenv(memory.ENV_VAR, raising=False)
    n, source = memory.host_available()
    assert n > 0 and source in ("MemAvailable", "free pages")
    monkeypatch.setenv(memory.ENV_VAR, "3G")
    assert memory.host_available() == (3 << 30, memory.ENV_VAR)


def test_huge_film_fails_at_once_from_the_cli(tmp_path, monkeypatch, capsys):
    """camera.resolution = [40000, 40000] (legal) fails before anything is allocated, in well
    under a second, with the one-line error naming the key and both figures; exit 2."""
    monkeypatch.setenv(memory.ENV_VAR, "16G")   # the same on a machine with more memory
    p = tmp_path / "big.toml"
    p.write_text(dict_to_toml(TINY))
    out = tmp_path / "big.exr"
    main(["render", str(p), "-o", str(out), "--quiet", "--spp", "1"])   # warm imports
    capsys.readouterr()
    tracemalloc.start()
    t = time.perf_counter()
    status = main(["render", str(p), "-o", str(tmp_path / "x.exr"),
                   "-D", "camera.resolution=[40000, 40000]"])
    seconds = time.perf_counter() - t
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    err = capsys.readouterr().err
    assert status == 2
    assert seconds < 0.5, seconds
    assert peak < 50 << 20, peak   # the film (190 GiB) was never allocated
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert re.fullmatch(rf"volmc: error: {re.escape(str(p))}: camera\.resolution: a "
                        rf"40000x40000 film needs {FIGURE} of host memory \(the render "
                        rf"{FIGURE} in all\), 16\.0 GiB available \(VOLMC_MEMORY_LIMIT\)",
                        lines[0]), lines[0]
    assert not (tmp_path / "x.exr").exists()


def test_huge_film_real_figures():
    """Without the override the figure is the machine's: 40000^2 needs far more than any
    test machine has (190 GiB)."""
    scene = scene_from_dict(TINY, overrides=["camera.resolution=[40000, 40000]"])
    est = memory.estimate(scene, "opencl")
    film = est.by_key()["camera.resolution"]
    assert film.host > 150 << 30
    n, _ = memory.host_available()
    if n is not None and n < film.host:
        with pytest.raises(SceneError, match=r"camera\.resolution: a 40000x40000 film"):
            memory.check_memory(scene, "numba")


def _cloud_cli_refuses(tmp_path, capsys, define, message):
    """volmc render of the bundled cloud with ``-D define`` exits with status 2 and the one
    line ``volmc: error: .../cloud.toml: <message>``, writing nothing."""
    status = main(["render", str(default_scene()), "-o", str(tmp_path / "c.exr"),
                   "-D", define])
    err = capsys.readouterr().err
    assert status == 2, err
    assert re.fullmatch(rf"volmc: error: .*cloud\.toml: {message}\n", err), err
    assert not (tmp_path / "c.exr").exists()


def test_grid_too_large_fails_naming_the_density(tmp_path, monkeypatch, capsys, cloud256):
    """A 256^3 cloud (64 MiB loaded, 64 MiB more on the device, 128 MiB more for the
    float64 reference) against a 100M machine: medium.density, exit 2, from the CLI and
    from the library's render()."""
    monkeypatch.setenv(memory.ENV_VAR, "100M")
    _cloud_cli_refuses(tmp_path, capsys, "medium.density.resolution=256",
                       rf"medium\.density: the density grid needs {FIGURE} of host memory "
                       rf"\(the render {FIGURE} in all\), 100\.0 MiB available "
                       r"\(VOLMC_MEMORY_LIMIT\)")
    from volmc.render import render
    for backend in ("opencl", "numba"):
        with pytest.raises(SceneError, match=r"medium\.density: the density grid needs"):
            render(cloud256, backend=backend, progress=False)
    import volmc   # the Python API checks before it builds a backend, too
    with pytest.raises(volmc.VolmcError, match=r"medium\.density: the density grid needs"):
        volmc.render(cloud256, backend="numba", progress=False)


def test_generated_density_too_large_fails_before_generating(tmp_path, monkeypatch, capsys):
    """A generated grid that cannot fit fails before the generator runs (it would exhaust
    memory while generating): medium.density.resolution, the generator's peak against what
    there is, exit 2 and nothing written; the same from the library."""
    from volmc.scene import generators
    monkeypatch.setenv(memory.ENV_VAR, "1G")

    def never(*a, **k):
        raise AssertionError("the generator ran")
    monkeypatch.setattr(generators, "cloud", never)
    # 2048^3 float32 values and one byte per voxel of the validation masks: 40 GiB.
    _cloud_cli_refuses(tmp_path, capsys, "medium.density.resolution=2048",
                       r"medium\.density\.resolution: generating a 2048x2048x2048 cloud "
                       r"needs 40\.0 GiB of host memory, 1\.0 GiB available "
                       r"\(VOLMC_MEMORY_LIMIT\)")
    import volmc
    with pytest.raises(volmc.VolmcError, match=r"medium\.density\.resolution: generating"):
        volmc.load_scene(default_scene(), {"medium.density.resolution": 1024})
    # The plume generates two fields: a 512^3 plume needs 2 x 512 MiB + 128 MiB.
    monkeypatch.setattr(generators, "plume", never)
    spec = dict(TINY, medium=dict(TINY["medium"], density={
        "generator": "plume", "resolution": 512}))
    with pytest.raises(SceneError, match=r"generating a 512x512x512 plume needs 1\.1 GiB"):
        scene_from_dict(spec)


@pytest.mark.parametrize("suffix", [".npy", ".npz", ".vol", ".vdb"])
def test_grid_file_too_large_fails_before_reading(tmp_path, monkeypatch, suffix):
    """A grid file whose array would not fit fails before it is read (from the header), or,
    for a VDB file rendered dense, before it is expanded: the file and key are named. The
    same files load under a larger limit."""
    from volmc.scene.grids import save_grid
    path = tmp_path / f"g{suffix}"
    if suffix == ".vdb":
        # Two leaves in a box of 1.3e9 voxels: reading it needs little, expanding it much
        # (a compact file such as blobs.vdb needs more to read, 36 leaves, than to expand).
        import shutil
        from pathlib import Path
        shutil.copy(Path(__file__).parent / "data" / "vdb" / "sparse.vdb", path)
        what, limit = r"expanding grid 'density' to a dense \d+x\d+x\d+ array", "1M"
    elif suffix == ".npy":
        np.save(path, np.ones((40, 30, 20)))   # float64: its float32 copy counts too
        what, limit = r"loading a 20x30x40 grid of float64", "250K"
    else:
        save_grid(path, np.ones((40, 30, 20), np.float32))
        what = r"loading a 20x30x40 grid" + (" of float32" if suffix == ".npz" else "")
        limit = "100K"
    spec = dict(TINY, medium=dict(TINY["medium"], density={"file": str(path)}),
                render=dict(TINY["render"], grid_storage="dense"))
    monkeypatch.setenv(memory.ENV_VAR, limit)
    with pytest.raises(SceneError, match=rf"g\{suffix}: medium\.density.*: {what} needs "
                                         rf"{FIGURE} of host memory, {FIGURE} available"):
        scene_from_dict(spec)
    if suffix == ".vdb":   # the same file in bricks, under the same limit: read, not expanded
        spec["render"] = dict(spec["render"], grid_storage="bricks")
        assert scene_from_dict(spec).media_scenes[0].grid is not None
    else:
        monkeypatch.setenv(memory.ENV_VAR, "1G")
        assert scene_from_dict(spec).grid.shape[::-1] == (20, 30, 40)


def test_grid_file_estimates_follow_layout_and_member_names(tmp_path, monkeypatch):
    """A Fortran-order float32 array is copied to C order (8 bytes a voxel at the peak, not
    5): a limit between the two refuses it and loads the C-order file. An .npz member
    stored without the .npy suffix is read (and checked) too."""
    import zipfile
    from volmc.scene.grids import load_grid, load_peak_bytes
    a = np.ones((40, 30, 20), np.float32)
    np.save(tmp_path / "c.npy", a)
    np.save(tmp_path / "f.npy", np.asfortranarray(a))
    assert load_peak_bytes(a.size) == 5 * a.size
    assert load_peak_bytes(a.size, np.float32, True) == 8 * a.size
    monkeypatch.setenv(memory.ENV_VAR, str(6 * a.size))
    assert load_grid(tmp_path / "c.npy").flags.c_contiguous
    with pytest.raises(SceneError, match=r"f\.npy: density: loading a 20x30x40 grid"):
        load_grid(tmp_path / "f.npy")
    with zipfile.ZipFile(tmp_path / "bare.npz", "w") as z:
        with z.open("density", "w") as m:
            np.lib.format.write_array(m, a)
    assert load_grid(tmp_path / "bare.npz").shape == a.shape
    monkeypatch.setenv(memory.ENV_VAR, str(4 * a.size))
    with pytest.raises(SceneError, match=r"bare\.npz: density: loading a 20x30x40 grid"):
        load_grid(tmp_path / "bare.npz")


def test_vdb_field_placed_on_the_density_is_checked(tmp_path, monkeypatch):
    """A field grid from the density's VDB file is placed on the density's voxels: that
    array is checked before it is made, whatever size the field's own box has."""
    from pathlib import Path

    def spec(name):
        vdb = str(Path(__file__).parent / "data" / "vdb" / name)
        return dict(TINY, medium={"density": {"file": vdb}, "scale": 1.0, "albedo": 0.5,
                                  "emission": {"temperature": {"file": vdb}}})
    # Two leaves in a box of 1.3e9 voxels: the density (kept as bricks) and the field read
    # in a few KiB, and the field placed on the density's voxels is the large array.
    monkeypatch.setenv(memory.ENV_VAR, "1M")
    with pytest.raises(SceneError, match=r"medium\.emission\.temperature: placing grid "
                                         r"'density' on the density's \d+x\d+x\d+ voxels"):
        scene_from_dict(spec("sparse.vdb"))
    monkeypatch.setenv(memory.ENV_VAR, "1G")
    assert scene_from_dict(spec("blobs.vdb")).emission_grid.shape == (21, 21, 22)


def test_library_render_raises_for_a_huge_film(monkeypatch):
    from volmc.render import render
    monkeypatch.setenv(memory.ENV_VAR, "16G")
    scene = scene_from_dict(TINY, overrides=["camera.resolution=[40000, 40000]"])
    t = time.perf_counter()
    with pytest.raises(SceneError, match=r"camera\.resolution: a 40000x40000 film needs"):
        render(scene, backend="numba", progress=False)
    assert time.perf_counter() - t < 0.5


def test_device_limits_are_checked(cloud):
    """A device buffer above max_mem_alloc_size, or device memory above global_mem_size
    (a GPU: its memory is not the host's), fails naming the key."""
    import pyopencl as cl
    small = types.SimpleNamespace(global_mem_size=1 << 40, max_mem_alloc_size=4 << 20,
                                  type=cl.device_type.GPU, name="Small GPU")
    with pytest.raises(SceneError, match=r"medium\.density: the density grid needs a device "
                                         r"buffer of 8\.0 MiB, Small GPU allows 4\.0 MiB per "
                                         r"buffer \(max_mem_alloc_size\)"):
        memory.check_memory(cloud, "opencl", small)
    tiny = types.SimpleNamespace(global_mem_size=6 << 20, max_mem_alloc_size=1 << 30,
                                 type=cl.device_type.GPU, name="Tiny GPU")
    with pytest.raises(SceneError, match=r"medium\.density: the density grid needs 8\.0 MiB "
                                         r"of device memory .* on Tiny GPU"):
        memory.check_memory(cloud, "opencl", tiny)


def test_ordinary_scenes_pass(cloud):
    for backend in ("opencl", "numba"):
        est = memory.check_memory(cloud, backend)
        assert est.band_rows == 256   # one launch covers the image
        keys = est.by_key()
        assert keys["medium.density"].host >= 128 ** 3 * 4
    est = memory.estimate(cloud, "numba")
    # The loaded float32 grid and the reference's float64 copy.
    assert est.by_key()["medium.density"].host == 128 ** 3 * (4 + 8)
    assert est.by_key()["medium.density"].device == 0
    est = memory.estimate(cloud, "opencl")
    assert est.by_key()["medium.density"].device == 128 ** 3 * 4


def test_film_estimate_matches_what_numpy_allocates(tmp_path):
    """The film figure (sums, and the peak of writing EXR, variance EXR and PNG) is within a
    factor 2 of the bytes numpy allocates for them (tracemalloc)."""
    w, h = 512, 384
    scene = scene_from_dict(TINY, overrides=[f"camera.resolution=[{w}, {h}]"])
    sums, outputs = memory.estimate(scene, "numba", film=True, scene_data=False).components[:2]
    assert sums.key == outputs.key == "camera.resolution" and outputs.phase == "write"
    estimated = memory.Component(sums.key, sums.what, host=sums.host + outputs.host)
    rng = np.random.default_rng(1)
    tracemalloc.start()
    film = Film(w, h)
    film.sum[:] = rng.random((h, w, 4))   # RGBA
    film.sum_sq[:] = 2.0 * film.sum * film.sum
    film.spp = 4
    held = tracemalloc.get_traced_memory()[0]
    peak = 0
    for write in (lambda: write_exr(tmp_path / "a.exr", film.rgba()),
                  lambda: write_exr(tmp_path / "a.var.exr", film.variance_of_mean()),
                  lambda: write_png(tmp_path / "a.png", film.mean())):
        tracemalloc.reset_peak()
        write()
        peak = max(peak, tracemalloc.get_traced_memory()[1])
    tracemalloc.stop()
    assert held >= w * h * 64
    assert 0.5 < estimated.host / peak < 2.0, (estimated.host, peak)


def test_band_rows_follow_the_memory(monkeypatch):
    # OpenCL at 256x256: four samples per pixel per launch (params.launch_spp), 16 bytes
    # (RGBA) each on the device and its copy, 1 each of counters, and 3 x 4 float64
    # temporaries a pixel (the sum, the sum of squares, one sample): 228 bytes a pixel.
    assert launch_spp(256 * 256) == 4
    assert memory.launch_bytes_per_pixel("opencl", 256, 256) == (160, 68, 64)
    assert memory.band_rows(256, 256, "opencl", available=16 << 30) == 256
    # 1/8 of 8 MiB over 228 bytes a pixel: 4599 pixels, 17 rows of 256.
    assert memory.band_rows(256, 256, "opencl", available=8 << 20) == 17
    # Numba: the counters, 8 x 8 bytes a pixel.
    assert memory.band_rows(256, 256, "numba", available=8 << 20) == 256 // 4
    # One sample per pixel: 16 + 96 on the host, 17 on the device.
    assert memory.band_rows(40000, 40000, "opencl", available=64 << 30) == \
        memory.LAUNCH_BUDGET // 129 // 40000
    assert memory.band_rows(10, 10, "opencl", available=1) == 1
    # A small image keeps up to launch_spp samples of each pixel per launch: 2621 at 10x10.
    assert memory.launch_bytes_per_pixel("opencl", 10, 10)[0] == 2621 * 16 + 96
    # One sample buffer never exceeds max_mem_alloc_size (2 samples a pixel at 100x1000).
    assert memory.band_rows(100, 1000, "opencl", available=1 << 40,
                            max_alloc=16 * 2 * 100 * 5) == 5
    monkeypatch.setenv(memory.ENV_VAR, "8M")
    assert memory.band_rows(256, 256, "opencl") == 17


@pytest.mark.parametrize("backend", ["opencl", "numba"])
def test_banded_render_equals_unbanded(backend):
    """Bands of 7 rows (the last one short) give the image of one launch bit for bit, and
    the same counters: each pixel's samples are keyed by its index and the sample's."""
    from volmc.render import render
    scene = load_scene(default_scene(), ["camera.resolution=[24, 20]", "render.spp=6",
                                         "medium.density.resolution=32"])
    whole = render(scene, backend=backend, progress=False)
    banded = render(scene, backend=backend, progress=False, band_rows=7)
    assert banded.extra == whole.extra
    assert np.array_equal(banded.film.sum, whole.film.sum)
    assert np.array_equal(banded.film.sum_sq, whole.film.sum_sq)
    # The lanes' counts follow the work-items, which bands cut differently.
    assert sample_counts(banded.counters) == sample_counts(whole.counters)
    assert whole.counters["lookups"] > 0
    one_row = render(scene, backend=backend, progress=False, band_rows=1, spp=3)
    part = render(scene, backend=backend, progress=False, spp=3)
    assert np.array_equal(one_row.film.sum, part.film.sum)
    assert sample_counts(one_row.counters) == sample_counts(part.counters)


_PEAK_SCRIPT = """
import gc, json, sys
from volmc.cli import main
def status(key):
    for line in open('/proc/self/status'):
        if line.startswith(key):
            return int(line.split()[1]) * 1024
args = ['render', '--quiet', '--spp', '1', '-o', sys.argv[1], '-D', 'camera.resolution=[48, 48]']
assert main(args + ['-D', 'medium.density.resolution=16']) == 0   # imports, JIT, kernels
gc.collect()
base = status('VmRSS:')
with open('/proc/self/clear_refs', 'w') as f:   # resets VmHWM
    f.write('5')
assert main(args + ['-D', 'medium.density.resolution=192']) == 0
print(json.dumps(status('VmHWM:') - base))
"""


def test_estimate_bounds_the_measured_peak(tmp_path):
    """A grid-dominated volmc render (the cloud at 192^3, a 48x48 image): the peak RSS
    growth over the same process after a tiny render (VmHWM, reset through
    /proc/self/clear_refs) is at most the estimate, and the estimate at most 1.6x it."""
    import json
    import os
    import subprocess
    import sys
    if not os.path.exists("/proc/self/clear_refs"):
        pytest.skip("needs Linux's /proc/self/clear_refs")
    run = subprocess.run([sys.executable, "-c", _PEAK_SCRIPT, str(tmp_path / "c.exr")],
                         capture_output=True, text=True, timeout=300)
    if run.returncode != 0 and "clear_refs" in run.stderr:
        pytest.skip("/proc/self/clear_refs is not writable here")
    assert run.returncode == 0, run.stderr
    measured = json.loads(run.stdout.strip().splitlines()[-1])
    scene = load_scene(default_scene(), ["medium.density.resolution=192",
                                         "camera.resolution=[48, 48]"])
    est = memory.estimate(scene, "opencl").host
    assert measured <= est <= 1.6 * measured, (est, measured)


def test_the_camera_check_packs_the_boxes_alone(cloud):
    """volmc render's check that the camera sees a medium packed the whole scene in float64:
    a float64 copy of the grid (8 bytes a voxel) and its majorant, the peak of a render's
    memory that no estimate counted. It needs the boxes alone."""
    import tracemalloc
    from volmc.visibility import medium_in_view
    medium_in_view(cloud)   # Numba's compilation is not the check's
    tracemalloc.start()
    try:
        assert medium_in_view(cloud)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20, peak          # the 128^3 grid alone is 8 MiB in float32
