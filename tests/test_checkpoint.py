"""Checkpoint and resume (volmc/checkpoint.py, render(checkpoint=..., resume=...), and the
CLI's --checkpoint, --checkpoint-every and --resume): a resumed render equals an
uninterrupted one bit for bit, also after SIGKILL, and a checkpoint of another render is
refused with the one-line error and exit status 2."""

import json
import signal
import subprocess
import time

import numpy as np
import pytest

from volmc.film import read_exr
from volmc.params import sample_counts
from volmc.render import batch_schedule, render
from volmc.resources import default_scene
from volmc.scene import load_scene
from volmc.scene.errors import SceneError
from cli_subprocess import volmc_cli, volmc_env

SMALL = ["medium.density.resolution=16", "camera.resolution=[12, 10]", "render.max_depth=4"]


def _cli(args, cwd):
    return subprocess.Popen(volmc_cli(*args), cwd=cwd, env=volmc_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _header(path):
    with np.load(path) as z:
        return json.loads(str(z["header"]))


@pytest.mark.parametrize("n_pixels, spp", [(1, 1), (120, 8), (120, 1000), (70000, 5)])
def test_schedule_from_any_start_continues_the_schedule(n_pixels, spp):
    """From a batch boundary the schedule goes on with the full schedule's own batches; from
    inside a batch it finishes that batch first; either way it covers [start, spp)."""
    full = batch_schedule(n_pixels, spp)
    ends = np.cumsum(full)
    for k, start in enumerate([0] + list(ends)):
        assert batch_schedule(n_pixels, spp, start) == full[k:]
    for start in range(spp):
        rest = batch_schedule(n_pixels, spp, start)
        assert sum(rest) == spp - start and all(n > 0 for n in rest)
        cut = int(np.searchsorted(ends, start, side="right"))
        assert rest[1:] == full[cut + 1:]


@pytest.mark.parametrize("backend", ["numba", "opencl"])
def test_resumed_render_equals_uninterrupted(backend, tmp_path):
    """With one batch per chunk: a render of 3 spp checkpointed, then resumed to 8, gives
    the 8-spp render's sums bit for bit, and its counters; so does resuming a checkpoint
    that stopped inside a batch of the longer schedule (2 spp), up to summation order."""
    scene = load_scene(default_scene(), SMALL)
    full = render(scene, backend=backend, spp=8, progress=False, chunk_samples=1)
    for done in (3, 2):
        ck = tmp_path / f"ck{done}.npz"
        render(scene, backend=backend, spp=done, progress=False, checkpoint=str(ck),
               chunk_samples=1)
        assert _header(ck)["spp"] == done
        res = render(scene, backend=backend, spp=8, progress=False, resume=str(ck),
                     chunk_samples=1)
        assert res.film.spp == 8
        if done == 3:   # a batch boundary of the 8-spp schedule (1, 2, 4, 1)
            np.testing.assert_array_equal(res.film.sum, full.film.sum)
            np.testing.assert_array_equal(res.film.sum_sq, full.film.sum_sq)
            assert res.counters == full.counters
        else:
            np.testing.assert_allclose(res.film.sum, full.film.sum, rtol=1e-6, atol=1e-12)
            # The lanes' counters follow the batches, which differ here.
            assert sample_counts(res.counters) == sample_counts(full.counters)


def test_checkpoint_of_another_render_is_refused(tmp_path):
    """Another seed, sampler, backend, scene key or grid: SceneError naming the file and
    --resume; more samples than the checkpoint's are fine."""
    scene = load_scene(default_scene(), SMALL)
    ck = tmp_path / "ck.npz"
    render(scene, backend="opencl", spp=2, progress=False, checkpoint=str(ck))
    for keys, backend, word in [(["render.seed=5"], "opencl", "seed"),
                                (["render.sampler=sobol"], "opencl", "render.sampler"),
                                ([], "numba", "backend"),
                                (["medium.albedo=0.5"], "opencl", "different scene"),
                                (["medium.density.seed=8"], "opencl", "grids")]:
        other = load_scene(default_scene(), SMALL + keys)
        with pytest.raises(SceneError) as e:
            render(other, backend=backend, spp=4, progress=False, resume=str(ck))
        assert str(e.value).startswith(f"{ck}: --resume: ") and word in str(e.value), e.value
    more = load_scene(default_scene(), SMALL + ["render.spp=99"])
    assert render(more, backend="opencl", spp=3, progress=False, resume=str(ck)).film.spp == 3
    (tmp_path / "junk.npz").write_bytes(b"not a checkpoint")
    with pytest.raises(SceneError, match="not a volmc checkpoint"):
        render(scene, backend="opencl", spp=3, progress=False, resume=str(tmp_path / "junk.npz"))


def test_numpy_grid_scene_checkpoints_and_resumes(tmp_path):
    """A scene whose grid is a numpy array (Python API) checkpoints and resumes to the
    uninterrupted render bit for bit; the same scene with one voxel changed is refused
    by the grid's hash, as is another shape."""
    from volmc.scene import scene_from_dict
    rng = np.random.default_rng(3)
    grid = rng.random((6, 5, 4))

    def scene(g):
        return scene_from_dict({
            "camera": {"eye": [0.0, 0.3, 3.0], "target": [0, 0, 0], "fov": 45,
                       "resolution": [10, 8]},
            "medium": {"bounds": [[-1, -1, -1], [1, 1, 1]], "density": g, "scale": 2.0,
                       "albedo": 0.8},
            "lights": [{"type": "environment", "radiance": 0.5}], "render": {"spp": 8}})
    a = scene(grid)
    full = render(a, backend="numba", spp=8, progress=False, chunk_samples=1)
    ck = tmp_path / "ck.npz"
    render(a, backend="numba", spp=3, progress=False, checkpoint=str(ck), chunk_samples=1)
    assert "array = [6, 5, 4]" in _header(ck)["scene_toml"]
    res = render(a, backend="numba", spp=8, progress=False, resume=str(ck), chunk_samples=1)
    np.testing.assert_array_equal(res.film.sum, full.film.sum)
    # The same values in float32: the same grid as the scene holds it, so it resumes.
    res = render(scene(grid.astype(np.float32)), backend="numba", spp=8, progress=False,
                 resume=str(ck), chunk_samples=1)
    np.testing.assert_array_equal(res.film.sum, full.film.sum)
    changed = grid.copy()
    changed[2, 2, 2] += 0.25
    for other in (changed, grid[:, :, :3]):
        with pytest.raises(SceneError, match="the checkpoint's grids differ from the scene's"):
            render(scene(other), backend="numba", spp=8, progress=False, resume=str(ck))


def test_checkpoint_options_that_would_lose_work_are_refused(tmp_path):
    """--checkpoint naming an image of the render, also through a symbolic link (found by an
    outside check: a Ctrl-C then wrote the partial EXR over the saved samples), and
    --checkpoint-every without a checkpoint file (nothing would be written): one-line
    errors, exit status 2, before anything renders."""
    scene = str(default_scene())
    (tmp_path / "link.exr").symlink_to(tmp_path / "q.exr")
    for args, key, words in [
            (["--checkpoint", "q.exr"], "--checkpoint", "also an image"),
            (["--checkpoint", "link.exr"], "--checkpoint", "also an image"),
            (["--checkpoint", "q.png", "--png"], "--checkpoint", "also an image"),
            (["--checkpoint-every", "5"], "--checkpoint-every", "needs --checkpoint")]:
        p = _cli(["render", scene, "-o", "q.exr", "--quiet", *args], tmp_path)
        err = p.stderr.read()
        assert p.wait() == 2, err
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"volmc: error: command line: {key}: ")
        assert words in lines[0] and not (tmp_path / "q.exr").exists()


