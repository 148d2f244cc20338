"""Frame sequences (volmc/frames.py, volmc/scene/frames.py): ``{frame:04d}`` patterns in
every grid source, ``volmc render --frames`` and ``volmc.render_frames``. Each frame is the
single render of that frame's scene bit for bit (also on Dask); complete frames are
skipped; bad frames and missing frame files are one-line errors."""

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import volmc
from volmc.film import read_exr, write_exr
from volmc.frames import frame_path, is_complete, parse_frames
from volmc.scene.errors import SceneError
from volmc.scene.frames import describe, existing_frames, substitute
from volmc.scene.serialize import dict_to_toml
from cli_subprocess import volmc_cli, volmc_env

VDB = Path(__file__).parent / "data" / "vdb"
FRAMES = (1, 2, 3)


def _grid(f):
    """Frame f's density: a cube whose size and density change with f, so frames differ."""
    g = np.zeros((8, 8, 8), np.float32)
    g[1:3 + f, 2:6, 1:7] = 0.5 * f
    return g


def _scene(density_file="cache/d_{frame:04d}.npy"):
    return {
        "camera": {"eye": [0.0, 0.0, 4.0], "resolution": [16, 16]},
        "medium": {"bounds": [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]],
                   "density": {"file": density_file}, "scale": 3.0, "albedo": 0.8},
        "lights": [{"type": "environment", "radiance": 1.0}],
        "render": {"spp": 4, "seed": 3},
    }


@pytest.fixture
def seq(tmp_path):
    """tmp_path/s.toml over cache/d_0001.npy .. d_0003.npy."""
    (tmp_path / "cache").mkdir()
    for f in FRAMES:
        np.save(tmp_path / "cache" / f"d_{f:04d}.npy", _grid(f))
    (tmp_path / "s.toml").write_text(dict_to_toml(_scene()))
    return tmp_path / "s.toml"


def run(args, cwd):
    return subprocess.run(volmc_cli(*args), cwd=cwd, env=volmc_env(), capture_output=True,
                          text=True, timeout=600)


def one_line_error(r, *words):
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert lines[0].startswith("volmc: error: ") and "Traceback" not in r.stderr
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


# -- frame specs, paths, patterns ---------------------------------------------------------

def test_parse_frames():
    assert list(parse_frames("1-48:2")) == list(range(1, 49, 2))
    assert list(parse_frames("7")) == [7]
    assert list(parse_frames(" 0-3 ")) == [0, 1, 2, 3]
    assert list(parse_frames("3-3")) == [3]
    for bad, words in [("5-2", "before the first"), ("a-b", "expected FIRST-LAST"),
                       ("0:0", "step must be at least 1"), ("1-9:0", "step"),
                       ("-3", "expected"), ("1-", "expected"), ("", "expected"),
                       ("1,2", "expected"), ("0-99999999", "at most")]:
        with pytest.raises(SceneError, match=words) as e:
            parse_frames(bad)
        assert str(e.value).startswith("command line: --frames: ")


def test_frame_path_and_describe():
    assert frame_path("out/fire.exr", 7) == "out/fire.0007.exr"
    assert frame_path("fire.png", 12345) == "fire.12345.png"
    assert describe([1, 2, 3, 5, 7, 8]) == "frames 1-3, 5, 7-8"
    assert describe([]) == "no frames on disk"
    assert describe(list(range(0, 40, 2)), limit=3).endswith("... (20 frames)")


