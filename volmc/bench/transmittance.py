"""`volmc bench transmittance`: every estimator on analytic profiles and on the segments a
real render traces, speed against error, and maps of which estimator wins where.

Cases:
* 1-D profiles (constant, linear ramp, Gaussian bump, Gaussian hole, cosine) on [0, 1], scaled
  to a target transmittance T (0.01 ... 0.99) and given a majorant at a target tightness
  (mean extinction / majorant, 0.05 ... 1; capped at the profile's own mean / max). The
  control mu_c is the profile's minimum. Truth: the closed-form optical depth.
* Recorded segments of grid scenes (segments.py): a small render of each scene records the
  camera segments and the shadow segments it hands to its transmittance estimator, and a
  fixed-seed subset of each kind is replayed with every estimator on the scene's own
  majorant structure (the majorant grid by default), as the render has it. Truth: the exact
  optical depth (piecewise Gauss-Legendre, float64) along each float32 segment, in the
  packed frame. A chromatic scene is measured on its largest channel (the grey runner).
* Maps (segment_maps.py): the replayed segments split into their majorant segments, binned
  over (majorant optical depth, tightness), every estimator run on each bin's pieces.

Statistics come from the OpenCL backend (the production path) and times are OpenCL wall
times per estimate. Per estimator and case: mean, standard error, bias z-score against the
truth, variance, mean lookups, time per estimate, efficiency 1 / (variance x lookups) and
1 / (MSE x time), and the variance at an equal budget of BUDGET lookups (equal cost) beside
the per-estimate variance (equal samples).
"""

import json
import math
import time

import numpy as np
from numba import njit

from ..constants import (DENSITY_CONSTANT, DENSITY_COSINE, DENSITY_GAUSS_BUMP,
                         DENSITY_GAUSS_HOLE, DENSITY_RAMP)
from ..reference import medium as X
from ..techniques import ESTIMATORS
from ..reference.optical_depth import optical_depth_exact
from . import segment_maps
from .segments import majorant_name, record_segments, with_resolution
from .transmittance_runner import OpenCLEstimator

#: The recorded render of each grid scene: resolution (--quick: the smaller one), samples
#: per pixel and segments kept per pixel (the first ones of the pixel's paths).
RECORD_RESOLUTION = (64, 64)
QUICK_RESOLUTION = (16, 16)
RECORD_SPP = 1
RECORD_PER_PIXEL = 16

TARGET_T = (0.01, 0.1, 0.3, 0.6, 0.9, 0.99)
TIGHTNESS = (0.05, 0.1, 0.25, 0.5, 0.75, 1.0)
#: Identical timed launches per case; the fastest counts.
TIME_REPEATS = 3
#: Lookup budget of the equal-cost variance column.
BUDGET = 100.0

#: Unit-optical-depth shapes of the 1-D profiles on [0, 1]: (kind, a, b, c, s); a and b scale
#: with the target optical depth except the cosine's relative amplitude b.
SHAPES = {
    "constant": (DENSITY_CONSTANT, 1.0, 0.0, 0.0, 1.0),
    "ramp": (DENSITY_RAMP, 0.1, 1.9, 0.0, 1.0),
    "bump": (DENSITY_GAUSS_BUMP, 0.1, 3.0, 0.5, 0.08),
    "hole": (DENSITY_GAUSS_HOLE, 1.0, 0.95, 0.5, 0.15),
    "cosine": (DENSITY_COSINE, 1.0, 0.9, 3.0, 0.4),
}


def profile_case(shape, target_T, tightness):
    """(med, mbar, mu_c, exact T, effective tightness) for one sweep point."""
    kind, a, b, c, s = SHAPES[shape]
    base = X.make_profile(kind, a, b, c, s, 1.0)
    k = -math.log(target_T) / X.optical_depth_profile(base, 0.0, 1.0)
    med = X.make_profile(kind, a * k, b if kind == DENSITY_COSINE else b * k, c, s, 1.0)
    lo, hi, mean = X.profile_bounds(med, 0.0, 1.0)
    # The maximum is exact in float64; the OpenCL kernels evaluate the profile in float32,
    # which can land a few ulps above it (the cosine's peak did, and over_majorant counted
    # it). 2^-20 of relative slack keeps it a true majorant in either precision. The minorant
    # (the estimators' control) is the profile's true minimum.
    mbar = max(mean / tightness, hi * (1.0 + 2.0 ** -20))
    exact = math.exp(-X.optical_depth_profile(med, 0.0, 1.0))
    return med, mbar, lo, exact, mean / mbar


