"""The cost of several media (issue 22): ``python -m volmc.bench.media``.

Two families of scenes built from the default cloud, rendered by OpenCL at the device's lane
width, configurations alternating round by round (each round starting one later) so that the
machine's drift falls on all alike:

* **overlap N** (N = 1, 2, 4, 8): the cloud as N media in the same box, each with 1/N of
  the extinction. The coefficients add, so every N renders the same image in expectation:
  the ratios are the price of N overlapping media (N lookups per tentative collision, N
  walks merged into one segment sequence).
* **apart K** (K = 1, 2, 4, 8): the cloud and K - 1 copies far below it, which no camera
  ray and almost no shadow ray crosses. The figure to reach: the cost per sample follows
  the media a ray crosses (one), not the media in the scene (K).

Per configuration: samples per second, density lookups per sample, the per-sample variance
(the film's variance of the mean times spp, averaged over pixels and channels) and the cost
at equal error, seconds per sample x per-sample variance, as a ratio to the first
configuration of its family (below 1 is faster).
"""

import argparse

import numpy as np

from . import report_main
from ..resources import default_scene
from ..scene.loading import read_toml, scene_from_dict

FAMILY_SIZES = (1, 2, 4, 8)


def overlap_scene(base, n):
    """The default cloud as n media in one box, each with 1/n of the extinction."""
    med = base["medium"]
    media = [dict(med, scale=med.get("scale", 1.0) / n) for _ in range(n)]
    return _with_media(base, media)


def apart_scene(base, k):
    """The default cloud and k - 1 copies 30 units and more below it (off every camera ray;
    the sun's shadow rays go up, away from them)."""
    med = base["medium"]
    media = [med] + [dict(med, transform={"translate": [4.0 * j, -30.0 - 4.0 * j, 0.0]})
                     for j in range(1, k)]
    return _with_media(base, media)


def _with_media(base, media):
    raw = {k: v for k, v in base.items() if k != "medium"}
    raw["media"] = media
    return raw


def run(resolution=(128, 128), spp=16, rounds=3, sizes=FAMILY_SIZES, device=None, lanes=None,
        log=print):
    """The report: per family, per configuration, the figures of the module docstring."""
    from ..backends.opencl import OpenCLBackend
    from .convergence import timed_render
    base = read_toml(default_scene())
    base["camera"]["resolution"] = list(resolution)
    path = str(default_scene())
    configs = {}
    for n in sizes:
        configs[f"overlap {n}"] = overlap_scene(base, n)
    for k in sizes:
        configs[f"apart {k}"] = apart_scene(base, k)
    backends = {}
    for name, raw in configs.items():
        scene = scene_from_dict(raw, file=path, base_dir=str(default_scene().parent))
        be = OpenCLBackend(scene, device=device, lanes=lanes)
        be.warm_up()
        backends[name] = be
        log(f"built {name}: {len(scene.media)} media, W = {be.lanes}")
    w, h = resolution
    acc = {name: {"seconds": 0.0, "samples": 0, "lookups": 0, "var": []} for name in configs}
    order = list(backends.items())
    for r in range(rounds):
        # Each round starts one configuration later, so none always runs first.
        k = r % len(order)
        for name, be in order[k:] + order[:k]:
            mean, sec, cnt = timed_render(be, w, h, r * spp, spp)
            a = acc[name]
            a["seconds"] += sec
            a["samples"] += w * h * spp
            a["lookups"] += cnt["lookups"]
        log(f"round {r + 1}/{rounds} done")
    # Per-sample variance from one more render per configuration, same spp and seed.
    from ..film import Film
    for name, be in backends.items():
        film = Film(w, h)
        be.render(10**6, spp, film)
        film.spp = spp
        acc[name]["var"] = float(np.mean(film.variance_of_mean()[..., :3]) * spp)
        acc[name]["mean"] = float(np.mean(film.mean()[..., :3]))
    report = {"resolution": list(resolution), "spp_per_round": spp, "rounds": rounds,
              "lanes": next(iter(backends.values())).lanes, "families": {}}
    for family in ("overlap", "apart"):
        rows = []
        for n in sizes:
            a = acc[f"{family} {n}"]
            sps = a["samples"] / a["seconds"]
            rows.append({"media": n, "samples_per_second": sps,
                         "lookups_per_sample": a["lookups"] / a["samples"],
                         "variance_per_sample": a["var"], "image_mean": a["mean"],
                         "cost_at_equal_error": a["var"] / sps})
        first = rows[0]
        for row in rows:
            row["speed_vs_one"] = row["samples_per_second"] / first["samples_per_second"]
            row["cost_vs_one"] = row["cost_at_equal_error"] / first["cost_at_equal_error"]
        report["families"][family] = rows
    return report


def print_report(report, log=print):
    log(f"several media: default cloud at {report['resolution'][0]}x{report['resolution'][1]},"
        f" W = {report['lanes']}, {report['rounds']} alternating rounds of "
        f"{report['spp_per_round']} spp")
    for family, rows in report["families"].items():
        log(f"\n{family}: media | samples/s | vs 1 | lookups/sample | variance/sample | "
            "cost at equal error vs 1")
        for row in rows:
            log(f"  {row['media']} | {row['samples_per_second']:.0f} | "
                f"{row['speed_vs_one']:.3f}x | {row['lookups_per_sample']:.1f} | "
                f"{row['variance_per_sample']:.4g} | {row['cost_vs_one']:.3f}")


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m volmc.bench.media", description=__doc__.split(
        "\n\n")[0])
    p.add_argument("--resolution", type=int, nargs=2, default=(128, 128))
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--lanes", type=int, default=None)
    p.add_argument("--json", default=None, help="write the report here")
    a = p.parse_args(argv)
    report_main(lambda: run(tuple(a.resolution), a.spp, a.rounds, lanes=a.lanes), print_report, a.json)


if __name__ == "__main__":
    main()
