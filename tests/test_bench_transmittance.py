"""The estimator benchmark's maps (volmc/bench/segment_maps.py): majorant segments of a
replayed ray land in the bin their majorant optical depth and tightness say, and the auto
rule's choices are read per segment when the reference has the rule."""

import math

import numpy as np

from volmc.bench import segment_maps as sm
from volmc.constants import MAJORANT_GRID, TRACK_LENGTH, TRACK_RESIDUAL_RATIO
from volmc.reference import medium as X


def _two_voxel_ray(a, b, scale):
    """A 2x1x1 grid (densities a, b along x) in the unit box under a 1x1x1 majorant grid, and
    the ray along x through it: the clamped trilinear density is a, then linear from a to b,
    then b, so tau = scale (a + b) / 2 exactly, sigma_maj = scale b, sigma_min = scale a."""
    m = X.make_grid_medium((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), scale, (2, 1, 1)).reshape(1)
    m["majorant_kind"] = MAJORANT_GRID
    m["maj_res"] = (1, 1, 1)
    grid = np.array([[[a, b]]], np.float64)
    ray = np.array([[0.0, 0.5, 0.5, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]])
    return m, grid, np.full((1, 1, 1), max(a, b)), np.full((1, 1, 1), min(a, b)), ray


def test_a_constructed_segment_lands_in_its_bin():
    a, b, scale = 0.3, 1.0, 5.0
    m, grid, maj, mnr, ray = _two_voxel_ray(a, b, scale)
    pieces = sm.majorant_pieces(m, grid, maj, mnr, np.zeros(1, np.int32), ray)
    assert pieces.shape == (1, 6)
    assert math.isclose(pieces[0, 5], scale * (a + b) / 2, rel_tol=1e-12)
    tau_bar, tight, ratio = sm.piece_coordinates(pieces)
    assert math.isclose(tau_bar[0], scale * b) and math.isclose(ratio[0], a / b)
    assert math.isclose(tight[0], (a + b) / (2 * b), rel_tol=1e-12)
    i, j = sm.bin_index(tau_bar, tight)
    # tau_bar = 5 in [10^0.5, 10^1), tightness 0.65 in [0.6, 0.8).
    assert sm.TAU_BAR_EDGES[i[0]] <= 5.0 < sm.TAU_BAR_EDGES[i[0] + 1] and (i[0], j[0]) == (5, 3)
    # The edges: outside the tau_bar range is -1; tightness 1 is the last bin.
    i, j = sm.bin_index(np.array([1e-3, 1e3, 0.5]), np.array([0.0, 0.5, 1.0]))
    assert list(i[:2]) == [-1, -1] and j[2] == len(sm.TIGHTNESS_EDGES) - 2


def test_auto_rule_annotation_reads_the_rule(monkeypatch):
    """With a rule in the reference, each segment gets the rule's estimator; the regions grid
    spans (tau_bar, bound ratio)."""
    from volmc.reference import tracking

    def rule(s_maj, s_min, L):
        return TRACK_LENGTH if s_maj * L > 1.0 else TRACK_RESIDUAL_RATIO
    monkeypatch.setattr(tracking, "auto_segment_technique", rule, raising=False)
    got, names = sm.auto_rule()
    assert got is rule and names[TRACK_LENGTH] == "track_length"
    pieces = np.array([[0, 0.0, 1.0, 5.0, 1.0, 2.0], [0, 0.0, 0.1, 5.0, 1.0, 0.2]])
    assert sm.rule_choices(got, names, pieces) == ["track_length", "residual_ratio"]
    taus, ratios, grid = sm.rule_regions(got, names, 0.5, n_tau=8, n_ratio=3)
    assert len(grid) == 3 and len(grid[0]) == 8
    assert all(row[k] == ("track_length" if taus[k] > 1 else "residual_ratio")
               for row in grid for k in range(8))


