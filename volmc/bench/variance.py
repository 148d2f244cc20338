"""`volmc bench variance`: what each variance-reduction switch buys, at equal time.

A switch is a set of ``[render]`` keys (``SWITCHES``). Every configuration is the scene with
the switch keys at their plain values (``PLAIN``) and then the switch's own keys on top, so
the switches are compared against one baseline whatever the scene file sets. Keys this
volmc's ``Render`` does not have are left out of the plain configuration, and a switch that
needs one is skipped with a note: the table can name switches before the renderer has them.

Per scene: one plain OpenCL reference at ``reference_spp`` with an independent seed (its
noise subtracted, volmc.peers.compare.rmse_to_reference; with equiangular sampling when the
scene has a point light and emission sampling by MIS when a medium emits, which are unbiased
and far quieter there). Then, for each repetition r and
each spp level N, every configuration renders samples [0, N) of the scene with render.spp =
N and seed = scene seed + 1 + r: quasi-Monte Carlo samplers need each render to start at
index 0 and stratification needs render.spp to be the render's total, so independence
between repetitions comes from the seed, which re-scrambles. The configurations take turns
in an order that rotates after every render level, so drift of a shared machine hits all of
them alike. Each render gets its own backend, built and launched once before the timed
launches (compilation and upload are not timed; programs are cached per build options).

Efficiency: MSE x seconds (convergence.mse_seconds: the time to unit MSE), relative
efficiency = (MSE x s)_plain / (MSE x s)_config (> 1: the switch reaches the same error
sooner), and its two factors, the MSE ratio at the top spp (< 1: less error per sample) and
the samples/s ratio. The log-log slope of RMSE against spp is -1/2 for Monte Carlo; a
stratified or quasi-Monte Carlo sampler can be steeper where the integrand is smooth.
"""

import dataclasses
import math
import os
from collections import namedtuple

import numpy as np

from ..backends import make_backend
from ..peers.compare import rmse_to_reference
from .convergence import guard_totals, mse_seconds, reference_image, timed_render, turn_order

#: A row of the switch table: a label (the ``--switches`` name), the render keys it sets
#: ({key: value}) and applicable(scene) -> bool (its docstring says what it needs).
Switch = namedtuple("Switch", ["label", "overrides", "applicable"])

PLAIN = "plain"


def always(scene):
    """Every scene."""
    return True


def has_sampled_light(scene):
    """A light the MIS heuristic weighs phase against light sampling for: an environment, a
    sun disc or a sphere (delta lights are never hit by a phase-sampled direction)."""
    return any(lt.type in ("environment", "sphere") or
               (lt.type == "directional" and lt.angle > 0.0) for lt in scene.lights)


def has_point_light(scene):
    """A point or spot light (equiangular sampling picks distances along a ray towards
    one)."""
    return any(lt.type in ("point", "spot") for lt in scene.lights)


def emits(scene):
    """A medium that emits (emission sampling looks for its light)."""
    return any(m.emission is not None for m in scene.media)


def roulette_happens(scene):
    """Paths longer than render.rr_depth (max_depth < 0 or > rr_depth), where Russian
    roulette starts."""
    r = scene.render
    return r.max_depth < 0 or r.max_depth > r.rr_depth


#: The plain configuration first, then the switches. Add a switch by adding a row; a row
#: whose keys the scene's Render lacks is skipped, so rows may name keys still to come.
SWITCHES = (
    Switch(PLAIN, {"sampler": "independent", "light_samples": 1, "mis": "balance",
                   "equiangular": False, "rr": "throughput", "emission_sampling": "collision"},
           always),
    Switch("stratified", {"sampler": "stratified"}, always),
    Switch("sobol", {"sampler": "sobol"}, always),
    Switch("light_samples=4", {"light_samples": 4}, always),
    Switch("mis=power", {"mis": "power"}, has_sampled_light),
    Switch("equiangular", {"equiangular": True}, has_point_light),
    Switch("rr=albedo", {"rr": "albedo"}, roulette_happens),
    Switch("emission=light", {"emission_sampling": "light"}, emits),
    Switch("emission=mis", {"emission_sampling": "mis"}, emits),
)

#: (legend name, switch label) of the curves in the sampler figure.
SAMPLER_CURVES = (("independent", PLAIN), ("stratified", "stratified"), ("sobol", "sobol"))


def default_scene_paths():
    """The scenes benchmarked when none is given: the default cloud (multiple scattering,
    sky and sun), scenes/bench/thin.toml (thin, single scattering, sun and a point light),
    scenes/bench/haze.toml (homogeneous, single scattering, sun: the samplers' best case)
    and the lamp in fog (scenes/gallery/fog.toml: point lights in a homogeneous medium)."""
    from ..resources import default_scene, scenes_dir
    return [default_scene(), scenes_dir() / "bench" / "thin.toml",
            scenes_dir() / "bench" / "haze.toml", scenes_dir() / "gallery" / "fog.toml"]


