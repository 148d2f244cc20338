"""Efficiency of every transmittance estimator over majorant segments, mapped over
(majorant optical depth, tightness): which estimator wins where (`volmc bench
transmittance`).

Every replayed ray (a recorded camera or shadow segment) is split into the majorant segments
the render's own structure gives it (``majorant_pieces``: the reference iterator of
reference/medium.py). Homogeneous pieces (sigma_min = sigma_maj) are left out: every
estimator is exact there. Each remaining piece has a majorant optical depth
tau_bar = sigma_maj (t_max - t_min), a tightness tau / tau_bar (tau exact) and a bound ratio
sigma_min / sigma_maj. The pieces are binned on a log grid of tau_bar x a linear grid of
tightness; in each bin holding at least MIN_SEGMENTS pieces, at most MAX_SEGMENTS of them
are run as cases of their own (global majorant and minorant = the piece's bounds), every
estimator in one timed launch per recording, and the bin gets each estimator's
1 / (MSE x time) and 1 / (variance x lookups) and the winner among the unbiased ones.
"""

import math

import numpy as np
from numba import njit

from ..reference.medium import (ITER_STATE_SIZE, MediumData, majorant_iter_init,
                                majorant_next, no_field_arrays)
from ..reference.optical_depth import optical_depth_exact
from ..techniques import ESTIMATORS

#: Bin edges of the majorant optical depth tau_bar (8 bins, half a decade each) ...
TAU_BAR_EDGES = np.logspace(-2.0, 2.0, 9)
#: ... and of the tightness tau / tau_bar (5 bins).
TIGHTNESS_EDGES = np.linspace(0.0, 1.0, 6)
#: Fewest pieces a bin needs to be measured, and the most it runs (a fixed-seed subsample).
MIN_SEGMENTS = 32
MAX_SEGMENTS = 512
#: Estimates per piece.
PER_SEGMENT = 64
#: Relative slack on a piece's bounds: the kernels form scale x density in float32, which can
#: land an ulp beyond the float64 bound (transmittance.profile_case does the same).
SLACK = 2.0 ** -20


@njit(cache=True)
def majorant_pieces(medium, grid, maj, mnr, nodes, rays):
    """The non-empty majorant segments of every ray [r, 9] (o, d, t0, t1, pad) through
    medium record medium[0] with its majorant structure (maj, mnr, nodes): float64 [n, 6] of
    ray index, t_min, t_max (rounded to float32, as a kernel would see them as a ray's
    bounds), sigma_maj, sigma_min (1 / world unit) and the exact optical depth over
    [t_min, t_max]."""
    emis, table, bricks, pool, _, rec = no_field_arrays()
    med = (MediumData(medium[0], grid, maj, mnr, emis, table, bricks, pool, nodes, rec),)
    m = medium[0]
    bmin = (m.bmin[0], m.bmin[1], m.bmin[2])
    bmax = (m.bmax[0], m.bmax[1], m.bmax[2])
    it = np.empty(ITER_STATE_SIZE)
    n = 0
    for r in range(rays.shape[0]):
        o = (rays[r, 0], rays[r, 1], rays[r, 2])
        d = (rays[r, 3], rays[r, 4], rays[r, 5])
        majorant_iter_init(it, med, o, d, rays[r, 6], rays[r, 7])
        while majorant_next(it, med)[0]:
            n += 1
    out = np.empty((n, 6))
    k = 0
    for r in range(rays.shape[0]):
        o = (rays[r, 0], rays[r, 1], rays[r, 2])
        d = (rays[r, 3], rays[r, 4], rays[r, 5])
        majorant_iter_init(it, med, o, d, rays[r, 6], rays[r, 7])
        while True:
            ok, ta, tb, s_maj, s_min, _ = majorant_next(it, med)
            if not ok:
                break
            ta = float(np.float32(ta))
            tb = float(np.float32(tb))
            out[k, 0] = r
            out[k, 1] = ta
            out[k, 2] = tb
            out[k, 3] = s_maj
            out[k, 4] = s_min
            out[k, 5] = optical_depth_exact(grid, bmin, bmax, m.scale, o, d, ta, tb)
            k += 1
    return out