def test_substitute_formats_every_grid_source_and_leaves_raw_alone(tmp_path):
    for name in ("a_07.npy", "b_7.npz", "c_0007.npy", "d_   7.vdb", "e.npy"):
        (tmp_path / name).touch()
    raw = {"medium": {"density": {"file": "a_{frame:02d}.npy"},
                      "emission": {"temperature": {"file": "b_{frame}.npz"}}},
           "media": [{"density": {"file": str(tmp_path / "c_{frame:04d}.npy")}},
                     {"density": {"file": "d_{frame:4}.vdb", "grid": "smoke"},
                      "emission": {"radiance": 1.0, "field": {"file": "e.npy"}}}],
           # An environment map is not a grid: its file is left as written.
           "lights": [{"type": "environment", "file": "sky_{frame}.exr"}]}
    out = substitute(raw, 7, str(tmp_path / "s.toml"))
    assert out["medium"]["density"]["file"] == "a_07.npy"
    assert out["medium"]["emission"]["temperature"]["file"] == "b_7.npz"
    assert out["media"][0]["density"]["file"] == str(tmp_path / "c_0007.npy")
    assert out["media"][1]["density"] == {"file": "d_   7.vdb", "grid": "smoke"}
    assert out["media"][1]["emission"]["field"]["file"] == "e.npy"
    assert out["lights"][0]["file"] == "sky_{frame}.exr"
    assert raw["medium"]["density"]["file"] == "a_{frame:02d}.npy"   # not changed
    # No frame: a pattern is an error naming the key; a scene without one passes.
    with pytest.raises(SceneError, match=r"medium\.density\.file: .*--frames"):
        substitute(raw, None, "s.toml")
    plain = {"medium": {"density": {"file": "x{.npy"}}}   # not a format string: literal
    assert substitute(plain, None, "s.toml") is plain
    with pytest.raises(SceneError, match=r"media\[1\]\.density\.file: .*only \{frame\}"):
        substitute({"media": [{"density": {"file": "e.npy"}},
                              {"density": {"file": "{frame}_{take}.npy"}}]}, 1, "s.toml",
                   str(tmp_path))
    with pytest.raises(SceneError, match="Unknown format code"):
        substitute({"medium": {"density": {"file": "{frame:04s}.npy"}}}, 1, "s.toml")


def test_existing_frames_round_trip_the_pattern(tmp_path):
    for name in ("d_0001.npy", "d_0002.npy", "d_0010.npy", "d_12.npy", "d_0003.npy.bak",
                 "d_x.npy"):
        (tmp_path / name).touch()
    assert existing_frames("d_{frame:04d}.npy", str(tmp_path)) == [1, 2, 10]
    assert existing_frames("d_{frame}.npy", str(tmp_path)) == [12]
    assert existing_frames("nothing_{frame}.npy", str(tmp_path)) == []


# -- loading ------------------------------------------------------------------------------

def test_load_scene_frame_reads_that_frames_grids(seq):
    for f in FRAMES:
        s = volmc.load_scene(seq, frame=f)
        np.testing.assert_array_equal(s.grid, _grid(f))
        assert s.medium.density.path == f"cache/d_{f:04d}.npy"
    with pytest.raises(volmc.VolmcError, match="names a frame"):
        volmc.load_scene(seq)
    with pytest.raises(volmc.VolmcError, match=r"frame 9: .*has frames 1-3"):
        volmc.load_scene(seq, frame=9)
    # A scene dict, its paths relative to base_dir.
    s = volmc.scene_from_dict(_scene(), base_dir=seq.parent, frame=2)
    np.testing.assert_array_equal(s.grid, _grid(2))


def test_vdb_frames_in_density_and_emission_of_several_media(tmp_path):
    """VDB frames (two encodings of one grid), the pattern in a [[media]] density and its
    emission temperature, beside a medium whose grid names no frame."""
    (tmp_path / "cache").mkdir()
    shutil.copy(VDB / "blobs.vdb", tmp_path / "cache" / "fluid_data_0001.vdb")
    shutil.copy(VDB / "blobs_zip.vdb", tmp_path / "cache" / "fluid_data_0002.vdb")
    np.save(tmp_path / "still.npy", _grid(1))
    pattern = "cache/fluid_data_{frame:04d}.vdb"
    raw = _scene("still.npy")
    box = raw.pop("medium")
    raw["media"] = [box, {"density": {"file": pattern},
                          "emission": {"temperature": {"file": pattern,
                                                       "grid": "temperature"}}}]
    truth = np.load(VDB / "blobs_density.npy")
    for f in (1, 2):
        s = volmc.scene_from_dict(raw, base_dir=tmp_path, frame=f)
        vdb = s.media_scenes[1]
        assert np.array_equal(np.asarray(vdb.grid), truth)
        name = f"cache/fluid_data_{f:04d}.vdb"
        alone = volmc.scene_from_dict(raw, base_dir=tmp_path, overrides={
            "media.1.density.file": name, "media.1.emission.temperature.file": name})
        assert vdb.medium == alone.media_scenes[1].medium
        np.testing.assert_array_equal(vdb.emission_grid, alone.media_scenes[1].emission_grid)
        np.testing.assert_array_equal(s.media_scenes[0].grid, _grid(1))
    with pytest.raises(volmc.VolmcError) as e:
        volmc.scene_from_dict(raw, base_dir=tmp_path, frame=3)
    assert "media[1].density.file: frame 3: grid file not found: cache/fluid_data_0003.vdb" \
        in str(e.value) and "has frames 1-2" in str(e.value)


