"""Random scenes against an independent renderer: ``python -m volmc.bench.sweep``.

The shipped tests check each feature on scenes written for it. This sweep checks their
combinations on scenes nobody wrote: each case draws a scene at random (camera, one to three
media with grids or constant densities, placements, phase functions, colour-dependent
extinction and albedo, lights of every type) together with volmc's own choices that must not
change the expected image (the transmittance estimator, majorant, free flight, spectral
mode, sampler, roulette, splitting, equiangular sampling, grid storage, lane width), and
compares the image with one rendered independently:

- ``--against mitsuba``: Mitsuba 3's ``volpath`` through ``volmc peer``'s translation (the
  per-pixel t-test and image-mean test of volmc/peers/compare.py). Scenes stay inside what
  Mitsuba renders: no emission, sun discs, spot blends, panoramic cameras, overlapping media.
- ``--against cycles``: Blender Cycles through ``volmc peer cycles`` (needs ``bpy``). Scenes
  stay inside its translation: emission by a radiance field, overlapping media and
  panoramas, but only constant skies, suns and point lights.
- ``--against reference``: the Numba reference (float64, another seed), with everything
  volmc has: emission by field or temperature and the collision and MIS modes of emission
  sampling (not light sampling alone, whose variance is unbounded in scattering emitters), sun
  discs, blended spots, panoramic cameras, overlapping media (the z-tests of
  ``volmc.check.compare_images``).

Every comparison is a test at the 1 % level, so about one case in a hundred fails by chance:
a failing case is rendered again at four times the samples with new seeds ("chance" when it
then agrees). Where it fails again in some pixels while the image means agree, it is
rendered once more at 16 times the samples ("rare events" when it then agrees: see
CONFIRM). Only a case that fails at every rung is reported as a disagreement, "DIFFER".
Each case prints its seed and its scene, so ``--case SEED`` renders it again.
"""

import argparse
import os
import sys
import time
from collections import namedtuple

import numpy as np

from ..resources import scenes_dir

def _estimators(chromatic):
    """The render.transmittance values an image comparison can hold volmc to (unbiased,
    usable in grids), those for colour-dependent extinction when ``chromatic``."""
    from ..techniques import ESTIMATORS
    return tuple(e.name for e in ESTIMATORS.values()
                 if e.unbiased and not e.homogeneous_only and (e.chromatic or not chromatic))


#: What each target renders, so that its scenes stay inside it: emission ("radiance": by a
#: radiance field only), sun discs, spot blends, panoramic cameras, overlapping media (with
#: "phase_mix", each its own phase function; Cycles mixes them by one weight for all
#: channels, volmc by each channel's sigma_s), and the light types.
ALL_LIGHTS = ("environment", "map", "directional", "point", "spot", "sphere")
TARGETS = {
    "reference": dict(emission="all", sun_disc=True, blend=True, panoramic=True,
                      overlap=True, phase_mix=True, lights=ALL_LIGHTS),
    "mitsuba": dict(emission=None, sun_disc=False, blend=False, panoramic=False,
                    overlap=False, phase_mix=True, lights=ALL_LIGHTS),
    "cycles": dict(emission="radiance", sun_disc=False, blend=False, panoramic=True,
                   overlap=True, phase_mix=False, lights=("environment", "directional",
                                                          "point")),
}


def _rgb(rng, lo, hi, grey_p=0.5):
    if rng.random() < grey_p:
        v = float(rng.uniform(lo, hi))
        return [v, v, v]
    return [float(x) for x in rng.uniform(lo, hi, 3)]