def test_maps_figures_with_the_auto_rule(tmp_path):
    """The winner map draws the rule's per-bin choice and its regions panel, and the
    per-estimator maps draw every estimator, from a report as measure() writes it."""
    from volmc.bench import plots
    names = {TRACK_LENGTH: "track_length", TRACK_RESIDUAL_RATIO: "residual_ratio"}

    def rule(s_maj, s_min, L):
        return TRACK_LENGTH if s_maj * L > 1.0 else TRACK_RESIDUAL_RATIO
    taus, ratios, grid = sm.rule_regions(rule, names, 0.1, n_tau=16, n_ratio=4)
    res = {"ratio": {"eff_mse_time": 1.0, "eff_var_lookups": 2.0},
           "power_series": {"eff_mse_time": 3.0, "eff_var_lookups": 1.0}}
    bins = [{"i": i, "j": j, "n_segments": 40, "results": dict(res), "auto": "track_length",
             **sm.winners(res)} for i in (2, 5) for j in (0, 4)]
    assert bins[0]["winner_var_lookups"] == "ratio"
    assert bins[0]["winner_mse_time"] == "power_series"
    report = {"estimators": list(res), "unbiased": {n: True for n in res},
              "maps": {"tau_bar_edges": sm.TAU_BAR_EDGES.tolist(),
                       "tightness_edges": sm.TIGHTNESS_EDGES.tolist(), "bins": bins,
                       "auto": True, "auto_regions": {"length": 0.1, "tau_bar": taus,
                                                      "bound_ratio": ratios,
                                                      "choice": grid}}}
    plots.winner_map(report, tmp_path / "w.png")
    plots.segment_maps(report, tmp_path / "m.png")
    assert (tmp_path / "w.png").stat().st_size > 1000
    assert (tmp_path / "m.png").stat().st_size > 1000


# ---- what the benchmarks report (found by an outside check of their arithmetic) ----------

def test_efficiency_is_no_measure_without_lookups_or_with_nan():
    """Track length on a homogeneous segment is Bernoulli(T) at no lookup: 1 / (V x L) was
    inf and made it the "winner" of every tight constant profile; a NaN variance (non-finite
    estimates) was inf too. Exact estimators (variance 0) stay infinitely efficient."""
    from volmc.bench.transmittance import efficiency
    assert math.isnan(efficiency(0.0862, 0.0))
    assert math.isnan(efficiency(math.nan, 5.0)) and math.isnan(efficiency(1.0, math.nan))
    assert efficiency(0.0, 0.0) == efficiency(0.0, 3.0) == math.inf
    assert efficiency(2.0, 4.0) == 0.125


def test_the_most_efficient_is_single_and_measured():
    assert sm.most_efficient({"a": math.inf, "b": math.inf, "c": 3.0}) is None   # exact tie
    assert sm.most_efficient({"a": math.inf, "b": 3.0}) == "a"
    assert sm.most_efficient({"a": math.nan, "b": 2.0, "c": 1.0}) == "b"
    assert sm.most_efficient({"a": math.nan}) is None and sm.most_efficient({}) is None


def test_profile_sweep_counts_exact_ties_apart():
    from volmc.bench.transmittance import summarise
    from volmc.techniques import ESTIMATORS
    names = ["track_length", "residual_ratio", "ratio"]

    def row(**eff):
        return {"results": {n: {"eff_var_lookups": e} for n, e in eff.items()}}
    report = {"estimators": names, "unbiased": {n: ESTIMATORS[n].unbiased for n in names},
              "profiles": [row(track_length=math.nan, residual_ratio=math.inf, ratio=math.inf),
                           row(track_length=2.0, residual_ratio=5.0, ratio=math.nan),
                           row(track_length=math.nan, residual_ratio=math.inf, ratio=1.0)]}
    summary, ties = summarise(report)
    assert ties == 1
    assert {n: s["wins"] for n, s in summary.items()} == {"track_length": 0,
                                                          "residual_ratio": 2, "ratio": 0}
    assert summary["track_length"]["geomean_eff_var_lookups"] == 2.0


def test_render_benchmark_best_is_a_measured_row(capsys):
    from volmc.bench.convergence import best_volmc, print_report
    rows = [{"name": n, "backend": "opencl", "majorant": "grid", "free_flight": "delta",
             "transmittance": t, "mse_seconds": m, "samples_per_second": 1.0, "points": []}
            for n, t, m in (("a", "ratio", math.nan), ("b", "residual_ratio", 2e-6),
                            ("c", "track_length", 1e-6))]
    assert best_volmc(rows)["name"] == "c"
    assert best_volmc(rows[:1]) is None
    for r in rows:
        r["time_to_equal_error_vs_best_volmc"] = r["mse_seconds"] / 1e-6
    print_report({"resolution": [1, 1], "spp_levels": [16], "repeats": 1,
                  "reference_spp": 64, "lookup_ceiling": {}, "results": rows,
                  "best_volmc": "c"})
    lines = capsys.readouterr().out.splitlines()
    body = [ln.split()[0] for ln in lines if ln.startswith("  ") and ln.split()[0] in "abc"]
    assert body == ["c", "b", "a"]                      # measured rows first, NaN last
    assert "(RMSE 0)" in [ln for ln in lines if ln.split()[:1] == ["a"]][0]
