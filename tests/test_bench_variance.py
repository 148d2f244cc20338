"""`volmc bench variance`: the switch table, the efficiency arithmetic, the slope fit and the
command line end to end on a tiny scene."""

import json
import math

import pytest

from volmc import cli
from volmc.bench import variance
from volmc.bench.variance import PLAIN, Switch
from volmc.resources import scenes_dir
from volmc.scene import load_scene
from volmc.scene.schema import Render

from test_cli import run

SINGLE = str(scenes_dir() / "tests" / "single_scatter.toml")
# 8x8 and an environment light in place of the sun, so that mis=power applies.
TINY_DEFINES = ["-D", "camera.resolution=[8,8]",
                "-D", 'lights.0={type="environment", radiance=0.5}']

#: Stand-ins while the new render keys do not exist: "stratified" switches the shadow-ray
#: estimator (a key the renderer has), "sobol" a key it will never have.
STAND_IN = (
    variance.SWITCHES[0],
    Switch("stratified", {"transmittance": "track_length"}, variance.always),
    Switch("sobol", {"no_such_key": 1}, variance.always),
    Switch("mis=power", {"mis": "power"}, variance.has_sampled_light),
)


def test_slope_fit_on_synthetic_rmse():
    n = [1, 4, 16, 64, 256]
    assert variance.loglog_slope(n, [3.0 * x ** -0.5 for x in n]) == pytest.approx(-0.5)
    assert variance.loglog_slope(n, [0.2 / x for x in n]) == pytest.approx(-1.0)
    # RMSE 0 (below the reference's noise) is left out; one level left: no slope.
    assert variance.loglog_slope([1, 4, 4], [0.1, 0.0, 0.0]) is None


def _report(rows):
    """A scene report of 10x10 pixels, levels 4 and 16, from {label: (rmse at 4, rmse at
    16, seconds per sample per pixel)}: two repetitions with equal figures."""
    results = []
    for label, (e4, e16, sec) in rows.items():
        pts = [{"spp": n, "seed": s, "rmse": e, "seconds": sec * n,
                "counters": {"lookups": 100 * n, "capped": 0, "dropped": 0,
                             "over_majorant": 0}}
               for s in (1, 2) for n, e in ((4, e4), (16, e16))]
        results.append({"label": label, "render": {}, "points": pts})
    return {"scene": "s.toml", "resolution": [10, 10], "spp_levels": [4, 16],
            "results": results}


@pytest.mark.parametrize("n_items,levels", [(2, 2), (2, 3), (3, 3), (3, 2), (4, 2)])
def test_turn_order_gives_every_level_every_order(n_items, levels):
    # Over n repetitions of n configurations, each spp level renders each configuration
    # once in each place (the old turn per level alone gave a 2-level, 2-configuration
    # ladder the same order at a level in every repetition).
    from volmc.bench.convergence import turn_order
    items = list("abcd"[:n_items])
    for level in range(levels):
        orders = [turn_order(items, rep, level) for rep in range(n_items)]
        for place in range(n_items):
            assert sorted(o[place] for o in orders) == items
        assert all(sorted(o) == items for o in orders)


def test_efficiency_arithmetic():
    # The switch halves the RMSE at the top level (MSE x 1/4) at twice the time per
    # sample: MSE x s is half the plain one, so it is 2x as efficient.
    rep = variance.summarise(_report({PLAIN: (0.2, 0.1, 0.5), "x": (0.1, 0.05, 1.0)}))
    plain, x = rep["results"]
    assert plain["relative_efficiency"] == pytest.approx(1.0)
    assert plain["mse_seconds"] == pytest.approx(0.1 ** 2 * 8.0)   # upper half: 16 spp only
    assert x["relative_efficiency"] == pytest.approx(2.0)
    assert x["mse_ratio_at_top_spp"] == pytest.approx(0.25)
    assert x["samples_per_second_ratio"] == pytest.approx(0.5)
    assert plain["samples_per_second"] == pytest.approx(100 / 0.5)
    assert plain["lookups_per_sample"] == pytest.approx(1.0)
    assert plain["slope"] == pytest.approx(-0.5) and x["slope"] == pytest.approx(-0.5)
    # A configuration whose every error is below the reference noise has no MSE x s.
    rep = variance.summarise(_report({PLAIN: (0.2, 0.1, 0.5), "x": (0.0, 0.0, 1.0)}))
    assert rep["results"][1]["relative_efficiency"] is None
    assert variance.combined([rep], ["x", "y"]) == {"x": {"s.toml": None},
                                                             "y": {"s.toml": None}}