def _unit(rng):
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _blobs(rng, shape):
    """A smooth, lumpy density in [0, 1] on ``shape`` [z, y, x]: a few Gaussian blobs, with
    empty corners, so majorant cells differ and some are empty."""
    nz, ny, nx = shape
    z, y, x = np.meshgrid((np.arange(nz) + 0.5) / nz, (np.arange(ny) + 0.5) / ny,
                          (np.arange(nx) + 0.5) / nx, indexing="ij")
    d = np.zeros(shape)
    for _ in range(int(rng.integers(2, 6))):
        c = rng.uniform(0.2, 0.8, 3)
        r = rng.uniform(0.08, 0.3)
        d += rng.uniform(0.3, 1.0) * np.exp(-((x - c[0]) ** 2 + (y - c[1]) ** 2 +
                                               (z - c[2]) ** 2) / (2 * r * r))
    if rng.random() < 0.5:          # voxel-scale noise: sharp edges inside majorant cells
        d *= rng.uniform(0.5, 1.0, shape)
    return (d / d.max()).astype(np.float32)


def _density(rng):
    kind = rng.random()
    if kind < 0.3:
        return float(rng.uniform(0.2, 2.0))
    if kind < 0.55:
        return {"generator": "cloud", "resolution": int(rng.integers(12, 33)),
                "seed": int(rng.integers(0, 1000))}
    return _blobs(rng, tuple(int(n) for n in rng.integers(6, 25, 3)))


#: Half-extents of a medium's box are drawn in [0.3, 0.9] per axis.
HALF = (0.3, 0.9)
#: Centres of media kept apart (targets without overlapping media) are this far apart:
#: more than two of the largest spheres that hold a turned, stretched box.
APART = 4.5
#: Least distance of a point, spot or sphere light from any medium's bounding sphere.
LIGHT_MARGIN = 0.1
#: Largest stretch a medium's transform draws; its world box stays inside the sphere of
#: radius STRETCH |half| about its centre.
STRETCH = 1.4


def _transform(rng, centre):
    """A turn, stretch or mirror about the box's centre, which stays where it was drawn
    (a transform acts about the world origin, so translate = c - R S c)."""
    from ..scene.transform import rotation
    t, m = {}, np.eye(3)
    if rng.random() < 0.5:
        s = rng.uniform(0.6, STRETCH, 3) if rng.random() < 0.5 else \
            [rng.uniform(0.6, STRETCH)] * 3
        s = [float(v) for v in s]
        if rng.random() < 0.2:
            s[int(rng.integers(3))] *= -1.0          # a mirror
        t["scale"] = s
        m = np.diag(s)
    if rng.random() < 0.7:
        t["rotate"] = [*(float(v) for v in _unit(rng)), float(rng.uniform(-180, 180))]
        m = rotation(t["rotate"][:3], t["rotate"][3]) @ m
    if t:
        t["translate"] = [float(v) for v in np.asarray(centre) - m @ np.asarray(centre)]
    return t


def _medium(rng, centre, half, chroma, emission, temperature):
    m = {"bounds": [[float(c - h) for c, h in zip(centre, half)],
                    [float(c + h) for c, h in zip(centre, half)]],
         "density": _density(rng),
         "albedo": _rgb(rng, 0.3, 1.0, grey_p=0.6)}
    if rng.random() < 0.4:
        m["albedo"] = [1.0, 1.0, 1.0] if rng.random() < 0.5 else m["albedo"]
    k = float(rng.uniform(1.0, 8.0)) / max(half)
    m["scale"] = [k * c for c in chroma] if chroma else k
    if rng.random() < 0.6:
        m["phase"] = {"type": "hg", "g": float(rng.uniform(-0.8, 0.85))}
    if rng.random() < 0.4:
        t = _transform(rng, centre)
        if t:
            m["transform"] = t
    if emission:
        shape = tuple(int(n) for n in rng.integers(6, 17, 3))
        field = _blobs(rng, shape)
        if not temperature or rng.random() < 0.5:
            m["emission"] = {"radiance": _rgb(rng, 0.5, 4.0), "field": field}
        else:
            m["emission"] = {"temperature": field, "remap": [0.2, 1.0, 800.0, 2200.0],
                             "scale": float(rng.uniform(0.5, 3.0)) * 1e-3}
        m["albedo"] = [min(a, 0.9) for a in m["albedo"]]
    return m