def test_every_medium_s_grids_are_in_the_identity(tmp_path):
    """A checkpoint of a scene whose second medium's grid then changes is refused (found by
    an outside check: only the first medium's grids were hashed, and the resume mixed two
    renders of different scenes)."""
    import volmc
    first = np.full((8, 8, 8), 1.0, np.float32)

    def two_media(second):
        return volmc.scene_from_dict({
            "camera": {"eye": [0, 0, 6], "resolution": [8, 8]},
            "media": [{"bounds": [[-2, -1, -1], [0, 1, 1]], "density": first, "scale": 2.0,
                       "albedo": 0.0},
                      {"bounds": [[0, -1, -1], [2, 1, 1]], "density": second, "scale": 2.0,
                       "albedo": 0.0}],
            "lights": [{"type": "environment", "radiance": 1.0}], "render": {"spp": 4}})
    ck = tmp_path / "ck.npz"
    volmc.render(two_media(first), spp=2, progress=False, checkpoint=str(ck))
    with pytest.raises(volmc.VolmcError, match="grids differ"):
        volmc.render(two_media(first * 5.0), spp=4, progress=False, resume=str(ck))
    assert volmc.render(two_media(first.copy()), spp=4, progress=False,
                        resume=str(ck)).spp == 4


def test_sigkill_after_a_checkpoint_then_resume(tmp_path):
    """volmc render --checkpoint killed by SIGKILL after its first checkpoints, then
    --resume: the EXR equals an uninterrupted render's bit for bit. Resuming with another
    seed or scene key fails with one line and exit status 2, before rendering."""
    scene = str(default_scene())
    common = [scene, "-D", "medium.density.resolution=32", "-D", "camera.resolution=[48, 40]",
              "--spp", "2000", "--quiet"]
    ck = tmp_path / "ck.npz"
    p = _cli(["render", *common, "-o", "killed.exr", "--checkpoint", str(ck),
              "--checkpoint-every", "0"], tmp_path)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 300:
        if ck.exists() and _header(ck)["spp"] >= 64:
            break
        assert p.poll() is None, p.stderr.read()
        time.sleep(0.02)
    p.send_signal(signal.SIGKILL)
    p.wait()
    done = _header(ck)["spp"]
    assert 64 <= done < 2000, done   # killed mid-render, after some checkpoints
    assert not (tmp_path / "killed.exr").exists()
    r = _cli(["render", *common, "-o", "resumed.exr", "--resume", str(ck)], tmp_path)
    assert r.wait() == 0, r.stderr.read()
    u = _cli(["render", *common, "-o", "whole.exr"], tmp_path)
    assert u.wait() == 0, u.stderr.read()
    a, meta = read_exr(tmp_path / "resumed.exr")
    b, _ = read_exr(tmp_path / "whole.exr")
    assert meta["spp"] == 2000
    np.testing.assert_array_equal(a, b)
    for extra, word in [(["--seed", "3"], "seed"), (["-D", "medium.albedo=0.5"], "scene")]:
        bad = _cli(["render", *common, *extra, "-o", "bad.exr", "--resume", str(ck)], tmp_path)
        err = bad.stderr.read()
        assert bad.wait() == 2
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"volmc: error: {ck}: --resume: ")
        assert word in lines[0] and "Traceback" not in err
        assert not (tmp_path / "bad.exr").exists()