def replay_cases(rec, n, seed=3):
    """Random subsets (fixed ``seed``) of at most ``n`` camera and ``n`` shadow segments of a
    ``segments.Recording``: [(label, rays [k, 9] rounded to float32 as the kernels see them,
    exact transmittance [k] along exactly those rays, in the packed frame)]."""
    rng = np.random.default_rng(seed)
    out = []
    for label, segs in (("camera segments", rec.camera), ("shadow segments", rec.shadow)):
        idx = np.sort(rng.choice(len(segs), size=min(n, len(segs)), replace=False))
        rays = segs[idx].astype(np.float32).astype(np.float64)
        out.append((label, rays, np.exp(-optical_depths(rec, rays))))
    return out


def optical_depths(rec, rays):
    """Exact optical depth along each ray [k, 9] over its [t0, t1] through the recording's
    grid (packed frame and extinction scale)."""
    m = rec.medium[0]
    return _optical_depths(np.asarray(rec.grid, np.float64), tuple(m["bmin"]),
                           tuple(m["bmax"]), float(m["scale"]), rays)


@njit(cache=True)
def _optical_depths(grid, bmin, bmax, scale, rays):
    out = np.empty(rays.shape[0])
    for i in range(rays.shape[0]):
        r = rays[i]
        out[i] = optical_depth_exact(grid, bmin, bmax, scale, (r[0], r[1], r[2]),
                                     (r[3], r[4], r[5]), r[6], r[7])
    return out


def stats(est, exact, counters, seconds, n_per_ray):
    """Metrics of estimates ``est`` [n_rays * n_per_ray] against per-ray truths ``exact``;
    ``counters`` [n, N_COUNTERS] per estimate. The guard counts (estimates that hit the step
    cap, lookups above the majorant, non-finite estimates) are reported with them."""
    from ..params import COUNTER_NAMES
    lookups = counters[:, COUNTER_NAMES.index("lookups")]
    guards = {"capped": int(counters[:, COUNTER_NAMES.index("capped")].sum()),
              "over_majorant": int(counters[:, COUNTER_NAMES.index("over_majorant")].sum()),
              "non_finite": int(np.count_nonzero(~np.isfinite(est)))}
    e = est.reshape(-1, n_per_ray)
    truth = np.asarray(exact).reshape(-1, 1)
    err = e - truth
    n = e.size
    mean_err = float(err.mean())
    se = float(err.std(ddof=1) / math.sqrt(n)) if n > 1 else float("inf")
    var = float(np.mean(e.var(axis=1, ddof=1)))
    mse = float(np.mean(err ** 2))
    lk = float(lookups.mean())
    t = seconds / n
    if se > 0:
        z = mean_err / se
    else:
        z = 0.0 if abs(mean_err) < 1e-6 else math.copysign(math.inf, mean_err)
    return {
        "mean": float(e.mean()), "truth": float(np.mean(exact)), "bias": mean_err,
        "stderr": se, "bias_z": z, "variance": var, "mse": mse, "lookups": lk,
        "seconds_per_estimate": t,
        "eff_var_lookups": 1.0 / (var * lk) if var * lk > 0 else math.inf,
        "eff_mse_time": 1.0 / (mse * t) if mse * t > 0 else math.inf,
        "eff_mse_lookups": 1.0 / (mse * lk) if mse * lk > 0 else math.inf,
        "variance_at_budget": var * max(lk, 1.0) / BUDGET,
        "guards": guards,
    }


def timed_launch(runner, med, grid, rays, bounds, n_per_ray, seed,
                 structure=(None, None, None)):
    """A launch's (estimates, counters, seconds), after an untimed launch of one estimate
    (the first launch compiles for the size). ``structure``: (maj, mnr, nodes) of the
    medium's own majorant structure, or Nones for ``bounds``. The time is the fastest of
    TIME_REPEATS identical launches: other work on the machine only ever adds time."""
    maj, mnr, nodes = structure
    runner.run(med, grid, rays[:1], None if bounds is None else bounds[:1], 1, seed, 0, maj,
               mnr, nodes)
    best = math.inf
    for _ in range(TIME_REPEATS):
        t = time.perf_counter()
        est, cnt = runner.run(med, grid, rays, bounds, n_per_ray, seed, 0, maj, mnr, nodes)
        best = min(best, time.perf_counter() - t)
    return est, cnt, best