def _outside(pos, spheres, margin):
    """``pos`` moved radially out of every sphere (centre, radius) it is within ``margin``
    of. A point-like light inside a scattering medium gives distance-sampled next-event
    estimates unbounded variance (1/d^2 at the vertices near it), so no per-pixel test
    could judge the images. Where overlapping spheres push it back and forth, it goes out
    along its own direction from the origin, beyond them all."""
    pos = np.asarray(pos, float)
    for _ in range(8):
        moved = False
        for c, r in spheres:
            d = pos - c
            n = np.linalg.norm(d)
            if n < r + margin:
                pos = c + (d / n if n > 1e-9 else np.array([0.0, 1.0, 0.0])) * (r + margin)
                moved = True
        if not moved:
            return pos
    # Rounding alone can keep "moving" a point that sits on a sphere: that one is out.
    if all(np.linalg.norm(pos - c) >= r + margin - 1e-9 for c, r in spheres):
        return pos
    reach = max(np.linalg.norm(c) + r + margin for c, r in spheres)
    n = np.linalg.norm(pos)
    return (pos / n if n > 1e-9 else np.array([0.0, 1.0, 0.0])) * reach


def _lights(rng, cap, spread, spheres):
    lights = []
    kinds = list(cap["lights"])
    for kind in rng.choice(kinds, size=int(rng.integers(1, min(3, len(kinds)) + 1)),
                           replace=False):
        if kind == "environment":
            lights.append({"type": "environment", "radiance": _rgb(rng, 0.1, 1.0)})
        elif kind == "map":
            lights.append({"type": "environment", "file": str(scenes_dir() / "maps" /
                                                              "sunrise.exr"),
                           "strength": float(rng.uniform(0.3, 1.5)),
                           "rotation": float(rng.uniform(-180, 180))})
        elif kind == "directional":
            d = {"type": "directional", "direction": [float(v) for v in _unit(rng)],
                 "irradiance": _rgb(rng, 0.5, 4.0)}
            if cap["sun_disc"] and rng.random() < 0.5:
                d["angle"] = float(rng.uniform(0.5, 20.0))
            lights.append(d)
        else:
            pos = _unit(rng) * spread * rng.uniform(0.6, 1.6)
            radius = float(rng.uniform(0.1, 0.5)) if kind == "sphere" else 0.0
            pos = _outside(pos, spheres, LIGHT_MARGIN + radius)
            if kind == "point":
                lights.append({"type": "point", "position": [float(v) for v in pos],
                               "intensity": _rgb(rng, 2.0, 20.0)})
            elif kind == "spot":
                s = {"type": "spot", "position": [float(v) for v in pos],
                     "direction": [float(v) for v in -pos / np.linalg.norm(pos) +
                                   0.3 * _unit(rng)],
                     "intensity": _rgb(rng, 5.0, 40.0), "angle": float(rng.uniform(10, 70))}
                if cap["blend"] and rng.random() < 0.5:
                    s["blend"] = float(rng.uniform(0.0, 1.0))
                lights.append(s)
            else:
                lights.append({"type": "sphere", "position": [float(v) for v in pos],
                               "radius": radius,
                               "radiance": _rgb(rng, 1.0, 10.0)})
    # A scene with a map has one environment light: the map replaces a constant sky.
    if any("file" in lt for lt in lights):
        lights = [lt for lt in lights if lt["type"] != "environment" or "file" in lt]
    return lights


