"""Peer renderers for cross-checks: ``volmc peer mitsuba|cycles SCENE``.

``compare_with_peer`` renders a scene with volmc (OpenCL) and a peer (Mitsuba 3's
``volpath``, volmc/peers/mitsuba.py; Blender Cycles, volmc/peers/cycles.py) at the same spp
and reports (a) agreement (mean and per-pixel z-scores with both variances) and (b) speed:
each renderer's time and RMSE against a high-spp volmc reference, and the equal-error time
ratio. A peer's time is its tracing time: for Cycles, whose every render syncs the scene
first (seconds for a grid), the sync is reported apart.

Every peer module has ``probe()`` (its version, or PeerUnavailable saying why it cannot
run), ``check_translatable(scene)``, optionally ``caveats(scene)`` (notes on what the peer
is known to render wrongly in a scene it translates) and a renderer class whose ``render(spp, seed,
passes)`` returns (mean, variance of the mean, seconds, [passes, 3] pass image means).
"""

import importlib

from .errors import PeerUnavailable

#: peer name: (display name, module, renderer class)
PEERS = {"mitsuba": ("Mitsuba", "mitsuba", "MitsubaRenderer"),
         "cycles": ("Cycles", "cycles", "CyclesRenderer")}


def peer_module(name):
    return importlib.import_module(f".{PEERS[name][1]}", __name__)


def available(name, scene=None):
    """(version, None) when peer ``name`` runs here (and translates ``scene``), else
    (None, the reason)."""
    mod = peer_module(name)
    try:
        version = mod.probe()
        if scene is not None:
            mod.check_translatable(scene)
        return version, None
    except PeerUnavailable as e:
        return None, str(e)


def make_renderer(name, scene):
    mod = peer_module(name)
    return getattr(mod, PEERS[name][2])(scene)


def compare_with_peer(name, scene, spp=None, passes=16, reference_spp=None, device=None,
                      log=print):
    """Agreement and speed report (a dict) of volmc against peer ``name`` on ``scene``, and
    the images {"volmc", name, "reference"} with "volmc.var" and name + ".var", the two
    renders' variances of the mean.

    spp: samples per pixel of both test renders (default: the scene's). passes: the peer
    renders in this many independent launches, whose spread gives its per-pixel variance.
    reference_spp: samples per pixel of the volmc reference for RMSE (default 8 * spp; 0 skips
    the speed part)."""
    from ..backends import make_backend
    from ..render import render, whole
    from . import compare

    title = PEERS[name][0]
    mod = peer_module(name)
    version = mod.probe()
    mod.check_translatable(scene)
    spp = spp or scene.render.spp
    reference_spp = 8 * spp if reference_spp is None else reference_spp
    seed = scene.render.seed
    passes = max(2, min(passes, spp))
    peer = make_renderer(name, scene)
    log(f"volmc against {title} {version} ({peer.mode}): {spp} spp each, {title} in "
        f"{passes} passes")
    try:
        peer.warm_up()
        be = make_backend("opencl", scene, device)
        be.warm_up()
        rv = whole(render(scene, backend=be, spp=spp, progress=False))
        mean_v, var_v = rv.film.mean(), rv.film.variance_of_mean()
        log(f"  volmc: {rv.seconds:8.2f} s")

        mean_p, var_p, sec_p, pass_means = peer.render(spp, seed=seed + 7, passes=passes)
        sync = getattr(peer, "last_sync_seconds", None)
        log(f"  {title}: {sec_p:8.2f} s" + ("" if sync is None else
                                            f" tracing, {sync:.2f} s scene sync"))
        agr = compare.agreement(mean_v, var_v, mean_p, var_p, pass_means, peer.last_low)
        log("  " + agr.summary(title))
        notes = mod.caveats(scene) if hasattr(mod, "caveats") else []
        for note in notes:
            log(f"  note: {note}")
        report = {"peer": name, "peer_version": version, f"{name}_version": version,
                  "peer_mode": peer.mode, f"{name}_mode": peer.mode, "spp": spp,
                  "passes": passes, "agreement": {**agr.__dict__, "passed": agr.passed},
                  "caveats": notes,
                  "volmc": {"seconds": rv.seconds, "mean": agr.mean_volmc},
                  name: {"seconds": sec_p, "mean": agr.mean_peer}}
        if sync is not None:
            report[name]["sync_seconds"] = sync
        # Each renderer's variance of the mean beside its image (volmc's from its samples,
        # the peer's from its passes): what the per-pixel test weighed.
        images = {"volmc": mean_v, name: mean_p, "volmc.var": var_v, f"{name}.var": var_p}

        if reference_spp:
            sr = scene.with_render(seed=(seed + 2) % 2**64)
            ref = whole(render(sr, backend=make_backend("opencl", sr, device),
                               spp=reference_spp, progress=False))
            ref_mean, ref_var = ref.film.mean(), ref.film.variance_of_mean()
            images["reference"] = ref_mean
            # The peer's single-launch speed (its passes above include per-launch costs).
            mean_s, _, sec_s, _ = peer.render(spp, seed=seed + 3)
            e_v = compare.rmse_to_reference(mean_v, ref_mean, ref_var)
            e_p = compare.rmse_to_reference(mean_s, ref_mean, ref_var)
            ratio = compare.equal_error_time_ratio(rv.seconds, e_v, sec_s, e_p)
            report["reference_spp"] = reference_spp
            report["volmc"].update(rmse=e_v)
            report[name].update(rmse=e_p, seconds_single_launch=sec_s)
            report["equal_error_time_ratio"] = ratio
            log(f"  speed at {spp} spp against a {reference_spp}-spp volmc reference "
                f"(reference noise removed):")
            log(f"    volmc: {rv.seconds:8.2f} s, RMSE {e_v:.5f}")
            log(f"    {title}: {sec_s:8.2f} s, RMSE {e_p:.5f}")
            log(f"    {title} needs {ratio:.2f}x volmc's time to reach the same RMSE"
                if ratio is not None else "    volmc's image is exact (RMSE 0): no time ratio")
    finally:
        if hasattr(peer, "close"):
            peer.close()
    return report, images

