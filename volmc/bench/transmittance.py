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

import math
import threading
import time
from collections import namedtuple

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


def efficiency(error, cost):
    """1 / (error x cost): inf for an exact estimator (error 0), NaN where it is not a
    measure -- an error that is NaN (an estimate went non-finite), or a noisy estimator
    that made no lookups (track length on a homogeneous segment: Bernoulli(T) at no
    lookup), which 1 / (V x L) cannot weigh against the others."""
    if math.isnan(error) or math.isnan(cost):
        return math.nan
    if error == 0.0:
        return math.inf
    return 1.0 / (error * cost) if cost > 0.0 else math.nan


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
        "eff_var_lookups": efficiency(var, lk),
        "eff_mse_time": efficiency(mse, t),
        "eff_mse_lookups": efficiency(mse, lk),
        "variance_at_budget": var * max(lk, 1.0) / BUDGET,
        "guards": guards,
    }


Launch = namedtuple("Launch", "name scene med rays bounds n_per_ray seed")
Launch.__doc__ = """One launch of estimator ``name`` on ``rays`` [r, 9] with ``n_per_ray``
estimates each, on the 1-D profile ``med`` (``scene`` None) or on recorded scene ``scene``
(an index into the cases' shared list of (medium, grid, maj, mnr, nodes)). ``bounds`` [r, 2]:
each ray's majorant and minorant, or None to walk the scene's own majorant structure."""

_NO_GRID = np.zeros((1, 1, 1))
#: OpenCL runners built in this process, by (estimator, device): a Dask worker keeps them
#: from case to case.
_RUNNERS = {}
#: One case at a time per process: a Dask worker with several threads would otherwise run
#: cases at once on the shared runners (an OpenCL kernel's arguments are not thread-safe)
#: and time each case under the others' load.
_CASE_LOCK = threading.Lock()


def _runner(name, device):
    key = (name, device)
    if key not in _RUNNERS:
        _RUNNERS[key] = OpenCLEstimator(name, device)
    return _RUNNERS[key]


def _launch_args(launch, shared, n):
    """``runner.run`` arguments of ``launch``, cut to its first ``n`` rays."""
    b = None if launch.bounds is None else launch.bounds[:n]
    if launch.scene is None:
        return (launch.med, _NO_GRID, launch.rays[:n], b)
    medium, grid, maj, mnr, nodes = shared[launch.scene]
    if b is not None:
        maj = mnr = nodes = None
    return (medium, grid, launch.rays[:n], b, None, 0, maj, mnr, nodes)


def run_case(launches, shared=(), device=None):
    """Run one case's launches in this process: [(estimates, counters, seconds)] per launch.

    Each launch first runs one untimed estimate (the first launch of a size compiles); then
    TIME_REPEATS rounds run every launch in turn, and a launch's time is its fastest round:
    other work on the machine only ever adds time, and alternating spreads what it adds
    evenly over the estimators a case compares. Estimates are the same in every round (fixed
    seed). Cases in one process run one at a time (_CASE_LOCK)."""
    with _CASE_LOCK:
        return _run_case(launches, shared, device)


def _run_case(launches, shared, device):
    runners = [_runner(x.name, device) for x in launches]
    for r, x in zip(runners, launches):
        a = _launch_args(x, shared, 1)
        r.run(*a[:4], 1, x.seed, *a[5:])
    out = [None] * len(launches)
    best = [math.inf] * len(launches)
    for _ in range(TIME_REPEATS):
        for i, (r, x) in enumerate(zip(runners, launches)):
            a = _launch_args(x, shared, len(x.rays))
            # Records, uploads and allocations are the same for every estimator and would
            # add a fixed few ms a launch: only the estimates and their read-back are timed.
            prepared = r.prepare(*a[:4], x.n_per_ray, x.seed, *a[5:])
            t = time.perf_counter()
            out[i] = r.launch(prepared)
            best[i] = min(best[i], time.perf_counter() - t)
    return [(est, cnt, sec) for (est, cnt), sec in zip(out, best)]


def run_cases(cases, shared=(), device=None, client=None):
    """``run_case`` of every case (a list of Launches) in order, yielding each case's result
    list as it is ready: in this process, or with a Dask ``client`` as one task per case on
    the cluster's workers (submitted together; ``shared`` sent once, distributed.hold).
    A case's launches run back to back on one worker, so the estimators it compares are
    timed on the same machine under the same load; different cases may run on different
    machines. Tasks still pending when the caller stops (Ctrl-C) are cancelled."""
    if client is None:
        for c in cases:
            yield run_case(c, shared, device)
        return
    from ..distributed import hold
    data = hold(client, tuple(shared), "volmc-bench-data")
    futures = [client.submit(run_case, c, data, device, pure=False, retries=3)
               for c in cases]
    try:
        for f in futures:
            res = f.result()
            f.release()
            yield res
    finally:
        pending = [f for f in futures if not f.done()]
        if pending:
            client.cancel(pending)


