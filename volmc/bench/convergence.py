"""Speed against error: RMSE as a function of wall time for every render configuration.

A configuration is backend x majorant x free-flight x shadow-ray estimator (and the peers,
Mitsuba 3 and Blender Cycles, when they can run). A peer's time is its tracing time; Cycles'
scene sync, which every Cycles render repeats, is recorded apart ("sync_seconds"). Each one renders the scene at a ladder of sample counts; every render
is timed (compilation excluded: each renderer is built and launched once before timing) and
its RMSE is taken against a high-spp reference rendered by volmc with an independent seed.
The reference's own noise adds its mean variance of the mean to every MSE; that known amount
is subtracted (volmc.peers.compare.rmse_to_reference).

Renders alternate: each spp level is rendered by every configuration in turn, in an order
turned by one place per level and per repetition (turn_order), so drift of this shared
machine hits all of them alike.

Efficiency: for an unbiased renderer MSE = c / t, so c = MSE x t (geometric mean over the
upper half of the spp ladder, where fixed per-launch costs no longer matter) is the time
needed for unit MSE. The time to reach the same RMSE as configuration B is c_A / c_B times
B's time: the "time to equal error" ratios printed.
"""

import math
import time
from dataclasses import dataclass, replace

import numpy as np
from numba import njit

from ..film import Film
from ..reference.camera import camera_ray
from ..reference.integrator import enter_media
from ..reference.medium import majorant_iter_init, majorant_next, media_data, new_iter
from ..params import COUNTER_NAMES
from ..peers.compare import rmse_to_reference
from ..backends import make_backend
from ..render import batch_schedule


@dataclass(frozen=True)
class Config:
    """One renderer configuration. Backends "mitsuba", "cycles" (peers) and "baseline" (an
    earlier volmc at ``path``, rendering the scene as it is written) ignore the technique fields;
    ``lanes`` is OpenCL's lane width (0: the default)."""
    backend: str
    majorant: str = ""
    free_flight: str = ""
    transmittance: str = ""
    path: str = ""
    spectral: str = ""
    lanes: int = 0

    @property
    def name(self):
        if self.backend == "mitsuba":
            return "mitsuba volpath"
        if self.backend == "cycles":
            return "cycles cpu"
        if self.backend == "baseline":
            return f"baseline {self.path}"
        name = f"{self.backend} {self.majorant} {self.free_flight} {self.transmittance}"
        name = f"{name} {self.spectral}" if self.spectral else name
        return f"{name} W{self.lanes}" if self.lanes else name

    @property
    def ceiling_key(self):
        """The key of this configuration's lookup ceiling (``lookups.lookup_ceiling``)."""
        return f"{self.backend} W{self.lanes}" if self.lanes else self.backend


def unbiased_grid_estimators():
    """Unbiased shadow-ray estimators that work on grids (the registry decides)."""
    from ..techniques import ESTIMATORS
    return [n for n, e in ESTIMATORS.items() if e.unbiased and not e.homogeneous_only]


#: Backends of configurations rendered by another renderer than volmc.
PEER_BACKENDS = ("mitsuba", "cycles")
NOT_VOLMC = PEER_BACKENDS + ("baseline",)


def make_configs(backends, majorants, free_flights, transmittances, peers=(), baselines=(),
                 spectrals=("",)):
    """Every combination of the technique lists; a spectral mode "" keeps the scene's;
    ``peers``: names of peer renderers to add (volmc.peers.PEERS)."""
    out = [Config(b, m, f, t, spectral=sp) for b in backends for m in majorants
           for f in free_flights for t in transmittances for sp in spectrals]
    out += [Config(p) for p in (peers or ())]
    out += [Config("baseline", path=str(p)) for p in baselines]
    return out


@njit(cache=True)
def _camera_segments(params, med):
    """(majorant segments, camera rays through the media) over every pixel centre's primary
    ray: the segments majorant_next yields (empty ones are skipped, as in tracking)."""
    prm = params[0]
    it = new_iter(med)
    segments = 0
    rays = 0
    for py in range(prm.height):
        for px in range(prm.width):
            o, d = camera_ray(prm, px, py, 0.5, 0.5, 0.5, 0.5)
            o, t0, t1, _ = enter_media(med, o, d)
            if not t1 > t0:
                continue
            rays += 1
            majorant_iter_init(it, med, o, d, t0, t1)
            while majorant_next(it, med)[0]:
                segments += 1
    return segments, rays