def switch_labels(table=None):
    """The labels ``--switches`` accepts (every row but the plain one)."""
    return [s.label for s in (SWITCHES if table is None else table) if s.label != PLAIN]


def render_keys(scene):
    """Names of the scene's ``[render]`` keys (the fields of its Render)."""
    return {f.name for f in dataclasses.fields(scene.render)}


def configurations(scene, labels, table=None):
    """([(label, {render key: value})] with the plain configuration first, {label: why it
    is skipped}) of the switches ``labels`` on ``scene``. The plain keys the scene's Render
    lacks are left out; a switch with such a key, or whose predicate fails, is skipped."""
    table = SWITCHES if table is None else table
    rows = {s.label: s for s in table}
    known = render_keys(scene)
    plain = {k: v for k, v in rows[PLAIN].overrides.items() if k in known}
    configs, skipped = [(PLAIN, plain)], {}
    for label in labels:
        sw = rows[label]
        missing = sorted(set(sw.overrides) - known)
        if missing:
            skipped[label] = "needs " + ", ".join(f"render.{k}" for k in missing) + \
                ", which this volmc does not have"
        elif not sw.applicable(scene):
            doc = (sw.applicable.__doc__ or sw.applicable.__name__).split("(")[0]
            skipped[label] = "needs " + " ".join(doc.split()).rstrip(". ").lower()
        else:
            configs.append((label, {**plain, **sw.overrides}))
    return configs, skipped


def loglog_slope(spp, rmse):
    """Least-squares slope of log RMSE against log spp (-0.5 for plain Monte Carlo). Points
    of RMSE 0 (below the reference's noise) are left out; None with fewer than two distinct
    spp values left."""
    pts = [(math.log(n), math.log(e)) for n, e in zip(spp, rmse) if e > 0]
    if len({x for x, _ in pts}) < 2:
        return None
    x, y = np.array(pts).T
    return float(np.polyfit(x, y, 1)[0])


def _measure(scene, configs, spp_levels, reference_spp, repeats, backend, device, log):
    """{label: [point]}: every configuration rendered at every spp level in every
    repetition, RMSE against the plain reference. A point: spp, seed, seconds, rmse,
    counters."""
    w, h = scene.camera.resolution
    keys = dict(configs[0][1])
    if "equiangular" in keys and has_point_light(scene):
        # The same image with far less noise near point lights, where plain next-event
        # estimation has unbounded variance: a quieter reference, same expectation.
        keys["equiangular"] = True
    if "emission_sampling" in keys and emits(scene):
        # Where a small hot flame lights its smoke, the collision estimator finds its light
        # too rarely for a reference (a pixel's few hits carry it all); MIS does not.
        keys["emission_sampling"] = "mis"
    ref = scene.with_render(**keys)
    ref_mean, ref_var = reference_image(ref, reference_spp, device, log)
    base = scene.render.seed
    points = {label: [] for label, _ in configs}
    for rep in range(repeats):
        seed = (base + 1 + rep) % 2**64
        for level, spp in enumerate(spp_levels):
            for label, keys in turn_order(configs, rep, level):
                s = scene.with_render(spp=spp, seed=seed, **keys)
                be = make_backend(backend, s, device)
                be.warm_up()
                # A new backend's first launch does driver-side work: not measured.
                timed_render(be, w, h, 0, 1)
                mean, sec, counts = timed_render(be, w, h, 0, spp)
                points[label].append({"spp": spp, "seed": seed, "seconds": sec,
                                      "rmse": rmse_to_reference(mean, ref_mean, ref_var),
                                      "counters": counts})
        log(f"  repetition {rep + 1}/{repeats} done")
    return points


def summarise(report):
    """Fill in each result row of a scene report from its points: mse_seconds, slope,
    samples_per_second, mse_at_top_spp (mean over repetitions), lookups_per_sample, guards,
    and against the plain row relative_efficiency, mse_ratio_at_top_spp and
    samples_per_second_ratio (None where a figure is undefined). Returns the report."""
    w, h = report["resolution"]
    levels = report["spp_levels"]
    top = max(levels)
    for r in report["results"]:
        pts = r["points"]
        secs = sum(p["seconds"] for p in pts)
        samples = w * h * sum(p["spp"] for p in pts)
        r["mse_seconds"] = mse_seconds(pts, levels)
        r["slope"] = loglog_slope([p["spp"] for p in pts], [p["rmse"] for p in pts])
        r["samples_per_second"] = samples / secs if secs > 0 else None
        r["mse_at_top_spp"] = float(np.mean([p["rmse"] ** 2 for p in pts if p["spp"] == top]))
        r["lookups_per_sample"] = sum(p["counters"]["lookups"] for p in pts) / samples
        r["guards"] = guard_totals(pts)
    plain = next(r for r in report["results"] if r["label"] == PLAIN)
    for r in report["results"]:
        r["relative_efficiency"] = _ratio(plain["mse_seconds"], r["mse_seconds"])
        r["mse_ratio_at_top_spp"] = _ratio(r["mse_at_top_spp"], plain["mse_at_top_spp"])
        r["samples_per_second_ratio"] = _ratio(r["samples_per_second"],
                                               plain["samples_per_second"])
    return report