def run(names=None, scenes=(), n_per_case=2048, n_rays=1024, n_per_ray=64, quick=False,
        log=print, device=None, resolution=None, per_pixel=RECORD_PER_PIXEL, client=None):
    """Run the benchmark; returns the JSON-able report. ``scenes``: grid scenes whose render
    is recorded at their own camera.resolution or at ``resolution`` (width, height) if given
    (the CLI sets RECORD_RESOLUTION, or QUICK_RESOLUTION with --quick, by -D), keeping
    ``per_pixel`` segments per pixel; ``n_rays`` camera and ``n_rays`` shadow segments (a
    quarter with ``quick``) are replayed with ``n_per_ray`` estimates each. The recordings
    are made here; the cases (a profile sweep point, a replayed set, a map bin: every
    estimator on it) run here or, with a Dask ``client``, as tasks on its workers
    (``run_cases``). Every figure but the times is the same either way."""
    names = list(names or ESTIMATORS)
    targets = TARGET_T if not quick else (0.1, 0.6)
    tights = TIGHTNESS if not quick else (0.25, 1.0)
    report = {"profiles": [], "grids": [], "budget": BUDGET, "estimators": names,
              "unbiased": {n: ESTIMATORS[n].unbiased for n in names}}
    plan = []   # (launches, finish(launches, results)) per case, in report order
    ray = np.array([[0, 0, 0, 1, 0, 0, 0, 1, 0]], np.float64)
    for shape in SHAPES:
        for T in targets:
            for tight in tights:
                med, mbar, mu_c, exact, eff_tight = profile_case(shape, T, tight)
                row = {"profile": shape, "target_T": T, "tightness": tight,
                       "effective_tightness": eff_tight, "exact": exact, "results": {}}
                launches = []
                for n in names:
                    if ESTIMATORS[n].homogeneous_only and shape != "constant":
                        continue  # analytic needs a homogeneous segment
                    mu = float(med["density"])  # homogeneous_only: the constant profile
                    bnd = np.array([[mu, mu] if ESTIMATORS[n].homogeneous_only
                                    else [mbar, mu_c]])
                    launches.append(Launch(n, None, med, ray, bnd, n_per_case, 17))
                report["profiles"].append(row)
                plan.append((launches, _finish_row(row, [exact], n_per_case)))
    shared, replays = [], []
    for scene in scenes:
        if resolution:
            scene = with_resolution(scene, resolution)
        res = scene.camera.resolution
        rec = record_segments(scene, "opencl", spp=RECORD_SPP, per_pixel=per_pixel,
                              device=device, seed=0)
        grey = "" if not scene.medium.chromatic else " (chromatic: the largest channel)"
        log(f"  {scene.file}: recorded {len(rec.camera)} camera and {len(rec.shadow)} shadow "
            f"segments at {res[0]}x{res[1]}, {majorant_name(rec)}{grey}")
        k = len(shared)
        shared.append((rec.medium, rec.grid, rec.maj, rec.mnr, rec.nodes))
        n = n_rays if not quick else n_rays // 4
        cases = replay_cases(rec, n, seed=3)
        replays.append((rec, np.concatenate([c[1] for c in cases])))
        for label, rays, exact in cases:
            if not len(rays):   # no shadow ray reached the medium (an empty grid), say
                log(f"  {scene.file}: no {label} recorded: left out")
                continue
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
            launches = [Launch(n_, k, None, rays, None, n_per_ray, 29) for n_ in names
                        if not ESTIMATORS[n_].homogeneous_only]
            report["grids"].append(row)
            plan.append((launches, _finish_row(row, exact, n_per_ray, with_convergence=True)))
    if replays:
        report["maps"], map_plan = segment_maps.plan(
            names, replays, log=log,
            min_segments=segment_maps.MIN_SEGMENTS // (4 if quick else 1))
        plan += map_plan
    where = "here" if client is None else "as tasks on the cluster"
    log(f"  {len(plan)} cases ({sum(len(c) for c, _ in plan)} launches) running {where}")
    step = max(len(plan) // 8, 1)
    results = run_cases([c for c, _ in plan], shared, device, client)
    for i, ((launches, finish), res) in enumerate(zip(plan, results)):
        finish(launches, res)
        if (i + 1) % step == 0 or i + 1 == len(plan):
            log(f"  {i + 1} of {len(plan)} cases done")
    report["summary"], report["exact_ties"] = summarise(report)
    return report


def _finish_row(row, exact, n_per_ray, with_convergence=False):
    """The finish step of a profile or replayed-set case: each launch's stats (and
    convergence) into ``row["results"]``."""
    def finish(launches, results):
        for x, (est, cnt, sec) in zip(launches, results):
            r = row["results"][x.name] = stats(est, exact, cnt, sec, n_per_ray)
            if with_convergence:
                r["convergence"] = convergence(est, exact, cnt[:, 0], sec, n_per_ray)
    return finish


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
    """(per estimator: geometric-mean efficiency over the profile sweep and the number of
    sweep points where it is the most efficient unbiased estimator; the number of sweep
    points with no single one, where several are exact)."""
    names = report["estimators"]
    eff = {n: [] for n in names}
    wins = {n: 0 for n in names}
    ties = 0
    for row in report["profiles"]:
        for n, r in row["results"].items():
            if math.isfinite(r["eff_var_lookups"]):
                eff[n].append(r["eff_var_lookups"])
        best = segment_maps.most_efficient({   # auto runs one of the others
            n: r["eff_var_lookups"] for n, r in row["results"].items()
            if report["unbiased"][n] and not ESTIMATORS[n].homogeneous_only and n != "auto"})
        if best:
            wins[best] += 1
        else:
            ties += 1
    out = {n: {"geomean_eff_var_lookups": float(np.exp(np.mean(np.log(eff[n]))))
               if eff[n] else None, "wins": wins[n]} for n in names}
    return out, ties


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
    if report.get("exact_ties"):
        log(f"{'':>17s} {'':>10s}  no single best in {report['exact_ties']} (several exact)")
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