def test_configurations_plain_keys_and_skips():
    scene = load_scene(SINGLE)   # a sun only, max_depth 1
    configs, skipped = variance.configurations(scene, variance.switch_labels())
    # Plain sets only the keys this Render has; the rest of its row is left out.
    assert configs[0] == (PLAIN, _plain(scene)) and configs[0][1]["mis"] == "balance"
    assert "an environment" in skipped["mis=power"]   # no sky in this scene
    configs, skipped = variance.configurations(scene, ["stratified", "sobol"], STAND_IN)
    plain = _plain(scene)
    assert configs == [(PLAIN, plain),
                       ("stratified", {**plain, "transmittance": "track_length"})]
    assert skipped == {"sobol": "needs render.no_such_key, which this volmc does not have"}
    assert not variance.has_point_light(scene) and not variance.roulette_happens(scene)


def _plain(scene):
    """The plain row's keys that the scene's Render has (mis at least)."""
    keys = variance.render_keys(scene)
    return {k: v for k, v in variance.SWITCHES[0].overrides.items() if k in keys}


def test_default_scenes_ship_and_thin_scene_is_single_scattering():
    paths = variance.default_scene_paths()
    assert [p.name for p in paths] == ["cloud.toml", "thin.toml", "haze.toml", "fog.toml"]
    assert all(p.is_file() for p in paths)
    thin = load_scene(paths[1])
    assert thin.render.max_depth == 1 and thin.grid is not None
    assert {lt.type for lt in thin.lights} == {"directional", "point"}
    assert thin.camera.resolution == (96, 96)
    # the samplers' best case: homogeneous, single scattering, one directional light (its
    # next-event estimate draws no random number)
    haze = load_scene(paths[2])
    assert haze.render.max_depth == 1 and haze.grid is None
    assert {lt.type for lt in haze.lights} == {"directional"}


def test_cli_end_to_end(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(variance, "SWITCHES", STAND_IN)
    builds = []
    make = variance.make_backend

    def recording(name, scene, device=None):
        builds.append(scene.render)
        return make(name, scene, device)
    monkeypatch.setattr(variance, "make_backend", recording)
    out, png = tmp_path / "v.json", tmp_path / "v.png"
    status = cli.main(["bench", "variance", SINGLE, *TINY_DEFINES, "--switches",
                       "mis=power,stratified,sobol", "--spp-levels", "1,2",
                       "--reference-spp", "16", "--repeats", "1", "--json", str(out),
                       "--plot", str(png)])
    text = capsys.readouterr().out
    assert status == 0
    assert "rel. eff." in text and "relative efficiency against plain" in text
    assert "sobol            skipped: needs render.no_such_key" in text
    report = json.loads(out.read_text())
    assert report["benchmark"] == "variance"
    assert report["switches"] == ["mis=power", "stratified", "sobol"]
    (scene,) = report["scenes"]
    assert scene["resolution"] == [8, 8] and scene["spp_levels"] == [1, 2]
    assert scene["skipped"] == {"sobol": "needs render.no_such_key, which this volmc does "
                                         "not have"}
    rows = {r["label"]: r for r in scene["results"]}
    assert list(rows) == [PLAIN, "mis=power", "stratified"]
    plain = _plain(load_scene(SINGLE))
    assert rows[PLAIN]["render"] == plain
    assert rows["mis=power"]["render"] == {**plain, "mis": "power"}
    for r in rows.values():
        assert [p["spp"] for p in r["points"]] == [1, 2]
        assert all(p["seed"] == 17 and p["rmse"] > 0 and p["seconds"] > 0
                   and "lookups" in p["counters"] for p in r["points"])
        for key in ("relative_efficiency", "mse_ratio_at_top_spp", "samples_per_second_ratio",
                    "mse_seconds", "slope", "guards"):
            assert key in r
        assert math.isfinite(r["slope"])
    assert rows[PLAIN]["relative_efficiency"] == 1.0
    assert report["combined"] == {
        "mis=power": {"single_scatter.toml": rows["mis=power"]["relative_efficiency"]},
        "stratified": {"single_scatter.toml": rows["stratified"]["relative_efficiency"]},
        "sobol": {"single_scatter.toml": None}}
    # Every timed render was built with render.spp = its total and the repetition's seed
    # (the reference, with the plain keys and its own seed, is built outside variance).
    timed = [(b.spp, b.seed, b.mis, b.transmittance) for b in builds]
    default = Render().transmittance       # the scene names none
    assert sorted(timed) == sorted((n, 17, mis, est) for n in (1, 2) for mis, est in (
        ("balance", default), ("power", default), ("balance", "track_length")))
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("args,flag", [
    (["--switches", "mis=power,nope"], "--switches"),
    (["--switches", "plain"], "--switches"),
    (["--spp-levels", "4,x"], "--spp-levels"),
    (["--repeats", "0"], "--repeats"),
    (["--backend", "gpu"], "--backend"),
    (["--json", "/nonexistent/dir/v.json"], "--json"),
])
def test_bad_values_exit_2_with_one_line(tmp_path, args, flag):
    r = run(["bench", "variance", SINGLE, *args], tmp_path)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("volmc: error: ") and flag in lines[0]