def segments_per_camera_ray(scene, majorant):
    """Mean number of majorant segments along the camera rays (pixel centres) that cross the
    medium box, with render.majorant = ``majorant`` (float64 reference walk)."""
    from ..pack import pack_scene
    pk = pack_scene(scene.with_render(majorant=majorant), np.float64)
    segments, rays = _camera_segments(pk.params, media_data(pk))
    return segments / max(rays, 1)


def config_scene(scene, cfg):
    """``scene`` with the techniques of volmc configuration ``cfg``."""
    return scene.with_render(majorant=cfg.majorant, free_flight=cfg.free_flight,
                             transmittance=cfg.transmittance,
                             spectral=cfg.spectral or scene.render.spectral)


class _VolmcRunner:
    def __init__(self, scene, cfg, device):
        self.scene = config_scene(scene, cfg)
        self.be = make_backend(cfg.backend, self.scene, device, lanes=cfg.lanes or None)
        self.lanes = getattr(self.be, "lanes", 0)
        self.be.warm_up()
        w, h = self.scene.camera.resolution
        self.w, self.h = w, h
        self.next_sample = 0
        self.render(1)  # first launch (driver-side compilation) is not measured

    def render(self, spp):
        out = timed_render(self.be, self.w, self.h, self.next_sample, spp)
        self.next_sample += spp  # later renders use fresh, independent samples
        return out


class _ClusterRunner:
    """A volmc configuration rendered on a Dask cluster (``run(..., client=...)``): each
    render's chunks of samples [start, start + spp) run as tasks (distributed.py), timed
    from submission to the last merge, so scheduling and transfer are in the figure."""

    def __init__(self, scene, cfg, device, client):
        from ..cl.lanes import resolve_lanes
        self.scene = config_scene(scene, cfg)
        self.cfg, self.device, self.client = cfg, device, client
        self.lanes = resolve_lanes(cfg.lanes or None) if cfg.backend == "opencl" else 0
        self.w, self.h = self.scene.camera.resolution
        self.next_sample = 0
        self.render(1)  # the workers build their backends: not measured

    def render(self, spp):
        from ..distributed import ClusterChunks
        from ..render import chunk_schedule
        start = self.next_sample
        film = Film(self.w, self.h)
        chunks = chunk_schedule(self.w * self.h, start + spp, start)
        t = time.perf_counter()
        runner = ClusterChunks(self.client, self.scene, self.cfg.backend, self.device, film,
                               chunks, self.lanes or None)
        runner.warm_up()
        for n in runner:
            film.spp += n
        sec = time.perf_counter() - t
        self.next_sample += spp
        c = runner.counter_totals()
        return film.mean(), sec, {k: int(c[i]) for i, k in enumerate(COUNTER_NAMES)}


def timed_render(backend, width, height, start, spp):
    """Render samples [start, start + spp) of every pixel in the batches ``volmc render``
    uses. Returns (mean image [h, w, 3], wall seconds of the launches alone, {counter: count
    during this render}). The backend must be built and warmed up already."""
    film = Film(width, height)
    before = np.array(backend.counter_totals(), np.int64)
    t = time.perf_counter()
    for n in batch_schedule(width * height, spp):
        backend.render(start + film.spp, n, film)
        film.spp += n
    sec = time.perf_counter() - t
    delta = np.array(backend.counter_totals(), np.int64) - before
    return film.mean(), sec, {k: int(delta[i]) for i, k in enumerate(COUNTER_NAMES)}


#: Offset of the reference's seed from the scene's: its noise is independent of every timed
#: render (those use the scene's seed, or small offsets from it).
REFERENCE_SEED_OFFSET = 0x5EED