# -- the command line ---------------------------------------------------------------------

def test_cli_frames_equal_single_renders_and_resume(seq):
    d = seq.parent
    (d / "out").mkdir()
    r = run(["render", str(seq), "--frames", "1-3", "-o", "out/s.exr", "--png"], d)
    assert r.returncode == 0, r.stderr
    for i, f in enumerate(FRAMES, 1):
        assert f"frame {i}/3 ({f}): done: out/s.{f:04d}.exr + out/s.{f:04d}.png" in r.stderr
        assert (d / "out" / f"s.{f:04d}.png").stat().st_size > 0
    frames = {f: read_exr(d / "out" / f"s.{f:04d}.exr", alpha=True) for f in FRAMES}
    assert not np.array_equal(frames[1][0], frames[2][0])
    # Frame f alone: the pattern replaced by frame f's file through -D.
    for f in (1, 3):
        r1 = run(["render", str(seq), "--quiet", "-o", f"one{f}.exr",
                  "-D", f"medium.density.file=\"cache/d_{f:04d}.npy\""], d)
        assert r1.returncode == 0, r1.stderr
        one, meta = read_exr(d / f"one{f}.exr", alpha=True)
        np.testing.assert_array_equal(frames[f][0], one)
        assert frames[f][1]["frame"] == f and frames[f][1]["partial"] == 0
        assert frames[f][1]["spp"] == meta["spp"] == 4
    # A killed run: frame 2's EXR gone, frame 3's partial. Frame 1 is skipped untouched
    # (its grid file may be gone by then), 2 and 3 render again to the same images.
    (d / "out" / "s.0002.exr").unlink()
    (d / "cache" / "d_0001.npy").unlink()
    img3, meta3 = frames[3]
    write_exr(d / "out" / "s.0003.exr", img3, {**meta3, "partial": 1})
    t1 = (d / "out" / "s.0001.exr").stat().st_mtime_ns
    r = run(["render", str(seq), "--frames", "1-3", "-o", "out/s.exr"], d)
    assert r.returncode == 0, r.stderr
    assert "frame 1/3 (1): out/s.0001.exr is complete, skipped" in r.stderr
    assert "frame 2/3 (2): done" in r.stderr and "frame 3/3 (3): done" in r.stderr
    assert "3 frames, 2 rendered, 1 complete already" in r.stderr
    assert (d / "out" / "s.0001.exr").stat().st_mtime_ns == t1
    for f in FRAMES:
        np.testing.assert_array_equal(read_exr(d / "out" / f"s.{f:04d}.exr", alpha=True)[0],
                                      frames[f][0])
    # Another scene (an override, here the spp) or a truncated file is not complete.
    np.save(d / "cache" / "d_0001.npy", _grid(1))
    ident = read_exr(d / "out" / "s.0001.exr")[1]["frame_identity"]
    assert is_complete(d / "out" / "s.0001.exr", ident)
    data = (d / "out" / "s.0002.exr").read_bytes()
    (d / "out" / "s.0002.exr").write_bytes(data[:len(data) // 2])
    r = run(["render", str(seq), "--frames", "1-2", "-o", "out/s.exr", "--quiet",
             "-D", "render.spp=2"], d)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert read_exr(d / "out" / "s.0001.exr")[1]["spp"] == 2
    assert read_exr(d / "out" / "s.0002.exr")[1]["spp"] == 2
    assert not is_complete(d / "out" / "s.0001.exr", ident)


def test_cli_frame_errors_are_one_line(seq):
    d = seq.parent
    r = run(["render", str(seq), "--frames", "2-5"], d)
    one_line_error(r, f"{seq}: medium.density.file: frame 4: grid file not found: "
                      "cache/d_0004.npy", "has frames 1-3")
    assert not list(d.glob("s.*.exr"))   # checked before any frame renders
    one_line_error(run(["render", str(seq)], d), "medium.density.file", "--frames")
    for bad in ("5-2", "a-b", "0:0"):
        one_line_error(run(["render", str(seq), "--frames", bad], d),
                       "command line: --frames: ", repr(bad))
    one_line_error(run(["render", str(seq), "--frames", "1-3", "--resume", "x.npz"], d),
                   "command line: --resume: ")
    (d / "plain.toml").write_text(dict_to_toml(_scene("cache/d_0001.npy")))
    one_line_error(run(["render", str(d / "plain.toml"), "--frames", "1-3"], d),
                   "--frames: no grid file of the scene names the frame")


def test_cli_frames_on_dask_equal_local(seq):
    pytest.importorskip("distributed")
    d = seq.parent
    for out, extra in (("local.exr", []), ("dask.exr", ["--workers", "2"])):
        r = run(["render", str(seq), "--frames", "2-3", "--quiet", "-o", out] + extra, d)
        assert r.returncode == 0, r.stderr
    for f in (2, 3):
        local, _ = read_exr(d / f"local.{f:04d}.exr", alpha=True)
        dask, meta = read_exr(d / f"dask.{f:04d}.exr", alpha=True)
        np.testing.assert_array_equal(dask, local)
        assert meta["backend"] == "opencl on dask" and meta["frame"] == f


# -- the API ------------------------------------------------------------------------------

def test_render_frames_api(seq, tmp_path):
    imgs = volmc.render_frames(seq, "1-3:2", spp=3, seed=5, progress=False)
    assert list(imgs) == [1, 3]
    for f, img in imgs.items():
        one = volmc.render(volmc.load_scene(seq, frame=f), spp=3, seed=5, progress=False)
        np.testing.assert_array_equal(img.image, one.image)
        np.testing.assert_array_equal(img.variance, one.variance)
        assert img.spp == 3 and img.seed == 5
    out = tmp_path / "api" / "fire.exr"
    out.parent.mkdir()
    paths = volmc.render_frames(str(seq), [2, 1], output=out, spp=3, seed=5, png=True,
                                variance=True, progress=False)
    assert paths == {2: str(tmp_path / "api" / "fire.0002.exr"),
                     1: str(tmp_path / "api" / "fire.0001.exr")}
    for f in (1, 2):
        assert (tmp_path / "api" / f"fire.{f:04d}.png").is_file()
        assert (tmp_path / "api" / f"fire.{f:04d}.var.exr").is_file()
    np.testing.assert_array_equal(read_exr(paths[1])[0], imgs[1].image)
    mtimes = {f: Path(p).stat().st_mtime_ns for f, p in paths.items()}
    assert volmc.render_frames(seq, 1, output=out, spp=3, seed=5, progress=False) == \
        {1: paths[1]}
    assert Path(paths[1]).stat().st_mtime_ns == mtimes[1]   # complete: skipped
    for bad, match in [(dict(frames="2-1"), "volmc.render_frames\\(\\): frames: "),
                       (dict(frames=[1, 1]), "named twice"),
                       (dict(frames=[-1]), "frames: must be in"),
                       (dict(frames=[4]), "frame 4: grid file not found"),
                       (dict(frames=1, png=True), "png: needs an output"),
                       (dict(frames=1, output=tmp_path / "x.png"), "ending in .exr")]:
        with pytest.raises(volmc.VolmcError, match=match):
            volmc.render_frames(seq, **bad)
    with pytest.raises(volmc.VolmcError, match="a loaded Scene holds one frame"):
        volmc.render_frames(volmc.load_scene(seq, frame=1), [1])
    # A dict scene, its grid paths against base_dir.
    imgs = volmc.render_frames(_scene(), [2], base_dir=seq.parent, spp=3, seed=5,
                               progress=False)
    np.testing.assert_array_equal(imgs[2].image, volmc.render(
        volmc.load_scene(seq, frame=2), spp=3, seed=5, progress=False).image)


def test_cli_frames_denoise_each_frame(seq):
    pytest.importorskip("pyoidn")
    d = seq.parent
    r = run(["render", str(seq), "--frames", "1-2", "-o", "f.exr", "--png", "--denoise",
             "--quiet"], d)
    assert r.returncode == 0, r.stderr
    for f in (1, 2):
        img, meta = read_exr(d / f"f.{f:04d}.exr", alpha=True)
        den, dmeta = read_exr(d / f"f.{f:04d}.denoised.exr", alpha=True)
        assert dmeta["frame"] == f and dmeta["denoised.from"] == f"f.{f:04d}.exr"
        assert np.array_equal(den[..., 3], img[..., 3]) and "denoised" not in meta
        assert (d / f"f.{f:04d}.denoised.png").exists()
    out = d / "api" / "g.exr"
    out.parent.mkdir()
    volmc.render_frames(str(seq), "1-2", output=out, denoise=True, progress=False)
    for f in (1, 2):
        dmeta = read_exr(d / "api" / f"g.{f:04d}.denoised.exr")[1]
        assert int(dmeta["denoised.albedo_aov"]) == 1
    with pytest.raises(volmc.VolmcError, match="denoise: needs an output"):
        volmc.render_frames(seq, 1, denoise=True)


def test_frame_patterns_that_cannot_name_a_file_are_one_line_errors():
    """An index or attribute of the frame number, another field, or a width Python would
    spend gigabytes on: SceneError naming the file and key (they were a TypeError and a
    MemoryError)."""
    from volmc.scene.frames import format_path
    for pattern in ("d_{frame[0]}.npy", "d_{frame.real}.npy", "d_{fram:04d}.npy",
                    "d_{frame:>99999999999}.npy", "d_{frame:.500}.npy", "d_{frame:x>100}.npy"):
        with pytest.raises(SceneError) as e:
            format_path(pattern, 7, "s.toml", "medium.density.file")
        assert str(e.value).startswith("s.toml: medium.density.file: "), pattern
    assert format_path("d_{frame:04d}.npy", 7, "s.toml", "k") == "d_0007.npy"
    assert format_path("d_{frame:>12}.npy", 7, "s.toml", "k") == "d_" + " " * 11 + "7.npy"


def test_frames_cut_short_or_missing_files_render_again(seq):
    """Found by an outside workflow test: an EXR cut short keeps its header, and was taken
    for complete; and a run asking for more files (--png, --variance) than the one before
    skipped every frame without writing them."""
    d = seq.parent
    r = run(["render", str(seq), "--frames", "1-2", "-o", "s.exr", "--quiet"], d)
    assert r.returncode == 0, r.stderr
    first = read_exr(d / "s.0002.exr", alpha=True)[0]
    data = (d / "s.0002.exr").read_bytes()
    (d / "s.0002.exr").write_bytes(data[:len(data) - 200])     # the header is whole
    r = run(["render", str(seq), "--frames", "1-2", "-o", "s.exr"], d)
    assert "frame 1/2 (1): s.0001.exr is complete, skipped" in r.stderr
    assert "frame 2/2 (2): done" in r.stderr
    # OpenEXR's own messages about the cut file stay off the terminal of a run that works.
    assert "EXR_ERR" not in r.stderr and "Warning" not in r.stderr, r.stderr
    np.testing.assert_array_equal(read_exr(d / "s.0002.exr", alpha=True)[0], first)
    r = run(["render", str(seq), "--frames", "1-2", "-o", "s.exr", "--png", "--variance"], d)
    assert r.returncode == 0 and "2 rendered, 0 complete already" in r.stderr, r.stderr
    for f in (1, 2):
        assert (d / f"s.{f:04d}.png").is_file() and (d / f"s.{f:04d}.var.exr").is_file()
    r = run(["render", str(seq), "--frames", "1-2", "-o", "s.exr", "--png", "--variance"], d)
    assert "0 rendered, 2 complete already" in r.stderr, r.stderr


def test_complete_frames_are_skipped_without_a_stderr(seq):
    """A run with no stderr at all (2>&-, a service) still skips its complete frames: the
    check that keeps OpenEXR's messages quiet must not fail there (it did, and every frame
    was rendered again)."""
    import os
    d = seq.parent
    args = volmc_cli("render", str(seq), "--frames", "1-2", "-o", "s.exr", "--quiet")
    r = subprocess.run(args, cwd=d, env=volmc_env(), capture_output=True, timeout=600)
    assert r.returncode == 0, r.stderr
    before = [os.stat(d / f"s.{f:04d}.exr").st_mtime_ns for f in (1, 2)]
    r = subprocess.run(args, cwd=d, env=volmc_env(), stdout=subprocess.PIPE, timeout=600,
                       preexec_fn=lambda: os.close(2))
    assert r.returncode == 0
    assert [os.stat(d / f"s.{f:04d}.exr").st_mtime_ns for f in (1, 2)] == before


def test_a_missing_png_is_toned_from_the_exr(seq):
    """A complete frame whose PNG alone is missing is not rendered again: its PNG is written
    from its EXR with this run's exposure (so deleting a sequence's PNGs re-tones it); the
    other frames' PNGs and every EXR are left as they were."""
    from matplotlib import image as mpimg
    from volmc.film import tonemap
    d = seq.parent
    r = run(["render", str(seq), "--frames", "1-2", "-o", "s.exr", "--png", "--quiet"], d)
    assert r.returncode == 0, r.stderr
    exrs = [(d / f"s.{f:04d}.exr").read_bytes() for f in (1, 2)]
    kept = (d / "s.0002.png").read_bytes()
    (d / "s.0001.png").unlink()
    r = run(["render", str(seq), "--frames", "1-2", "-o", "s.exr", "--png", "--exposure", "2"],
            d)
    assert r.returncode == 0 and "0 rendered, 2 complete already" in r.stderr, r.stderr
    assert [(d / f"s.{f:04d}.exr").read_bytes() for f in (1, 2)] == exrs
    assert (d / "s.0002.png").read_bytes() == kept
    rgb = read_exr(d / "s.0001.exr")[0]
    want = (tonemap(rgb.astype(np.float64), 2.0, "filmic") * 255.0 + 0.5).astype(np.uint8)
    got = (mpimg.imread(d / "s.0001.png")[..., :3] * 255.0 + 0.5).astype(np.uint8)
    np.testing.assert_array_equal(got, want)
    assert want.std() > 0


def test_a_frame_that_cannot_be_written_is_rescued(seq, tmp_path, monkeypatch):
    """Found by an outside workflow test: a full disk (or a directory gone read-only)
    while a sequence wrote a frame ended in a traceback and lost the frame. Now the one-line
    error names the option and the file, the frame's image is saved in the temporary
    directory, and the frames before it stay complete."""
    import errno
    import volmc.film
    real, calls = volmc.film.write_png, []

    def write_png(path, *args, **kw):
        calls.append(path)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(path, *args, **kw)

    monkeypatch.setattr(volmc.film, "write_png", write_png)
    out = tmp_path / "o" / "f.exr"
    out.parent.mkdir()
    with pytest.raises(volmc.VolmcError) as e:
        volmc.render_frames(seq, "1-3", output=out, png=True, progress=False, backend="numba")
    text = str(e.value)
    assert text.startswith(f"volmc.render_frames(): png: could not write "
                           f"{tmp_path / 'o' / 'f.0002.png'} ([Errno 28] No space left on "
                           "device); frame 2's image is saved as "), text
    rescued = text.rsplit(" ", 1)[1]
    try:
        img, meta = read_exr(rescued, alpha=True)
    finally:
        Path(rescued).unlink()
    one = volmc.render(volmc.load_scene(seq, frame=2), progress=False, backend="numba")
    np.testing.assert_array_equal(img[..., :3], one.image.astype(np.float32))
    assert meta["frame"] == 2
    assert sorted(p.name for p in out.parent.iterdir()) == ["f.0001.exr", "f.0001.png"]