def piece_coordinates(pieces):
    """(tau_bar, tightness, bound ratio) of pieces [n, 6] (``majorant_pieces``)."""
    tau_bar = pieces[:, 3] * (pieces[:, 2] - pieces[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        tight = np.where(tau_bar > 0, pieces[:, 5] / tau_bar, 1.0)
    return tau_bar, np.clip(tight, 0.0, 1.0), pieces[:, 4] / pieces[:, 3]


def bin_index(tau_bar, tightness, tau_edges=TAU_BAR_EDGES, tight_edges=TIGHTNESS_EDGES):
    """(i, j): the tau_bar bin and the tightness bin of each piece; i = -1 outside the
    tau_bar range. Tightness 1 falls in the last bin."""
    tau_bar = np.asarray(tau_bar, np.float64)
    i = np.searchsorted(tau_edges, tau_bar, side="right") - 1
    i[(tau_bar < tau_edges[0]) | (tau_bar >= tau_edges[-1])] = -1
    j = np.clip(np.searchsorted(tight_edges, tightness, side="right") - 1, 0,
                len(tight_edges) - 2)
    return i, j


def auto_rule():
    """(rule, {technique constant: estimator name}) of the renderer's "auto" transmittance
    rule, ``reference.tracking.auto_segment_technique(s_maj, s_min, L)``, or (None, {}) in a
    build that does not have it."""
    from .. import constants
    from ..reference import tracking
    rule = getattr(tracking, "auto_segment_technique", None)
    if rule is None:
        return None, {}
    names = {}
    for const, name in (("TRACK_LENGTH", "track_length"),
                        ("TRACK_RESIDUAL_RATIO", "residual_ratio"),
                        ("TRACK_TELESCOPING", "telescoping")):
        if hasattr(constants, const):
            names[int(getattr(constants, const))] = name
    return rule, names


def rule_choices(rule, names, pieces):
    """The estimator name the rule picks for each piece [n, 6]."""
    out = []
    for p in pieces:
        c = int(rule(float(p[3]), float(p[4]), float(p[2] - p[1])))
        out.append(names.get(c, str(c)))
    return out


def rule_regions(rule, names, length, n_tau=120, n_ratio=60):
    """The rule's choice over (tau_bar, sigma_min / sigma_maj) for pieces of length
    ``length`` (world units): (tau_bar values [n_tau], ratio values [n_ratio], names
    [n_ratio][n_tau])."""
    taus = np.logspace(math.log10(TAU_BAR_EDGES[0]), math.log10(TAU_BAR_EDGES[-1]), n_tau)
    ratios = (np.arange(n_ratio) + 0.5) / n_ratio
    grid = [[names.get(int(rule(t / length, q * t / length, length)), "?") for t in taus]
            for q in ratios]
    return taus.tolist(), ratios.tolist(), grid


def plan(names, replays, seed=41, log=print, min_segments=MIN_SEGMENTS):
    """The maps over ``replays``, a list of (Recording, rays [r, 9]) (every replayed segment
    of a scene; the launches name scene k, entry k of run_cases' shared data):
    (maps, cases). ``maps`` is the JSON-able skeleton (per bin the pieces counted and the
    subsample run); each case, a (launches, finish) pair, measures one bin with every
    estimator of ``names`` except the homogeneous-only ones, and ``finish(launches,
    results)`` puts their metrics and winners in the bin. Bins with fewer than
    ``min_segments`` pieces are not measured."""
    from .transmittance import Launch
    names = [n for n in names if not ESTIMATORS[n].homogeneous_only]
    per_scene = []
    n_all = n_homog = 0
    for k, (rec, rays) in enumerate(replays):
        p = majorant_pieces(rec.medium, np.asarray(rec.grid, np.float64),
                            np.asarray(rec.maj, np.float64), np.asarray(rec.mnr, np.float64),
                            np.asarray(rec.nodes, np.int32), rays)
        n_all += len(p)
        homog = p[:, 4] >= p[:, 3]
        n_homog += int(homog.sum())
        per_scene.append((k, p[~homog]))
    scene_of = np.concatenate([np.full(len(p), k) for k, p in per_scene])
    pieces = np.concatenate([p for _, p in per_scene])
    tau_bar, tight, ratio = piece_coordinates(pieces)
    bi, bj = bin_index(tau_bar, tight)
    rule, rule_names_ = auto_rule()
    rng = np.random.default_rng(seed)
    bins, cases = [], []
    for i in range(len(TAU_BAR_EDGES) - 1):
        for j in range(len(TIGHTNESS_EDGES) - 1):
            members = np.flatnonzero((bi == i) & (bj == j))
            row = {"tau_bar": [float(TAU_BAR_EDGES[i]), float(TAU_BAR_EDGES[i + 1])],
                   "tightness": [float(TIGHTNESS_EDGES[j]), float(TIGHTNESS_EDGES[j + 1])],
                   "i": i, "j": j, "n_segments": int(members.size), "results": {}}
            if members.size:
                row["mean_bound_ratio"] = float(ratio[members].mean())
            if rule is not None and members.size:
                choice = rule_choices(rule, rule_names_, pieces[members])
                vals, cnt = np.unique(choice, return_counts=True)
                row["auto"] = str(vals[np.argmax(cnt)])
                row["auto_share"] = float(cnt.max() / cnt.sum())
            if members.size >= min_segments:
                use = np.sort(rng.choice(members, size=min(MAX_SEGMENTS, members.size),
                                         replace=False))
                row["n_used"] = int(use.size)
                launches, truths = [], []
                for k in np.unique(scene_of[use]):
                    p = pieces[use[scene_of[use] == k]]
                    r = replays[k][1][p[:, 0].astype(np.int64)].copy()
                    r[:, 6], r[:, 7] = p[:, 1], p[:, 2]
                    bounds = np.stack([p[:, 3] * (1.0 + SLACK), p[:, 4] * (1.0 - SLACK)], 1)
                    launches += [Launch(n, int(k), None, r, bounds, PER_SEGMENT, 53)
                                 for n in names]
                    truths += [np.exp(-p[:, 5])] * len(names)
                cases.append((launches, _finish_bin(row, truths)))
            bins.append(row)
    log(f"  maps: {len(pieces)} heterogeneous majorant segments ({n_homog} homogeneous of "
        f"{n_all} left out), {len(cases)} bins to measure")
    out = {"tau_bar_edges": TAU_BAR_EDGES.tolist(), "tightness_edges": TIGHTNESS_EDGES.tolist(),
           "min_segments": min_segments, "max_segments": MAX_SEGMENTS,
           "per_segment": PER_SEGMENT, "n_pieces": int(n_all), "n_homogeneous": int(n_homog),
           "bins": bins, "auto": rule is not None}
    if rule is not None and len(pieces):   # (an empty grid has no majorant segments)
        length = float(np.median(pieces[:, 2] - pieces[:, 1]))
        taus, ratios, grid = rule_regions(rule, rule_names_, length)
        out["auto_regions"] = {"length": length, "tau_bar": taus, "bound_ratio": ratios,
                               "choice": grid}
    return out, cases


def _finish_bin(row, truths):
    """The finish step of a bin's case: per estimator, its launches (one per recording the
    bin's pieces come from) pooled, with their times summed; then the winners."""
    def finish(launches, results):
        from .transmittance import stats
        keep = ("bias_z", "variance", "mse", "lookups", "seconds_per_estimate",
                "eff_var_lookups", "eff_mse_time", "guards")
        for n in dict.fromkeys(x.name for x in launches):
            mine = [i for i, x in enumerate(launches) if x.name == n]
            r = stats(np.concatenate([results[i][0] for i in mine]),
                      np.concatenate([truths[i] for i in mine]),
                      np.concatenate([results[i][1] for i in mine]),
                      sum(results[i][2] for i in mine), PER_SEGMENT)
            row["results"][n] = {k: r[k] for k in keep}
        row.update(winners(row["results"]))
    return finish


def most_efficient(effs):
    """The name of the largest efficiency in {name: efficiency}, or None when there is no
    single one: NaN (an estimate went non-finite) is no efficiency, and an infinite one
    (variance 0: exact) wins only alone; several exact estimators tie."""
    finite = {n: e for n, e in effs.items() if not math.isnan(e)}
    if not finite:
        return None
    top = max(finite.values())
    best = [n for n, e in finite.items() if e == top]
    return best[0] if len(best) == 1 or math.isfinite(top) else None


def winners(results):
    """The most efficient unbiased fixed estimator by 1 / (variance x lookups) and by
    1 / (MSE x time). "auto" is not a contender: it runs one of the others (on a lone
    transmittance, unbiased ray marching in these grey media), and the maps are what its
    rule is judged against."""
    return {label: most_efficient({n: r[key] for n, r in results.items()
                                   if ESTIMATORS[n].unbiased and n != "auto"})
            for key, label in (("eff_var_lookups", "winner_var_lookups"),
                               ("eff_mse_time", "winner_mse_time"))}


def win_counts(maps):
    """{criterion: {estimator: bins won}} over the measured bins."""
    out = {}
    for key in ("winner_var_lookups", "winner_mse_time"):
        c = {}
        for b in maps["bins"]:
            if b.get(key):
                c[b[key]] = c.get(b[key], 0) + 1
        out[key] = c
    return out