def reference_image(scene, reference_spp, device=None, log=print):
    """(mean, variance of the mean) images of the scene rendered by OpenCL at
    ``reference_spp`` samples per pixel with an independent seed, for rmse_to_reference."""
    log(f"reference: volmc opencl, {reference_spp} spp (independent seed)")
    t = time.perf_counter()
    sref = scene.with_render(seed=(scene.render.seed + REFERENCE_SEED_OFFSET) % 2**64)
    from ..render import render, whole
    ref = whole(render(sref, backend=make_backend("opencl", sref, device), spp=reference_spp,
                       progress=False))
    ref_mean, ref_var = ref.film.mean(), ref.film.variance_of_mean()
    log(f"  {time.perf_counter() - t:.1f} s; reference noise (RMS standard error) "
        f"{math.sqrt(float(np.mean(ref_var))):.2e}")
    return ref_mean, ref_var


def mse_seconds(points, spp_levels):
    """MSE x wall seconds (unit: radiance^2 s), the time to reach unit MSE: the geometric
    mean over the points in the upper half of the spp ladder, where fixed per-launch costs
    no longer matter. Points of RMSE 0 (below the reference's noise) are left out; None
    when no point is left."""
    upper = sorted(spp_levels)[len(spp_levels) // 2:]
    fit = [p for p in points if p["spp"] in upper and p["rmse"] > 0]
    if not fit:
        return None
    return math.exp(float(np.mean([math.log(p["rmse"] ** 2 * p["seconds"]) for p in fit])))


class _PeerRunner:
    def __init__(self, name, scene):
        from ..peers import make_renderer
        self.r = make_renderer(name, scene)
        self.r.warm_up()
        self.seed = 1000

    @property
    def sync_seconds(self):
        """The peer's scene sync in its last render (Cycles), else None."""
        return getattr(self.r, "last_sync_seconds", None)

    def render(self, spp):
        self.seed += 1
        mean, _, sec, _ = self.r.render(spp, seed=self.seed)
        return mean, sec, None

    def close(self):
        if hasattr(self.r, "close"):
            self.r.close()


def turn_order(items, rep, level):
    """The order in which ``items`` render spp level ``level`` in repetition ``rep``: turned
    by one place per level and per repetition, so over n repetitions of n items every level
    sees every item in every place (turned per level alone, a ladder of as many levels as
    items gave each level the same order in every repetition)."""
    items = list(items)
    k = (rep + level) % len(items) if items else 0
    return items[k:] + items[:k]


def guard_totals(points):
    """{guard counter: total over the points}: paths cut by the step cap, dropped samples,
    lookups above the majorant (each nonzero one is a bias to report)."""
    return {k: sum(p["counters"][k] for p in points) for k in ("capped", "dropped",
                                                                "over_majorant")}


def run(scene, configs, spp_levels, reference_spp, repeats=1, device=None, ceiling=None,
        log=print, defines=(), client=None):
    """Render every configuration at every spp level; returns the report dict. ``defines``:
    the -D overrides the scene was loaded with (a baseline worker loads it the same way).
    ``client``: a dask.distributed Client; volmc's own configurations (not baselines or
    Mitsuba, which run here) then render on its workers."""
    w, h = scene.camera.resolution
    pixels = w * h
    ref_mean, ref_var = reference_image(scene, reference_spp, device, log)

    runners = {}
    for cfg in configs:
        t = time.perf_counter()
        if cfg.backend in PEER_BACKENDS:
            runners[cfg] = _PeerRunner(cfg.backend, scene)
        elif cfg.backend == "baseline":
            from .baseline import BaselineRunner
            runners[cfg] = BaselineRunner(cfg.path, scene.file, defines)
        elif client is not None:
            runners[cfg] = _ClusterRunner(scene, cfg, device, client)
        else:
            runners[cfg] = _VolmcRunner(scene, cfg, device)
        log(f"  {cfg.name}: ready in {time.perf_counter() - t:.1f} s")

    segments = {c.majorant: segments_per_camera_ray(scene, c.majorant) for c in configs
                if c.backend not in NOT_VOLMC}
    # One untimed pass at the top level first: a runner's first renders of full-size launches
    # were 1.2x to 1.9x slower than its later ones (buffers growing, first touches), and a
    # baseline's worker process more so, which tilted short comparisons.
    for cfg in configs:
        runners[cfg].render(max(spp_levels))
    points = {cfg: [] for cfg in configs}
    for rep in range(repeats):
        for level, spp in enumerate(spp_levels):
            for cfg in turn_order(configs, rep, level):
                mean, sec, counts = runners[cfg].render(spp)
                e = rmse_to_reference(mean, ref_mean, ref_var)
                points[cfg].append({"spp": spp, "seconds": sec, "rmse": e,
                                    "lookups": counts and counts["lookups"],
                                    "counters": counts})
                sync = getattr(runners[cfg], "sync_seconds", None)
                if sync is not None:
                    points[cfg][-1]["sync_seconds"] = sync
        log(f"  repetition {rep + 1}/{repeats} done")

    results = []
    for cfg in configs:
        pts = points[cfg]
        c = mse_seconds(pts, spp_levels)
        c = math.nan if c is None else c
        secs = sum(p["seconds"] for p in pts)
        spp_total = sum(p["spp"] for p in pts)
        row = {"name": cfg.name, "backend": cfg.backend, "majorant": cfg.majorant,
               "free_flight": cfg.free_flight, "transmittance": cfg.transmittance,
               "lanes": cfg.lanes, "points": pts, "mse_seconds": c,
               "samples_per_second": pixels * spp_total / secs}
        if "sync_seconds" in pts[0]:
            row["sync_seconds"] = sum(p["sync_seconds"] for p in pts)
        if pts[0]["lookups"] is not None:
            row["guards"] = guard_totals(pts)
            lk = sum(p["lookups"] for p in pts)
            row["lookups_per_sample"] = lk / (pixels * spp_total)
            row["lookups_per_second"] = lk / secs
            row["segments_per_camera_ray"] = segments[cfg.majorant]
            if ceiling and cfg.ceiling_key in ceiling:
                row["fraction_of_lookup_ceiling"] = row["lookups_per_second"] / ceiling[
                    cfg.ceiling_key]
            # The lanes' occupancy: the mean fraction active per iteration of the walk loop.
            lanes = getattr(runners[cfg], "lanes", 0)
            rounds = sum(p["counters"]["lane_rounds"] for p in pts)
            if lanes and rounds:
                row["lanes"] = lanes
                row["gathers"] = getattr(getattr(runners[cfg], "be", None), "gathers", None)
                row["lane_occupancy"] = sum(p["counters"]["lane_active"]
                                            for p in pts) / (rounds * lanes)
        results.append(row)
    for runner in runners.values():
        if hasattr(runner, "close"):
            runner.close()
    best = best_volmc(results)
    for r in results:
        r["time_to_equal_error_vs_best_volmc"] = (r["mse_seconds"] / best["mse_seconds"]
                                                  if best else math.nan)
    report = {"scene": scene.file, "resolution": [w, h], "spp_levels": list(spp_levels),
              "reference_spp": reference_spp, "repeats": repeats,
              "best_volmc": best["name"] if best else None,
              "lookup_ceiling": ceiling or {}, "results": results}
    own = scene.render
    same = [r for r in results if (r["backend"], r["majorant"], r["free_flight"],
                                   r["transmittance"]) == ("opencl", own.majorant,
                                                           own.free_flight, own.transmittance)]
    for r in results:
        if r["backend"] == "baseline" and same:
            r["time_to_equal_error_vs_current"] = r["mse_seconds"] / same[0]["mse_seconds"]
    for r in results:
        if r["backend"] in PEER_BACKENDS:
            report[f"{r['backend']}_time_to_equal_error_vs_best_volmc"] = \
                r["time_to_equal_error_vs_best_volmc"]
    return report


def majorant_pairs(report):
    """(grid row, other row) for configurations that differ only in the majorant, the other
    being the global majorant or the octree."""
    by_key = {}
    for r in report["results"]:
        if r["backend"] not in NOT_VOLMC:
            by_key[(r["backend"], r["free_flight"], r["transmittance"], r["majorant"])] = r
    out = []
    for (b, f, t, m), r in by_key.items():
        for other in ("global", "octree"):
            if m == "grid" and (b, f, t, other) in by_key:
                out.append((r, by_key[(b, f, t, other)]))
    return out


def best_volmc(results):
    """The volmc row of least MSE x time among those that measured an error, or None. A row
    whose every RMSE was at or below the reference's noise has NaN there, which min() would
    have kept whenever it came first."""
    measured = [r for r in results if r["backend"] not in NOT_VOLMC and
                math.isfinite(r["mse_seconds"])]
    return min(measured, key=lambda r: r["mse_seconds"]) if measured else None


def print_report(report, log=print):
    log(f"\nspeed against error ({report['resolution'][0]}x{report['resolution'][1]}, spp "
        f"{report['spp_levels']} x {report['repeats']}, reference {report['reference_spp']} "
        f"spp); MSE x time = time for unit MSE, lower is better")
    ceiling = report["lookup_ceiling"]
    if ceiling:
        log("lookup ceiling (raw trilinear lookups, no tracking): " + ", ".join(
            f"{b} {v / 1e6:.1f} M/s" for b, v in ceiling.items()))
    log(f"  {'configuration':46s} {'samples/s':>10s} {'lookups/':>9s} {'of ceil.':>8s} "
        f"{'MSE x s':>10s} {'time to equal error':>20s}")
    for r in sorted(report["results"], key=lambda r: (math.isnan(r["mse_seconds"]),
                                                      r["mse_seconds"])):
        frac = r.get("fraction_of_lookup_ceiling")
        lps = r.get("lookups_per_sample")
        ratio = r["time_to_equal_error_vs_best_volmc"]
        mse = r["mse_seconds"]
        cost = (f"{mse:10.3e} " if math.isfinite(mse) else f"{'(RMSE 0)':>10s} ") + (
            f"{ratio:14.2f} x best" if math.isfinite(ratio) else f"{'-':>21s}")
        log(f"  {r['name']:46s} {r['samples_per_second']:10.0f} "
            f"{'' if lps is None else f'{lps:9.1f}':>9s} "
            f"{'' if frac is None else f'{100 * frac:7.1f}%':>8s} {cost}")
    if report["best_volmc"] is None:
        log("  no volmc configuration measured an error above the reference's noise: raise "
            "--reference-spp, or the spp levels' lowest")
    for name, title in (("mitsuba", "Mitsuba 3"), ("cycles", "Cycles")):
        key = f"{name}_time_to_equal_error_vs_best_volmc"
        if key in report and report["best_volmc"] is not None:
            log(f"{title} needs {report[key]:.2f}x the time of the best volmc configuration "
                f"({report['best_volmc']}) to reach the same RMSE")
    for r in report["results"]:
        if "sync_seconds" in r:
            total = sum(p["seconds"] for p in r["points"])
            log(f"{r['name']}: {total:.1f} s tracing (the times above), {r['sync_seconds']:.1f} "
                f"s scene sync besides (every render syncs the scene again)")
    for r in report["results"]:
        if "time_to_equal_error_vs_current" in r:
            log(f"{r['name']} needs {r['time_to_equal_error_vs_current']:.3f}x the time of the "
                f"current code with the scene's own techniques to reach the same RMSE")
    guarded = [r for r in report["results"] if "guards" in r]
    bad = [r for r in guarded if any(r["guards"].values())]
    log(f"guard counters (capped, dropped, over majorant): "
        + ("0 in every volmc configuration" if not bad else "; ".join(
            f"{r['name']}: {r['guards']}" for r in bad)))
    pairs = majorant_pairs(report)
    if pairs:
        log("majorant grid against global majorant and octree (same backend, free flight, "
            "estimator):")
        for g, o in pairs:
            log(f"  {g['backend']} {g['free_flight']} {g['transmittance']}, grid vs "
                f"{o['majorant']}: lookups/sample {g['lookups_per_sample']:.1f} vs "
                f"{o['lookups_per_sample']:.1f}; segments/camera ray "
                f"{g['segments_per_camera_ray']:.1f} vs {o['segments_per_camera_ray']:.1f}; "
                f"samples/s {g['samples_per_second']:.0f} vs {o['samples_per_second']:.0f}; "
                f"{o['majorant']} needs {o['mse_seconds'] / g['mse_seconds']:.2f}x the time "
                f"to equal error")