def test_damaged_checkpoints_are_one_line_errors(tmp_path):
    """A checkpoint truncated, replaced by an .npy, a directory, or edited (its spp, seconds,
    sums or counters): SceneError naming the file and --resume, never another exception,
    and never a film built from impossible numbers."""
    from volmc import checkpoint as ckpt
    from volmc.cl.lanes import resolve_lanes
    scene = load_scene(default_scene(), SMALL)
    good = tmp_path / "ck.npz"
    render(scene, backend="opencl", spp=2, progress=False, checkpoint=str(good))
    lanes = resolve_lanes(None, None)
    with np.load(good) as z:
        parts = {k: z[k] for k in z.files}
    header = json.loads(str(parts["header"]))

    def edited(name, head=None, **arrays):
        p = tmp_path / name
        np.savez(p, **{**parts, "header": np.array(json.dumps({**header, **(head or {})})),
                       **arrays})
        return p
    cut = tmp_path / "cut.npz"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    npy = tmp_path / "arr.npz"
    with open(npy, "wb") as f:
        np.save(f, np.zeros(3))
    folder = tmp_path / "dir.npz"
    folder.mkdir()
    bad = [cut, npy, folder,
           edited("neg.npz", {"spp": -4}), edited("float.npz", {"spp": 2.5}),
           edited("secs.npz", {"seconds": "x"}), edited("inf.npz", {"seconds": 1e400}),
           edited("nan.npz", sum=parts["sum"] * np.nan),
           edited("negsq.npz", sum_sq=-parts["sum_sq"] - 1.0),
           edited("cnt.npz", counters=-parts["counters"] - 1)]
    # Edits that leave every value plausible: only the digest tells.
    plausible = [edited("spp.npz", {"spp": 1}), edited("secs2.npz", {"seconds": 0.5}),
                 edited("sum.npz", sum=parts["sum"] * 0.5),
                 edited("cnt2.npz", counters=parts["counters"] + 1)]
    for p in bad + plausible:
        with pytest.raises(SceneError) as e:
            ckpt.load(str(p), scene, "opencl", lanes)
        assert str(e.value).startswith(f"{p}: --resume: "), (p, e.value)
        assert p not in plausible or "edited or damaged" in str(e.value), (p, e.value)
    assert ckpt.load(str(good), scene, "opencl", lanes)[0].spp == 2