def _ratio(a, b):
    return a / b if a is not None and b else None


def run_scene(scene, labels, spp_levels, reference_spp, repeats=3, backend="opencl",
              device=None, log=print, table=None):
    """The report of one scene (see the module docstring): resolution, levels, skipped
    switches with reasons, and one result row per configuration with its points."""
    configs, skipped = configurations(scene, labels, table)
    log(f"  {len(configs)} configurations: " + ", ".join(label for label, _ in configs)
        + (f" ({len(skipped)} switches skipped)" if skipped else ""))
    points = _measure(scene, configs, spp_levels, reference_spp, repeats, backend, device, log)
    report = {"scene": scene.file, "resolution": list(scene.camera.resolution),
              "spp_levels": list(spp_levels), "reference_spp": reference_spp,
              "repeats": repeats, "backend": backend, "skipped": skipped,
              "results": [{"label": label, "render": keys, "points": points[label]}
                          for label, keys in configs]}
    return summarise(report)


def scene_names(reports):
    """A short column name per scene report: the file name, the path where two clash."""
    base = [os.path.basename(str(r["scene"])) for r in reports]
    return [b if base.count(b) == 1 else str(r["scene"]) for b, r in zip(base, reports)]


def combined(reports, labels):
    """{switch label: {scene name: relative efficiency, or None where skipped}}."""
    names = scene_names(reports)
    out = {}
    for label in labels:
        out[label] = {}
        for name, rep in zip(names, reports):
            row = [r for r in rep["results"] if r["label"] == label]
            out[label][name] = row[0]["relative_efficiency"] if row else None
    return out


def run(scenes, labels, spp_levels, reference_spp, repeats=3, backend="opencl", device=None,
        log=print, table=None):
    """Benchmark every scene; the full report: per-scene reports and the combined table."""
    reports = []
    for scene in scenes:
        w, h = scene.camera.resolution
        log(f"{scene.file}: {w}x{h}, spp {list(spp_levels)} x {repeats}")
        reports.append(run_scene(scene, labels, spp_levels, reference_spp, repeats, backend,
                                 device, log, table))
    return {"benchmark": "variance", "switches": list(labels), "scenes": reports,
            "combined": combined(reports, labels)}


def _num(v, fmt):
    return "-" if v is None else format(v, fmt)


def print_scene(report, log=print):
    """One scene's table: samples/s, MSE at the top spp and MSE x s, each against plain."""
    w, h = report["resolution"]
    top = max(report["spp_levels"])
    log(f"\n{report['scene']} ({w}x{h}, spp {report['spp_levels']} x {report['repeats']}, "
        f"reference {report['reference_spp']} spp, {report['backend']}); rel. efficiency = "
        f"(MSE x s)_plain / (MSE x s): > 1 is better")
    log(f"  {'configuration':16s} {'samples/s':>10s} {'x plain':>8s} {f'MSE@{top}':>10s} "
        f"{'x plain':>8s} {'MSE x s':>10s} {'rel. eff.':>9s} {'slope':>6s}")
    for r in report["results"]:
        log(f"  {r['label']:16s} {_num(r['samples_per_second'], '10.0f'):>10s} "
            f"{_num(r['samples_per_second_ratio'], '8.3f'):>8s} "
            f"{r['mse_at_top_spp']:10.3e} {_num(r['mse_ratio_at_top_spp'], '8.3f'):>8s} "
            f"{_num(r['mse_seconds'], '10.3e'):>10s} "
            f"{_num(r['relative_efficiency'], '9.3f'):>9s} {_num(r['slope'], '6.2f'):>6s}")
    for label, why in report["skipped"].items():
        log(f"  {label:16s} skipped: {why}")
    bad = [r for r in report["results"] if any(r["guards"].values())]
    if bad:
        log("  guard counters (capped, dropped, over majorant): " + "; ".join(
            f"{r['label']}: {r['guards']}" for r in bad))


def print_combined(full, log=print):
    """Relative efficiency of every switch (rows) on every scene (columns)."""
    table = full["combined"]
    names = scene_names(full["scenes"])
    width = max([12] + [len(n) for n in names])
    log("\nrelative efficiency against plain ((MSE x s)_plain / (MSE x s); > 1 is better, "
        "- = skipped, or no error measured above the reference's noise)")
    log(f"  {'switch':16s} " + " ".join(f"{n:>{width}s}" for n in names))
    for label, row in table.items():
        log(f"  {label:16s} " + " ".join(f"{_num(row[n], '.3f'):>{width}s}" for n in names))