def random_scene(seed, target="reference"):
    """(scene dict for ``scene_from_dict``, lane width) of case ``seed``, kept to what
    ``target`` (a key of TARGETS) renders."""
    cap = TARGETS[target]
    rng = np.random.default_rng([seed, list(TARGETS).index(target)])
    n_media = int(rng.choice([1, 1, 2, 3]))
    chroma = None
    if rng.random() < 0.3:
        chroma = [float(v) for v in rng.uniform(0.3, 1.0, 3)]
    emission = cap["emission"] is not None and rng.random() < 0.4
    media, centres, spheres = [], [], []
    for i in range(n_media):
        half = rng.uniform(*HALF, 3)
        if not cap["overlap"]:   # apart, so no two boxes can overlap whatever their turn
            centre = np.array([APART * (i - (n_media - 1) / 2), 0.0, 0.0]) + \
                rng.uniform(-.1, .1, 3)
        else:
            centre = rng.uniform(-0.6, 0.6, 3) * (n_media > 1)
        centres.append(centre)
        spheres.append((centre, STRETCH * float(np.linalg.norm(half))))
        media.append(_medium(rng, centre, half, chroma,
                             emission and (i == 0 or rng.random() < 0.5),
                             cap["emission"] == "all"))
    if not cap["phase_mix"]:
        for m in media[1:]:
            m.pop("phase", None)
            if "phase" in media[0]:
                m["phase"] = dict(media[0]["phase"])
    spread = 1.5 + (0.6 if cap["overlap"] else APART / 2) * (n_media - 1)
    cam = {"resolution": [int(rng.integers(12, 25)), int(rng.integers(12, 25))]}
    r = rng.random()
    if r < 0.12:    # inside the first medium's box
        cam["eye"] = [float(v) for v in centres[0] + rng.uniform(-0.1, 0.1, 3)]
        cam["target"] = [float(v) for v in centres[0] + _unit(rng)]
        cam["fov"] = float(rng.uniform(40, 90))
    else:
        eye = _unit(rng) * spread * rng.uniform(1.8, 3.0)
        cam["eye"] = [float(v) for v in eye]
        cam["target"] = [float(v) for v in rng.uniform(-0.3, 0.3, 3)]
        if r < 0.3:
            cam["type"] = "orthographic"
            cam["size"] = float(spread * rng.uniform(1.2, 2.0))
        elif r < 0.4 and cap["panoramic"]:
            cam["type"] = "panoramic"
        else:
            cam["fov"] = float(np.degrees(2 * np.arctan(spread / np.linalg.norm(eye))) *
                               rng.uniform(0.9, 1.4))
            if rng.random() < 0.2:
                cam["aperture"] = float(rng.uniform(0.01, 0.08))
    up = _unit(rng) if rng.random() < 0.2 else np.array([0.0, 1.0, 0.0])
    view = np.array(cam["target"]) - np.array(cam["eye"])
    if abs(np.dot(up, view)) > 0.95 * np.linalg.norm(view):
        up = np.array([1.0, 0.0, 0.0]) if abs(view[0]) < 0.5 * np.linalg.norm(view) else \
            np.array([0.0, 0.0, 1.0])
    cam["up"] = [float(v) for v in up]
    lights = _lights(rng, cap, spread, spheres)
    # Mitsuba's copy of a map blends along volmc's texel edges (peers/mitsuba.py,
    # ENVMAP_WIDTH): pixels that see the map directly, without noise, differ by up to 0.1 %
    # of the image mean, far beyond its standard error. So the Mitsuba target hides a map
    # from the camera (it still lights the media), or, where that would hide a sphere light
    # too (hide_emitters), draws a constant sky instead.
    hide_map = False
    if target == "mitsuba" and any("file" in lt for lt in lights):
        if any(lt["type"] == "sphere" for lt in lights):
            lights = [{"type": "environment", "radiance": [0.5 * lt["strength"]] * 3}
                      if "file" in lt else lt for lt in lights]
        else:
            hide_map = True
    transmittances = _estimators(chroma is not None)
    render = {
        "max_depth": int(rng.choice([1, 2, 4, 8, 16, -1])),
        "rr_depth": int(rng.integers(0, 6)),
        "transmittance": str(rng.choice(transmittances)),
        "majorant": str(rng.choice(["grid", "grid", "global", "octree"])),
        "free_flight": str(rng.choice(["delta", "decomposition"])),
        "spectral": str(rng.choice(["hero", "tracking", "channel"])),
        "grid_storage": str(rng.choice(["auto", "dense", "bricks"])),
        "mis": str(rng.choice(["balance", "power"])),
        "sampler": str(rng.choice(["independent", "stratified", "sobol"])),
        "light_samples": int(rng.choice([1, 1, 2, 3])),
        "equiangular": bool(rng.random() < 0.3),
        "rr": str(rng.choice(["throughput", "albedo"])),
        # Uniform directions towards a map with a sun (sunrise.exr's is 2 texels of 18,000)
        # are heavy-tailed: a pixel's few sun hits carry it, and no affordable spp gives the
        # per-pixel test a trustworthy variance. Uniform sampling is swept on constant skies.
        "env_sampling": str(rng.choice(["importance", "importance", "uniform"])
                            if not any("file" in lt for lt in lights) else "importance"),
        "env_compensation": bool(rng.random() < 0.3),
        # Mitsuba's hide_emitters would hide a sphere light too, which volmc shows.
        "transparent_background": bool(rng.random() < 0.15 and (
            target != "mitsuba" or all(lt["type"] != "sphere" for lt in lights))) or hide_map,
        "seed": int(rng.integers(0, 2**32)),
    }
    if rng.random() < 0.3:
        render["majorant_resolution"] = [int(v) for v in rng.integers(1, 6, 3)]
    if emission:
        # Not "light": alone, it has unbounded variance at a vertex inside an emitter (its
        # 1/d^2 is not cancelled, docs/emission_sampling.md), and the emitters here scatter,
        # so no per-pixel test can judge it (case 505 against Cycles: pixels at z = 6.6).
        render["emission_sampling"] = str(rng.choice(["collision", "mis"]))
    scene = {"camera": cam, "lights": lights, "render": render}
    if n_media == 1 and rng.random() < 0.5:
        scene["medium"] = media[0]
    else:
        scene["media"] = media
    return scene, int(rng.choice([1, 4, 8, 16]))


