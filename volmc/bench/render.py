"""Render-speed benchmarks: kernel specialisation and work-group size (samples/s).

Speed against error across backends and techniques is volmc/bench/convergence.py.

Every benchmark renders the same scene with the same seed in every configuration. Both
backends and all builds draw the same random numbers, so they trace the same paths and do
the same work (the lookup counters are printed to show it): the ratios measure speed only.
Configurations alternate within each repetition so machine drift affects all of them alike;
figures are medians over repetitions, compile time excluded.
"""

import statistics
import time

from ..film import Film


def _time_render(backend, scene, spp, start):
    """(wall seconds, process CPU seconds) to render ``spp`` samples per pixel from ``start``.

    CPU time (all threads of this process) is steadier than wall time on a shared machine:
    time stolen by other tenants is not counted."""
    w, h = scene.camera.resolution
    film = Film(w, h)
    t = time.perf_counter()
    c = time.process_time()
    backend.render(start, spp, film)
    return time.perf_counter() - t, time.process_time() - c


def run_configs(scene, configs, spp, repeats, log=print):
    """Time each named backend factory; returns {name: {samples_per_second, seconds, ...}}."""
    w, h = scene.camera.resolution
    backends = {}
    for name, factory in configs.items():
        t = time.perf_counter()
        be = factory()
        be.warm_up()
        be.render(0, 1, Film(w, h))  # first launch: driver-side compilation, not measured
        backends[name] = be
        log(f"  {name}: ready in {time.perf_counter() - t:.1f} s")
    times = {name: [] for name in configs}
    cpu = {name: [] for name in configs}
    for rep in range(repeats):
        for name, be in backends.items():
            wall, c = _time_render(be, scene, spp, 1 + rep * spp)
            times[name].append(wall)
            cpu[name].append(c)
    out = {}
    for name, be in backends.items():
        sec = statistics.median(times[name])
        csec = statistics.median(cpu[name])
        totals = be.counter_totals()
        out[name] = {"seconds": sec, "samples_per_second": w * h * spp / sec,
                     "cpu_seconds": csec, "samples_per_cpu_second": w * h * spp / csec,
                     "all_seconds": times[name], "all_cpu_seconds": cpu[name],
                     "lookups": int(totals[0])}
    return out


def specialisation_configs(scene, device=None):
    """{name: backend factory} for `volmc bench specialise`: the production build
    ("specialised": the scene's feature switches), each switch the scene does not need turned
    on ("+X": what compiling X out saves), and the generic build (every switch on)."""
    from ..backends.opencl import OpenCLBackend
    from ..scene.features import FEATURES, features
    needed = features(scene)

    def make(feats):
        return lambda: OpenCLBackend(scene, device=device, feature_set=feats)
    configs = {"specialised": make(needed)}
    for f in sorted(set(FEATURES) - needed):
        configs[f"+{f}"] = make(needed | {f})
    configs["generic"] = make(frozenset(FEATURES))
    return configs


def specialisation_gains(res):
    """{feature: samples-per-CPU-second gain of compiling it out}: "specialised" against
    the build with that switch on."""
    base = res["specialised"]["samples_per_cpu_second"]
    return {name[1:]: base / r["samples_per_cpu_second"]
            for name, r in res.items() if name.startswith("+")}


def bench_specialisation(scene, spp=4, repeats=3, device=None, log=print):
    """samples/s of the specialisation configurations (``specialisation_configs``)."""
    return run_configs(scene, specialisation_configs(scene, device), spp, repeats, log)


def bench_workgroup(scene, sizes=(None, 1, 2, 4, 8, 16, 32, 64), spp=4, repeats=3, device=None,
                    log=print):
    """samples/s of the OpenCL render kernel for each work-group size (None: driver's choice)."""
    from ..backends.opencl import OpenCLBackend
    configs = {("driver" if s is None else str(s)):
               (lambda s=s: OpenCLBackend(scene, device=device, local_size=s)) for s in sizes}
    return run_configs(scene, configs, spp, repeats, log)


def print_table(title, results, baseline=None, log=print):
    """Print samples/s per configuration and the ratio to ``baseline``."""
    log(title)
    base = results[baseline] if baseline else None
    for name, r in results.items():
        ratio = ""
        if base:
            ratio = (f"  x{r['samples_per_second'] / base['samples_per_second']:.2f} wall, "
                     f"x{r['samples_per_cpu_second'] / base['samples_per_cpu_second']:.2f} CPU "
                     f"vs {baseline}")
        log(f"  {name:>14s}: {r['samples_per_second']:10.0f} samples/s, "
            f"{r['samples_per_cpu_second']:10.0f} per CPU-second "
            f"({r['seconds']:.3f} s per batch, {r['lookups']} lookups){ratio}")
    log("  (CPU time counts every thread of this process, so it is not slowed by other tenants; "
        "wall time also shows how well each backend keeps all cores busy)")
