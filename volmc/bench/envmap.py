"""What environment-map sampling gains (issue 23): ``python -m volmc.bench.envmap``.

A scene lit by an environment map (by default the gallery's cloud under the HDR sunrise,
whose sun is in the map) rendered by OpenCL at the device's lane width with the map's
directions drawn four ways: uniformly over the sphere, by importance (luminance x
sin theta) with the balance heuristic, with the power heuristic, and with MIS compensation
(Karlik et al. 2019). Configurations alternate round by round (each round starting one
later), and each accumulates its own film over the rounds (each round continues its sample
indices), so the per-sample variance is estimated from every sample it rendered.

Per configuration: samples per second, the per-sample variance (the film's variance of the
mean times spp, averaged over pixels and channels) and the cost at equal error, seconds per
sample x per-sample variance, as a ratio to uniform sampling's (below 1 is better: the
fraction of uniform sampling's time that reaches its error). Every configuration is
unbiased, so equal variance is equal error; tests/test_environment.py checks that they
render the same image.
"""

import argparse
import time
from pathlib import Path

import numpy as np

from . import report_main
from ..film import Film
from ..resources import scenes_dir
from ..scene.loading import load_scene

CONFIGS = {
    "uniform": {"render.env_sampling": "uniform"},
    "importance": {},
    "importance, power heuristic": {"render.mis": "power"},
    "importance, compensated": {"render.env_compensation": True},
}


def _scene_path(path):
    return Path(path) if path is not None else scenes_dir() / "gallery" / "sunrise.toml"


def run(scene_path=None, resolution=(96, 96), spp=32, rounds=4, lanes=None, log=print):
    """The report: per configuration, the figures of the module docstring."""
    from ..backends.opencl import OpenCLBackend
    from .convergence import batch_schedule
    path = _scene_path(scene_path)
    w, h = resolution
    backends, films, secs = {}, {}, {}
    for name, keys in CONFIGS.items():
        over = dict(keys, **{"camera.resolution": [w, h]})
        sc = load_scene(path, over)
        be = OpenCLBackend(sc, lanes=lanes)
        be.warm_up()
        backends[name], films[name], secs[name] = be, Film(w, h), 0.0
        log(f"built {name}: W = {be.lanes}")
    order = list(backends)
    for r in range(rounds):
        k = r % len(order)
        for name in order[k:] + order[:k]:
            be, film = backends[name], films[name]
            t = time.perf_counter()
            for n in batch_schedule(w * h, spp):
                be.render(film.spp, n, film)
                film.spp += n
            secs[name] += time.perf_counter() - t
        log(f"round {r + 1}/{rounds} done")
    rows = []
    for name in order:
        film = films[name]
        sps = w * h * film.spp / secs[name]
        var = float(np.mean(film.variance_of_mean()[..., :3]) * film.spp)
        rows.append({"config": name, "samples_per_second": sps, "variance_per_sample": var,
                     "image_mean": float(np.mean(film.mean()[..., :3])),
                     "cost_at_equal_error": var / sps})
    for row in rows:
        row["cost_vs_uniform"] = row["cost_at_equal_error"] / rows[0]["cost_at_equal_error"]
    return {"scene": str(path), "resolution": list(resolution), "spp_per_round": spp,
            "rounds": rounds, "lanes": backends[order[0]].lanes, "configs": rows}


def print_report(report, log=print):
    log(f"environment-map sampling: {Path(report['scene']).name} at "
        f"{report['resolution'][0]}x{report['resolution'][1]}, W = {report['lanes']}, "
        f"{report['rounds']} alternating rounds of {report['spp_per_round']} spp")
    log("config | samples/s | variance/sample | image mean | cost at equal error vs uniform")
    for row in report["configs"]:
        log(f"  {row['config']} | {row['samples_per_second']:.0f} | "
            f"{row['variance_per_sample']:.4g} | {row['image_mean']:.4f} | "
            f"{row['cost_vs_uniform']:.3g}")


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m volmc.bench.envmap",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("scene", nargs="?", default=None)
    p.add_argument("--resolution", type=int, nargs=2, default=(96, 96))
    p.add_argument("--spp", type=int, default=32)
    p.add_argument("--rounds", type=int, default=4)
    p.add_argument("--lanes", type=int, default=None)
    p.add_argument("--json", default=None, help="write the report here")
    a = p.parse_args(argv)
    report_main(lambda: run(a.scene, tuple(a.resolution), a.spp, a.rounds, lanes=a.lanes), print_report, a.json)


if __name__ == "__main__":
    main()
