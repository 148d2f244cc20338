"""Lane widths against each other (``volmc bench lanes``): samples per second and time to
equal error of the OpenCL renderer at W = 1, 4, 8 and 16 paths per work-item, on every
shipped scene with its own techniques.

Each scene goes through the speed-against-error machinery of ``volmc bench render``
(convergence.py): one configuration per width, renders alternating over an spp ladder,
RMSE against an independent high-spp reference. Every width traces the same paths with the
same random numbers (tests/test_lanes.py), so the error per sample is the same and the time
to equal error is the time per sample; the RMSE is still measured, so the report shows it.
Per width the report also gives the lanes' occupancy (the mean fraction of lanes active
per iteration of the walk loop) and, on grids, the density lookups per second as a fraction
of the lookup ceiling at the same width (lookups.py).
"""

from ..cl.lanes import LANE_WIDTHS
from . import convergence as cv


def default_scene_paths():
    """Every shipped scene: the default cloud, the homogeneous one, the gallery, the
    benchmark scenes and the analytic test scenes."""
    from ..resources import scenes_dir
    root = scenes_dir()
    return ([root / "cloud.toml", root / "homogeneous.toml"]
            + sorted((root / "gallery").glob("*.toml")) + sorted((root / "bench").glob("*.toml"))
            + sorted((root / "tests").glob("*.toml")))


def run_scene(scene, widths=LANE_WIDTHS, spp_levels=(4, 16), reference_spp=256, repeats=2,
              device=None, ceiling=True, log=print):
    """The convergence report of one scene at each lane width, with ``summary``: per width,
    samples/s, MSE x seconds, the time to equal error and the speed against W = widths[0],
    the occupancy and the fraction of the lookup ceiling."""
    own = scene.render
    configs = [cv.Config("opencl", own.majorant, own.free_flight, own.transmittance, lanes=w)
               for w in widths]
    ceil = {}
    if ceiling and scene.grid is not None:
        if len(scene.spec.media) > 1:
            # The ceiling reads one grid along camera rays (lookups.py); several placed
            # media have no single grid to read, so such a scene gets no fraction of it.
            log(f"lookup ceiling: none for a scene of {len(scene.spec.media)} media")
        else:
            from .lookups import lookup_ceiling
            for w in widths:
                ceil[f"opencl W{w}"] = lookup_ceiling(scene, ("opencl",), device=device,
                                                      lanes=w)["opencl"]
    report = cv.run(scene, configs, spp_levels, reference_spp, repeats, device, ceil, log=log)
    rows = {r["lanes"]: r for r in report["results"]}
    base = rows[widths[0]]
    report["summary"] = [{
        "lanes": w, "samples_per_second": rows[w]["samples_per_second"],
        "mse_seconds": rows[w]["mse_seconds"],
        "speed_vs_first": rows[w]["samples_per_second"] / base["samples_per_second"],
        "time_to_equal_error_vs_first": rows[w]["mse_seconds"] / base["mse_seconds"],
        "lane_occupancy": rows[w].get("lane_occupancy"),
        "lookups_per_sample": rows[w].get("lookups_per_sample"),
        "fraction_of_lookup_ceiling": rows[w].get("fraction_of_lookup_ceiling"),
        "rmse_last": rows[w]["points"][-1]["rmse"],
        "gathers": rows[w].get("gathers"),
    } for w in widths]
    return report


def print_summary(path, report, log=print):
    """One table per scene."""
    w, h = report["resolution"]
    gathers = sorted({s["gathers"] for s in report["summary"] if s.get("gathers")})
    log(f"\n{path} ({w}x{h}, spp {report['spp_levels']} x {report['repeats']}, reference "
        f"{report['reference_spp']} spp"
        + (f", gathers: {', '.join(gathers)}" if gathers else "") + ")")
    log(f"  {'W':>3s} {'samples/s':>11s} {'speed':>7s} {'time to equal error':>20s} "
        f"{'occupancy':>10s} {'of ceiling':>11s} {'RMSE':>10s}")
    for s in report["summary"]:
        occ = s["lane_occupancy"]
        frac = s["fraction_of_lookup_ceiling"]
        tee = s["time_to_equal_error_vs_first"]
        # A scene rendered without noise (RMSE 0 at every spp) has no time to equal error.
        tee = f"{tee:19.2f}x" if tee == tee else f"{'none (RMSE 0)':>20s}"
        log(f"  {s['lanes']:3d} {s['samples_per_second']:11.0f} {s['speed_vs_first']:6.2f}x "
            f"{tee} "
            f"{'' if occ is None else f'{100 * occ:9.0f}%':>10s} "
            f"{'' if frac is None else f'{100 * frac:10.1f}%':>11s} {s['rmse_last']:10.3e}")
