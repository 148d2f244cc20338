"""`volmc bench transmittance`: every estimator on analytic profiles and on grid rays, speed
against error.

Cases:
* 1-D profiles (constant, linear ramp, Gaussian bump, Gaussian hole, cosine) on [0, 1], scaled
  to a target transmittance T (0.01 ... 0.99) and given a majorant at a target tightness
  (mean extinction / majorant, 0.05 ... 1; capped at the profile's own mean / max). The
  control mu_c is the profile's minimum. Truth: the closed-form optical depth.
* Rays through shipped grid scenes: camera rays (random pixels, clipped to the box) and shadow
  rays from points inside the medium towards each light (random directions for the
  environment). Majorant: the global one; control: scale * min(grid). Truth: the exact optical
  depth (piecewise Gauss-Legendre, float64).

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

from ..constants import (DENSITY_CONSTANT, DENSITY_COSINE, DENSITY_GAUSS_BUMP,
                         DENSITY_GAUSS_HOLE, DENSITY_RAMP)
from ..reference import medium as X
from ..techniques import ESTIMATORS
from ..reference.integrator import ray_box
from ..reference.optical_depth import optical_depth_exact
from .transmittance_runner import OpenCLEstimator

TARGET_T = (0.01, 0.1, 0.3, 0.6, 0.9, 0.99)
TIGHTNESS = (0.05, 0.1, 0.25, 0.5, 0.75, 1.0)
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


def grid_rays(scene, n_camera, n_shadow, seed=0):
    """Camera and shadow rays through a grid scene: (label, rays [n, 9], exact T [n])."""
    from ..pack import camera_basis
    from ..scene.schema import DirectionalLight, PointLight
    rng = np.random.default_rng(seed)
    grid = scene.grid.astype(np.float64)
    lo = np.array(scene.medium.bounds[0])
    hi = np.array(scene.medium.bounds[1])
    scale = max(scene.medium.scale)   # grey: the benchmark's media have one channel
    cam = scene.camera
    f, r, u = camera_basis(cam)
    w, h = cam.resolution
    half = math.tan(math.radians(cam.fov) / 2) if cam.type == "perspective" else cam.size / 2
    out = []

    def clip(o, d):
        t0, t1 = ray_box(tuple(o), tuple(d), tuple(lo), tuple(hi))
        t0 = max(t0, 0.0)
        return (t0, t1) if t1 > t0 else None

    cams = []
    while len(cams) < n_camera:
        sx = (2 * rng.random() - 1) * half * w / h
        sy = (2 * rng.random() - 1) * half
        if cam.type == "perspective":
            o = np.array(cam.eye)
            d = np.array(f) + sx * np.array(r) + sy * np.array(u)
            d /= np.linalg.norm(d)
        else:
            o = np.array(cam.eye) + sx * np.array(r) + sy * np.array(u)
            d = np.array(f)
        seg = clip(o, d)
        if seg is not None:
            cams.append((o, d, *seg))
    out.append(("camera rays", cams))
    # Shadow-ray origins: voxel centres drawn in proportion to density, jittered in the voxel.
    p = grid.ravel() / grid.sum()
    idx = rng.choice(grid.size, size=n_shadow, p=p)
    zz, yy, xx = np.unravel_index(idx, grid.shape)
    vox = (hi - lo) / np.array([grid.shape[2], grid.shape[1], grid.shape[0]])
    pts = lo + (np.stack([xx, yy, zz], 1) + rng.random((n_shadow, 3))) * vox
    lights = [lt for lt in scene.lights]
    shadows = []
    for i, pt in enumerate(pts):
        lt = lights[i % len(lights)] if lights else None
        if isinstance(lt, DirectionalLight):
            d = -np.array(lt.direction)
            tmax = np.inf
        elif isinstance(lt, PointLight):
            v = np.array(lt.position) - pt
            tmax = np.linalg.norm(v)
            d = v / tmax
        else:
            d = rng.normal(size=3)
            d /= np.linalg.norm(d)
            tmax = np.inf
        seg = clip(pt, d)
        if seg is not None and min(seg[1], tmax) > seg[0]:
            shadows.append((pt, d, seg[0], min(seg[1], tmax)))
    out.append(("shadow rays", shadows))
    result = []
    for label, items in out:
        rays = np.zeros((len(items), 9))
        exact = np.zeros(len(items))
        for k, (o, d, t0, t1) in enumerate(items):
            rays[k, :3], rays[k, 3:6], rays[k, 6], rays[k, 7] = o, d, t0, t1
            # The kernels see float32 rays: take the truth along exactly those rays.
            r32 = rays[k].astype(np.float32).astype(np.float64)
            rays[k] = r32
            exact[k] = math.exp(-optical_depth_exact(grid, tuple(lo), tuple(hi), scale,
                                                     tuple(r32[:3]), tuple(r32[3:6]),
                                                     r32[6], r32[7]))
        result.append((label, rays, exact))
    return result


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


def _timed(runner, med, grid, rays, bounds, n_per_ray, seed):
    runner.run(med, grid, rays[:1], bounds[:1], 1, seed)  # first launch compiles for the size
    t = time.perf_counter()
    est, cnt = runner.run(med, grid, rays, bounds, n_per_ray, seed)
    return est, cnt, time.perf_counter() - t


def run(names=None, scenes=(), n_per_case=2048, n_rays=512, n_per_ray=32, quick=False,
        log=print, device=None):
    """Run the benchmark; returns the JSON-able report."""
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
                    est, cnt, sec = _timed(runners[n], med, np.zeros((1, 1, 1)), ray, bnd,
                                           n_per_case, 17)
                    row["results"][n] = stats(est, [exact], cnt, sec, n_per_case)
                report["profiles"].append(row)
        log(f"  profiles: {shape} done")
    for scene in scenes:
        grid = scene.grid
        lo, hi = scene.medium.bounds
        nz, ny, nx = grid.shape
        scale = max(scene.medium.scale)   # grey: the largest channel
        med = X.make_grid_medium(lo, hi, scale, (nx, ny, nz))
        mbar = scale * float(grid.max())
        mu_c = scale * float(grid.min())
        n_cam = n_rays if not quick else n_rays // 4
        for label, rays, exact in grid_rays(scene, n_cam, n_cam, seed=3):
            bounds = np.tile([mbar, mu_c], (len(rays), 1))
            row = {"scene": scene.file, "rays": label, "n_rays": len(rays),
                   "mean_exact_T": float(exact.mean()),
                   "mean_majorant_depth": float(mbar * np.mean(rays[:, 7] - rays[:, 6])),
                   "results": {}}
            for n in names:
                if ESTIMATORS[n].homogeneous_only:
                    continue
                est, cnt, sec = _timed(runners[n], med, grid, rays, bounds, n_per_ray, 29)
                row["results"][n] = stats(est, exact, cnt, sec, n_per_ray)
                row["results"][n]["convergence"] = convergence(est, exact, cnt[:, 0], sec,
                                                               n_per_ray)
            report["grids"].append(row)
            log(f"  {scene.file}: {label} done")
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
            if report["unbiased"][n] and not ESTIMATORS[n].homogeneous_only and e_rank > best_eff:
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
        log(f"\n{row['scene']}: {row['rays']} ({row['n_rays']} rays, mean T "
            f"{row['mean_exact_T']:.3f}, mean majorant optical depth "
            f"{row['mean_majorant_depth']:.1f})")
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
    totals = guard_totals(report)
    log("\nguard counters over every case (0 on a correct run): " + "; ".join(
        f"{n}: capped {t['capped']}, over majorant {t['over_majorant']}, non-finite "
        f"{t['non_finite']}" for n, t in totals.items()))


def guard_totals(report):
    """{estimator: summed guard counts} over the profile and grid cases."""
    out = {}
    for row in report["profiles"] + report["grids"]:
        for n, r in row["results"].items():
            t = out.setdefault(n, {"capped": 0, "over_majorant": 0, "non_finite": 0})
            for k in t:
                t[k] += r["guards"][k]
    return out


def write_json(path, report):
    with open(path, "w") as f:
        json.dump(report, f, indent=1, default=float)