def test_a_checkpoint_that_cannot_be_written_does_not_end_the_render(tmp_path, monkeypatch):
    """A full disk (or a directory gone read-only) under the checkpoint: the render goes on,
    returns its image, and says once that it has no checkpoint; the API warns. A last
    checkpoint that succeeds after failed ones leaves nothing to say."""
    import errno
    import volmc
    from volmc import checkpoint as ckpt
    from volmc.scene.errors import VolmcWarning
    scene = load_scene(default_scene(), SMALL + ["render.spp=8"])
    clean = render(scene, backend="numba", progress=False)
    real_save, calls, full = ckpt.save, [], {"below": 99}

    def save(path, film, *args):   # the disk is full until the render holds `below` spp
        calls.append(film.spp)
        if film.spp < full["below"]:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_save(path, film, *args)

    monkeypatch.setattr(ckpt, "save", save)
    path = tmp_path / "c.npz"
    kw = dict(backend="numba", progress=False, checkpoint=path, checkpoint_every=0.0,
              chunk_samples=12 * 10 * 2)
    res = render(scene, **kw)
    assert len(calls) >= 4 and not path.exists()
    assert np.array_equal(res.film.sum, clean.film.sum) and not res.partial
    assert res.guard_warnings() == [f"{path}: the checkpoint could not be written (No space "
                                    "left on device); the render went on without it"]
    with pytest.warns(VolmcWarning, match="the checkpoint could not be written"):
        volmc.render(scene, backend="numba", checkpoint=path)
    full["below"] = 8
    res = render(scene, **kw)
    assert res.guard_warnings() == [] and path.exists()
    assert ckpt.load(path, scene, "numba")[0].spp == 8


def test_a_checkpoint_is_not_overwritten_by_a_fresh_render(tmp_path):
    """Found by an outside workflow test: the same --checkpoint command run again (not
    --resume) replaced a checkpoint of 3775 spp with a fresh one. Now it is refused; the
    checkpoint goes on with --resume, and a file that is no checkpoint is overwritten as -o
    would."""
    import volmc
    scene = load_scene(default_scene(), SMALL + ["render.spp=4"])
    path = tmp_path / "c.npz"
    volmc.render(scene, backend="numba", checkpoint=path)
    before = path.read_bytes()
    with pytest.raises(volmc.VolmcError) as e:
        volmc.render(scene, backend="numba", checkpoint=path)
    assert str(e.value) == (f"volmc.render(): checkpoint: {path} holds a checkpoint of 4 spp: "
                            f"continue it with resume={path}, or delete it to start again")
    assert path.read_bytes() == before
    volmc.render(scene, backend="numba", spp=6, resume=path)      # goes on in the same file
    assert _header(path)["spp"] == 6
    tiny = tmp_path / "s.toml"
    from volmc.scene.serialize import to_toml
    tiny.write_text(to_toml(scene.spec))
    args = ["render", str(tiny), "--backend", "numba", "-o", "x.exr", "--quiet",
            "--checkpoint", "c.npz"]
    r = _cli(args, tmp_path)
    _, err = r.communicate(timeout=300)
    assert r.returncode == 2 and err.strip() == (
        "volmc: error: command line: --checkpoint: c.npz holds a checkpoint of 6 spp: "
        "continue it with --resume c.npz, or delete it to start again"), err
    (tmp_path / "other.npz").write_bytes(b"not a checkpoint")
    r = _cli(args[:-1] + ["other.npz"], tmp_path)
    _, err = r.communicate(timeout=300)
    assert r.returncode == 0 and _header(tmp_path / "other.npz")["spp"] == 4, err