def run(names=None, scenes=(), n_per_case=2048, n_rays=1024, n_per_ray=64, quick=False,
        log=print, device=None, resolution=None, per_pixel=RECORD_PER_PIXEL):
    """Run the benchmark; returns the JSON-able report. ``scenes``: grid scenes whose render
    is recorded at their own camera.resolution or at ``resolution`` (width, height) if given
    (the CLI sets RECORD_RESOLUTION, or QUICK_RESOLUTION with --quick, by -D), keeping
    ``per_pixel`` segments per pixel; ``n_rays`` camera and ``n_rays`` shadow segments (a
    quarter with ``quick``) are replayed with ``n_per_ray`` estimates each."""
    names = list(names or ESTIMATORS)
    targets = TARGET_T if not quick else (0.1, 0.6)
    tights = TIGHTNESS if not quick else (0.25, 1.0)
    runners = {n: OpenCLEstimator(n, device) for n in names}
    report = {"profiles": [], "grids": [], "budget": BUDGET, "estimators": names,
              "unbiased": {n: ESTIMATORS[n].unbiased for n in names}}
    ray = np.array([[0, 0, 0, 1, 0, 0, 0, 1, 0]], np.float64)
    for shape in SHAPES:
        for T in targets:
            for tight in tights:
                med, mbar, mu_c, exact, eff_tight = profile_case(shape, T, tight)
                bounds = np.array([[mbar, mu_c]])
                row = {"profile": shape, "target_T": T, "tightness": tight,
                       "effective_tightness": eff_tight, "exact": exact, "results": {}}
                for n in names:
                    if ESTIMATORS[n].homogeneous_only and shape != "constant":
                        continue  # analytic needs a homogeneous segment
                    mu = float(med["density"])  # homogeneous_only: the constant profile
                    bnd = bounds if not ESTIMATORS[n].homogeneous_only else np.array([[mu, mu]])
                    est, cnt, sec = timed_launch(runners[n], med, np.zeros((1, 1, 1)), ray,
                                                 bnd, n_per_case, 17)
                    row["results"][n] = stats(est, [exact], cnt, sec, n_per_case)
                report["profiles"].append(row)
        log(f"  profiles: {shape} done")
    replays = []
    for scene in scenes:
        if resolution:
            scene = with_resolution(scene, resolution)
        res = scene.camera.resolution
        rec = record_segments(scene, "opencl", spp=RECORD_SPP, per_pixel=per_pixel,
                              device=device, seed=0)
        grey = "" if not scene.medium.chromatic else " (chromatic: the largest channel)"
        log(f"  {scene.file}: recorded {len(rec.camera)} camera and {len(rec.shadow)} shadow "
            f"segments at {res[0]}x{res[1]}, {majorant_name(rec)}{grey}")
        n = n_rays if not quick else n_rays // 4
        cases = replay_cases(rec, n, seed=3)
        replays.append((rec, np.concatenate([c[1] for c in cases])))
        for label, rays, exact in cases:
            pieces = segment_maps.majorant_pieces(
                rec.medium, np.asarray(rec.grid, np.float64), np.asarray(rec.maj, np.float64),
                np.asarray(rec.mnr, np.float64), rec.nodes, rays)
            row = {"scene": scene.file, "rays": label, "n_rays": len(rays),
                   "majorant": majorant_name(rec), "extinction": "grey" if not grey else
                   "largest channel", "resolution": list(res),
                   "recorded": {"camera": len(rec.camera), "shadow": len(rec.shadow),
                                "pixels_full": rec.full},
                   "mean_exact_T": float(exact.mean()),
                   "mean_majorant_depth": float(np.sum(pieces[:, 3] * (pieces[:, 2] -
                                                                       pieces[:, 1]))
                                                / max(len(rays), 1)),
                   "mean_majorant_segments": len(pieces) / max(len(rays), 1),
                   "results": {}}
            for n_ in names:
                if ESTIMATORS[n_].homogeneous_only:
                    continue
                est, cnt, sec = timed_launch(runners[n_], rec.medium, rec.grid, rays, None,
                                             n_per_ray, 29,
                                             structure=(rec.maj, rec.mnr, rec.nodes))
                row["results"][n_] = stats(est, exact, cnt, sec, n_per_ray)
                row["results"][n_]["convergence"] = convergence(est, exact, cnt[:, 0], sec,
                                                                n_per_ray)
            report["grids"].append(row)
            log(f"  {scene.file}: {label} done")
    if replays:
        report["maps"] = segment_maps.measure(
            runners, replays, log=log,
            min_segments=segment_maps.MIN_SEGMENTS // (4 if quick else 1))
    report["summary"] = summarise(report)
    return report


def convergence(est, exact, lookups, seconds, n_per_ray):
    """Variance and RMSE of means of k estimates (k = 1, 2, 4, ...) against their cost."""
    e = est.reshape(-1, n_per_ray) - np.asarray(exact).reshape(-1, 1)
    per_est_time = seconds / est.size
    lk = float(lookups.mean())
    out = []
    k = 1
    while k <= n_per_ray:
        m = e[:, : (n_per_ray // k) * k].reshape(e.shape[0], -1, k).mean(axis=2)
        var = float(np.mean(m.var(axis=1, ddof=1))) if m.shape[1] > 1 else float("nan")
        out.append({"k": k, "lookups": k * lk, "seconds": k * per_est_time,
                    "variance": var, "rmse": float(np.sqrt(np.mean(m ** 2)))})
        k *= 2
    return out


def summarise(report):
    """Per estimator: geometric-mean efficiency over the profile sweep and the number of
    sweep points where it is the most efficient unbiased estimator."""
    names = report["estimators"]
    eff = {n: [] for n in names}
    wins = {n: 0 for n in names}
    for row in report["profiles"]:
        best, best_eff = None, -1.0
        for n, r in row["results"].items():
            e = r["eff_var_lookups"]
            if math.isfinite(e):
                eff[n].append(e)
            e_rank = e if math.isfinite(e) else 1e300
            if (report["unbiased"][n] and not ESTIMATORS[n].homogeneous_only and n != "auto"
                    and e_rank > best_eff):   # auto runs one of the others
                best, best_eff = n, e_rank
        if best:
            wins[best] += 1
    return {n: {"geomean_eff_var_lookups": float(np.exp(np.mean(np.log(eff[n]))))
                if eff[n] else None, "wins": wins[n]} for n in names}


def print_report(report, log=print):
    """Terminal table: grid rays in full, then the profile-sweep summary."""
    hdr = (f"{'estimator':>17s} {'mean':>8s} {'bias z':>7s} {'variance':>10s} {'lookups':>8s} "
           f"{'us/est':>7s} {'1/(V*L)':>10s} {'1/(MSE*t)':>10s} {'V@100lk':>10s}")
    for row in report["grids"]:
        log(f"\n{row['scene']}: {row['rays']} ({row['n_rays']} replayed, {row['majorant']}, "
            f"{row['extinction']}; mean T {row['mean_exact_T']:.3f}, mean majorant optical "
            f"depth {row['mean_majorant_depth']:.1f} over "
            f"{row['mean_majorant_segments']:.1f} majorant segments)")
        log(hdr)
        for n, r in row["results"].items():
            tag = "" if report["unbiased"][n] else "  (biased)"
            log(f"{n:>17s} {r['mean']:8.4f} {r['bias_z']:7.2f} {r['variance']:10.3e} "
                f"{r['lookups']:8.2f} {1e6 * r['seconds_per_estimate']:7.2f} "
                f"{r['eff_var_lookups']:10.3e} {r['eff_mse_time']:10.3e} "
                f"{r['variance_at_budget']:10.3e}{tag}")
    log(f"\n1-D profile sweep ({len(report['profiles'])} cases: 5 profiles x target T x "
        f"majorant tightness): geometric-mean 1/(variance x lookups), and the number of cases "
        f"where each unbiased estimator is the most efficient")
    for n, s in report["summary"].items():
        g = s["geomean_eff_var_lookups"]
        log(f"{n:>17s} {('%.3e' % g) if g else '     n/a':>10s}  best in {s['wins']}")
    if report.get("maps"):
        maps = report["maps"]
        wins = segment_maps.win_counts(maps)
        log(f"\nmaps over (majorant optical depth, tightness): {maps['n_pieces']} majorant "
            f"segments, {maps['n_homogeneous']} homogeneous left out; bins won by each "
            f"unbiased estimator")
        for key, label in (("winner_var_lookups", "1/(V*L)"), ("winner_mse_time",
                                                               "1/(MSE*t)")):
            log(f"  by {label}: " + ", ".join(f"{n} {c}" for n, c in
                                              sorted(wins[key].items(), key=lambda x: -x[1])))
    totals = guard_totals(report)
    log("\nguard counters over every case (0 on a correct run): " + "; ".join(
        f"{n}: capped {t['capped']}, over majorant {t['over_majorant']}, non-finite "
        f"{t['non_finite']}" for n, t in totals.items()))


def guard_totals(report):
    """{estimator: summed guard counts} over the profile and grid cases."""
    out = {}
    for row in report["profiles"] + report["grids"] + report.get("maps", {}).get("bins", []):
        for n, r in row["results"].items():
            t = out.setdefault(n, {"capped": 0, "over_majorant": 0, "non_finite": 0})
            for k in t:
                t[k] += r["guards"][k]
    return out


def write_json(path, report):
    with open(path, "w") as f:
        json.dump(report, f, indent=1, default=float)