def describe(raw, lanes):
    """One line naming what case ``raw`` exercises."""
    media = raw.get("media") or [raw["medium"]]
    parts = []
    for m in media:
        d = m["density"]
        kind = ("const" if isinstance(d, float) else "cloud" if isinstance(d, dict) else
                "grid" + "x".join(str(n) for n in d.shape[::-1]))
        extra = [k for k in ("transform", "emission") if k in m]
        parts.append(kind + ("+" + "+".join(extra) if extra else ""))
    r = raw["render"]
    lights = ",".join(lt["type"] if "file" not in lt else "map" for lt in raw["lights"])
    cam = raw["camera"].get("type", "perspective")[:5]
    opts = [r["transmittance"], r["majorant"], r["free_flight"], r["spectral"], r["sampler"],
            f"depth{r['max_depth']}", f"ls{r['light_samples']}"]
    opts += [k for k in ("equiangular", "env_compensation", "transparent_background")
             if r[k]]
    if "emission_sampling" in r:
        opts.append("em=" + r["emission_sampling"])
    return f"[{' '.join(parts)}] {cam} lights={lights} W={lanes} " + " ".join(opts)


def _scene(raw):
    from ..scene import scene_from_dict
    return scene_from_dict({k: v for k, v in raw.items()}, file="<sweep>")


def _with_lanes(lanes, fn):
    old = os.environ.get("VOLMC_LANES")
    os.environ["VOLMC_LANES"] = str(lanes)
    try:
        return fn()
    finally:
        if old is None:
            os.environ.pop("VOLMC_LANES")
        else:
            os.environ["VOLMC_LANES"] = old


#: One comparison: whether it passed, whether the image means alone agree, its summary line.
Run = namedtuple("Run", "passed means_agree summary")


def compare_peer(name, scene, spp, lanes, seed_offset=0):
    """The Run of volmc against peer ``name`` on ``scene``."""
    from ..peers import compare_with_peer
    from ..peers.compare import Agreement
    if seed_offset:
        scene = scene.with_render(seed=(scene.render.seed + seed_offset) % 2**64)
    report, _ = _with_lanes(lanes, lambda: compare_with_peer(
        name, scene, spp=spp, reference_spp=0, log=lambda *a: None))
    agr = Agreement(**{k: v for k, v in report["agreement"].items() if k != "passed"})
    return Run(agr.passed, agr.means_agree, agr.summary(name.capitalize()))


