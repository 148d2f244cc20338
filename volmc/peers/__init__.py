"""Peer renderers for cross-checks: ``volmc peer mitsuba SCENE``.

``compare_with_mitsuba`` renders a scene with volmc (OpenCL) and Mitsuba 3 (``volpath``) at
the same spp and reports (a) agreement (mean and per-pixel z-scores with both variances) and
(b) speed: each renderer's time and RMSE against a high-spp volmc reference, and the
equal-error time ratio.
"""


def compare_with_mitsuba(scene, spp=None, passes=16, reference_spp=None, device=None,
                         log=print):
    """Agreement and speed report (a dict) of volmc against Mitsuba 3 on ``scene``.

    spp: samples per pixel of both test renders (default: the scene's). passes: Mitsuba
    renders in this many independent launches, whose spread gives its per-pixel variance.
    reference_spp: samples per pixel of the volmc reference for RMSE (default 8 * spp; 0 skips
    the speed part)."""
    from ..backends import make_backend
    from ..render import render
    from . import compare
    from .mitsuba import MitsubaRenderer, probe

    version = probe()
    spp = spp or scene.render.spp
    reference_spp = 8 * spp if reference_spp is None else reference_spp
    seed = scene.render.seed
    passes = max(2, min(passes, spp))
    peer = MitsubaRenderer(scene)
    log(f"volmc against Mitsuba {version} ({peer.mode}, llvm): {spp} spp each, Mitsuba in "
        f"{passes} passes")
    peer.warm_up()
    be = make_backend("opencl", scene, device)
    be.warm_up()
    rv = render(scene, backend=be, spp=spp, progress=False)
    mean_v, var_v = rv.film.mean(), rv.film.variance_of_mean()
    log(f"  volmc:   {rv.seconds:8.2f} s")

    mean_p, var_p, sec_p, pass_means = peer.render(spp, seed=seed + 7, passes=passes)
    log(f"  Mitsuba: {sec_p:8.2f} s")
    agr = compare.agreement(mean_v, var_v, mean_p, var_p, pass_means, spp)
    log("  " + agr.summary("Mitsuba"))
    report = {"mitsuba_version": version, "mitsuba_mode": peer.mode, "spp": spp,
              "passes": passes,
              "agreement": {**agr.__dict__, "passed": agr.passed},
              "volmc": {"seconds": rv.seconds, "mean": agr.mean_volmc},
              "mitsuba": {"seconds": sec_p, "mean": agr.mean_peer}}
    images = {"volmc": mean_v, "mitsuba": mean_p}

    if reference_spp:
        sr = scene.with_render(seed=(seed + 2) % 2**64)
        ref = render(sr, backend=make_backend("opencl", sr, device), spp=reference_spp,
                     progress=False)
        ref_mean, ref_var = ref.film.mean(), ref.film.variance_of_mean()
        images["reference"] = ref_mean
        # Mitsuba's single-launch speed (its passes above include per-launch overhead).
        mean_s, _, sec_s, _ = peer.render(spp, seed=seed + 3)
        e_v = compare.rmse_to_reference(mean_v, ref_mean, ref_var)
        e_p = compare.rmse_to_reference(mean_s, ref_mean, ref_var)
        ratio = compare.equal_error_time_ratio(rv.seconds, e_v, sec_s, e_p)
        report["reference_spp"] = reference_spp
        report["volmc"].update(rmse=e_v)
        report["mitsuba"].update(rmse=e_p, seconds_single_launch=sec_s)
        report["equal_error_time_ratio"] = ratio
        log(f"  speed at {spp} spp against a {reference_spp}-spp volmc reference "
            f"(reference noise removed):")
        log(f"    volmc:   {rv.seconds:8.2f} s, RMSE {e_v:.5f}")
        log(f"    Mitsuba: {sec_s:8.2f} s, RMSE {e_p:.5f}")
        log(f"    Mitsuba needs {ratio:.2f}x volmc's time to reach the same RMSE")
    return report, images
