"""robustness case 19: a majorant that is too small (the density changed after the majorant was
built) is detected, never a silent bias.

volmc builds every majorant from the grid when a backend is created, so a scene file cannot
produce a wrong one; the ways it can happen are programmatic: a grid edited in place after the
backend was built, or bounds built by other code. Every lookup above its bound is counted
(``over_majorant``) in every estimator and free-flight loop of both backends, and the count is
reported: RenderResult.stats(), the EXR metadata (``volmc:count.over_majorant``), the
``volmc render --stats`` table, and a warning line on stderr even without --stats (guard
"reported counters", volmc/cli/render.py).
"""

import numpy as np
import pytest

from volmc import cli
from volmc.film import read_exr, write_exr
from volmc.render import make_backend, render
from volmc.scene import scene_from_dict



def _raw(grid_path, majorant):
    return {"camera": {"eye": [0.2, 0.1, 4.0], "target": [0, 0, 0], "fov": 40,
                       "resolution": [8, 8]},
            "medium": {"bounds": [[-1, -1, -1], [1, 1, 1]], "scale": 3.0, "albedo": 0.6,
                       "density": {"file": str(grid_path)}},
            "lights": [{"type": "environment", "radiance": 0.5},
                       {"type": "directional", "direction": [1, -1, -1], "irradiance": 1.0}],
            "render": {"spp": 16, "majorant": majorant, "transmittance": "ratio"}}


def _edit_grid_in_place(be, factor):
    """Scale the density a built backend renders, leaving its majorants as they were."""
    if be.name == "numba":
        be.packed.grid[...] *= factor
    else:
        g = np.empty(be.grid_buf.size // 4, np.float32)
        be.clc.read(g, be.grid_buf)
        be.clc.cl.enqueue_copy(be.clc.queue, be.grid_buf, g * np.float32(factor))
        be.clc.queue.finish()


@pytest.mark.parametrize("majorant", ["global", "grid"])
def test_case19_density_edited_after_the_majorant_is_reported(backend, majorant, tmp_path):
    """robustness case 19, both backends, global and grid majorants: the same scene renders with
    over_majorant == 0; with the grid scaled by 3 in place after the backend (and so the
    majorant) was built, over_majorant > 0 and the count appears in stats() and, written and
    read back, in the EXR metadata."""
    rng = np.random.default_rng(19)
    np.save(tmp_path / "g.npy", (0.2 + rng.random((6, 6, 6))).astype(np.float32))
    scene = scene_from_dict(_raw(tmp_path / "g.npy", majorant))
    ok = render(scene, backend=backend, progress=False)
    assert ok.counters["over_majorant"] == 0 and ok.counters["lookups"] > 0
    be = make_backend(backend, scene)
    _edit_grid_in_place(be, 3.0)
    res = render(scene, backend=be, progress=False)
    n = res.counters["over_majorant"]
    assert n > 0
    assert res.stats()["lookups_over_majorant"] == n
    write_exr(tmp_path / "out.exr", res.image, res.metadata())
    _, meta = read_exr(tmp_path / "out.exr")
    assert int(meta["count.over_majorant"]) == n


def test_case19_cli_reports_over_majorant(backend, tmp_path, monkeypatch, capsys):
    """robustness case 19 through the command line: with majorant cells built too small (half the
    true bound, patched into volmc.pack.pack_majorant, which both backends use), ``volmc render --stats`` prints a
    positive lookups_over_majorant, warns on stderr, and the EXR carries the count; the same
    render with correct majorants prints 0 and no warning."""
    import volmc.pack
    from volmc.pack import pack_majorant
    from volmc.scene.serialize import to_toml

    rng = np.random.default_rng(191)
    np.save(tmp_path / "g.npy", (0.2 + rng.random((6, 6, 6))).astype(np.float32))
    scene = scene_from_dict(_raw(tmp_path / "g.npy", "grid"))
    path = tmp_path / "s.toml"
    path.write_text(to_toml(scene.spec))

    def run(name):
        out = tmp_path / f"{name}.exr"
        code = cli.main(["render", str(path), "--backend", backend, "--stats", "--quiet",
                         "-o", str(out)])
        assert code == 0
        cap = capsys.readouterr()
        line = [ln for ln in cap.out.splitlines() if "lookups_over_majorant" in ln]
        assert len(line) == 1, cap.out
        return int(line[0].split()[-1]), cap.err, read_exr(out)[1]

    count, err, meta = run("good")
    assert count == 0 and "majorant" not in err and int(meta["count.over_majorant"]) == 0

    def too_small(scene, real=np.float64, grid=None):
        mx, mn = pack_majorant(scene, real, grid)
        return mx * real(0.5), mn * real(0.5)
    monkeypatch.setattr(volmc.pack, "pack_majorant", too_small)
    count, err, meta = run("bad")
    assert count > 0
    assert f"volmc: warning: {count} density lookups exceeded the majorant" in err
    assert int(meta["count.over_majorant"]) == count