def compare_reference(scene, spp, lanes, seed_offset=0):
    """The Run of the OpenCL kernels at ``lanes`` against the Numba reference, rendered
    with another seed."""
    from ..check import compare_images
    from ..render import render, whole
    sa = scene.with_render(seed=(scene.render.seed + seed_offset) % 2**64)
    sb = scene.with_render(seed=(scene.render.seed + seed_offset + 1) % 2**64)
    a = whole(render(sa, backend="opencl", spp=spp, progress=False, lanes=lanes))
    b = whole(render(sb, backend="numba", spp=spp, progress=False))
    c = compare_images(a.film.mean(), a.film.variance_of_mean(), b.film.mean(),
                       b.film.variance_of_mean(), dof_a=a.film.spp - 1, dof_b=b.film.spp - 1)
    capped = a.counters.get("capped", 0) + b.counters.get("capped", 0)
    return Run(c.passed and capped == 0, c.means_agree and capped == 0,
               c.summary() + (f"; capped {capped}" if capped else ""))


#: A case that fails is rendered again at these multiples of its spp (new seeds each time).
#: The second rung catches rare events: pixels carried by events a few hundred samples
#: usually miss (a track-length shadow ray through a thick box, which is 0 or the whole
#: light; the far side of a dense box lit from behind, reached by distance sampling with
#: probability exp(-tau)). A render that misses them sits many of its own standard errors
#: below the truth there, which no sample variance shows. Mitsuba's shadow rays through a
#: homogeneous box are track-length estimates, so it meets this more often than volmc.
CONFIRM = (4, 16)


def run_case(seed, against, spp, log=print):
    """Draw case ``seed``, compare it, confirm a failure; returns a dict for the record.

    Outcomes: "agree"; "chance" (failed, then agreed at 4x spp with new seeds); "rare
    events" (failed per pixel twice with image means agreeing, then agreed at 16x spp:
    CONFIRM); "DIFFER" (failed at every rung); "untranslatable" (outside the peer's
    translation); "refused" (not a valid scene)."""
    from ..peers.errors import PeerUnavailable
    from ..scene.errors import SceneError
    raw, lanes = random_scene(seed, against)
    line = describe(raw, lanes)
    if against == "reference":
        compare = compare_reference
    else:
        def compare(scene, spp, lanes, seed_offset=0):
            return compare_peer(against, scene, spp, lanes, seed_offset)
    t0 = time.perf_counter()
    try:
        scene = _scene(raw)
        run = compare(scene, spp, lanes)
        outcome, summary = "agree", run.summary
        for rung, factor in enumerate(CONFIRM):
            if run.passed or (rung > 0 and not run.means_agree):
                break
            run = compare(scene, factor * spp, lanes, seed_offset=1000 * (rung + 1))
            summary += f" | again at {factor}x spp: " + run.summary
            outcome = ("chance" if rung == 0 else "rare events") if run.passed else "DIFFER"
    except PeerUnavailable as e:
        outcome, summary = "untranslatable", str(e)
    except SceneError as e:
        outcome, summary = "refused", str(e)
    sec = time.perf_counter() - t0
    log(f"case {seed}: {outcome:>14} {sec:6.1f} s  {line}")
    if outcome not in ("agree",):
        log(f"    {summary}")
    return {"seed": seed, "outcome": outcome, "seconds": sec, "case": line,
            "summary": summary}


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m volmc.bench.sweep", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--against", choices=tuple(TARGETS), default="mitsuba")
    ap.add_argument("--cases", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0, help="first case's seed")
    ap.add_argument("--case", type=int, action="append", help="run only this case seed")
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--json", help="write the record here")
    args = ap.parse_args(argv)
    seeds = args.case or range(args.seed, args.seed + args.cases)
    records = []
    for s in seeds:
        records.append(run_case(s, args.against, args.spp))
        sys.stdout.flush()
    counts = {}
    for r in records:
        counts[r["outcome"]] = counts.get(r["outcome"], 0) + 1
    print("outcomes: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    if args.json:
        from ..outputs import write_json
        write_json(args.json, {"against": args.against, "spp": args.spp, "cases": records},
                   indent=1)
    return 1 if counts.get("DIFFER") else 0


if __name__ == "__main__":
    sys.exit(main())
