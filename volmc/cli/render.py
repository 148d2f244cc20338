"""``volmc render``: a scene (or a frame sequence) to EXR, and a PNG preview."""

import os
import sys
import time

from ..distributed import ClusterError
from ..scene.errors import SceneError
from .common import (EXIT_INTERRUPTED, add_cluster_options, add_defines_option,
                     add_lanes_option, add_scene_argument, check_opencl_choices, check_writable,
                     dask_session, exposure, nonnegative_seconds, seed, spp_count)


def add_render_parser(sub):
    from ..backends import BACKENDS
    from ..film import TONE_OPERATORS
    from ..render import CHECKPOINT_EVERY
    r = sub.add_parser("render", help="render a scene to EXR (and PNG)")
    add_scene_argument(r)
    r.add_argument("-o", "--output", help="EXR path (default: <scene name>.exr here)")
    r.add_argument("--spp", type=spp_count, help="samples per pixel (overrides render.spp)")
    r.add_argument("--seed", type=seed, help="random seed (overrides render.seed)")
    r.add_argument("--backend", choices=BACKENDS, default=BACKENDS[0],
                   help="render backend (default opencl; numba is the float64 reference)")
    r.add_argument("--device", help="OpenCL device as PLATFORM[:DEVICE] (index or name "
                                    "substring; default: $VOLMC_CL_DEVICE, else PoCL)")
    add_lanes_option(r)
    add_defines_option(r, "override a scene key (repeatable), e.g. -D medium.albedo=0.9")
    r.add_argument("--png", nargs="?", const=True, default=None, metavar="PATH",
                   help="also write a tonemapped sRGB PNG preview (default path: EXR name with "
                        ".png); on by default when no scene is given")
    r.add_argument("--exposure", type=exposure, default=0.0,
                   help="PNG exposure in stops (default 0)")
    r.add_argument("--tonemap", choices=TONE_OPERATORS, default="filmic",
                   help="PNG tone curve (default filmic)")
    r.add_argument("--variance", action="store_true",
                   help="also write <output>.var.exr: per-pixel variance of the mean")
    r.add_argument("--denoise", action="store_true",
                   help="also write a denoised preview, <output>.denoised.exr (and "
                        ".denoised.png with --png), by Intel Open Image Denoise guided by an "
                        "albedo AOV the render accumulates; the unbiased EXR is unchanged "
                        "(pip install 'volmc[denoise]')")
    r.add_argument("--quiet", action="store_true", help="no progress bar and no summary")
    r.add_argument("--stats", action="store_true",
                   help="print samples/s, path length, lookups and guard counters")
    add_cluster_options(r, "render")
    r.add_argument("--checkpoint", metavar="FILE",
                   help="write the accumulated samples to FILE (atomically) every "
                        "--checkpoint-every seconds and at the end")
    r.add_argument("--checkpoint-every", type=nonnegative_seconds, default=None,
                   metavar="SECONDS", help=f"checkpoint interval in seconds (default "
                                           f"{CHECKPOINT_EVERY:g}; "
                                           "with --checkpoint or --resume)")
    r.add_argument("--resume", metavar="FILE",
                   help="continue the render saved in checkpoint FILE to the requested spp "
                        "(it must be of the same scene, seed, sampler and backend); "
                        "checkpoints go on to FILE unless --checkpoint says otherwise")
    r.add_argument("--frames", metavar="FIRST-LAST[:STEP]",
                   help="render a frame sequence: the scene once per frame, its grid file "
                        "patterns ({frame:04d}) filled in, to <name>.0001.exr, ...; frames "
                        "whose EXR is complete are skipped (e.g. 1-48, 1-48:2, 7)")
    return r


def _announce_start():
    # Printed once the backend is ready and Ctrl-C keeps the samples rendered so far.
    print("volmc: started (Ctrl-C stops after the current chunk and writes the partial image)",
          file=sys.stderr, flush=True)


def cmd_render(args):
    from ..film import variance_path, write_exr, write_png
    from ..render import CHECKPOINT_EVERY, render
    from ..scene import load_scene
    from ..scene.serialize import to_toml

    scene_path, out, png = _render_paths(args)
    defines = _render_defines(args)
    if args.denoise:   # a missing denoiser fails before anything is rendered
        from ..denoise import oidn
        oidn()
    if args.frames is not None:
        return cmd_render_frames(args, scene_path, out, png, defines)
    scene = load_scene(scene_path, defines)

    _check_render_device(args)
    if args.resume and not os.path.isfile(args.resume):   # before the "rendering" line
        from ..checkpoint import missing
        raise missing(args.resume)
    checkpoint = args.checkpoint or args.resume
    if args.checkpoint_every is not None and not checkpoint:
        raise SceneError("command line", "--checkpoint-every", "needs --checkpoint FILE or "
                         "--resume FILE: without one nothing is written")
    if checkpoint:
        check_writable(checkpoint, "--checkpoint" if args.checkpoint else "--resume")
        from ..checkpoint import refuse_overwrite
        refuse_overwrite(checkpoint, args.resume, "command line", "--checkpoint", "--resume ")
        # Real paths: a checkpoint reached through a link to the EXR was accepted, and the
        # partial image of a Ctrl-C then overwrote the samples it held.
        if os.path.realpath(checkpoint) in [os.path.realpath(p) for p, _ in
                                            _outputs(args, out, png)]:
            raise SceneError("command line", "--checkpoint", f"{checkpoint} is also an "
                             "image this render writes")
    from ..memory import check_memory
    # A render that cannot fit fails now.
    check_memory(scene, args.backend, args.device, albedo=args.denoise)
    if not args.quiet:
        w, h = scene.camera.resolution
        print(f"volmc: rendering {scene_path} ({w}x{h}, {scene.render.spp} spp, "
              f"backend {args.backend})", file=sys.stderr, flush=True)
    _warn_out_of_view(scene, scene_path)
    failure = None
    with dask_session(args) as client:
        # By name: the driver reads a --resume checkpoint (and refuses a wrong one) before
        # it builds and compiles the backend.
        try:
            res = render(scene, backend=args.backend, progress=False if args.quiet else None,
                         on_start=None if args.quiet else _announce_start,
                         checkpoint=checkpoint,
                         checkpoint_every=(CHECKPOINT_EVERY if args.checkpoint_every is None
                                           else args.checkpoint_every), resume=args.resume,
                         client=client, device=args.device, lanes=args.lanes,
                         albedo=args.denoise)
        except ClusterError as e:
            # The samples merged before the cluster failed are written as after Ctrl-C (the
            # checkpoint by the driver, the partial image below), then the one-line error.
            if e.result is None:
                raise _cluster_error(args, e.reason) from None
            failure, res = e, e.result
    meta = res.metadata()
    meta["scene"] = os.path.abspath(scene_path)
    meta["scene_toml"] = to_toml(scene.spec)
    _write_or_rescue(out, res.film.rgba(), meta)
    denoised = []
    try:   # after the EXR: nothing rendered is lost if one of these fails
        if args.variance:
            write_exr(variance_path(out), res.film.variance_of_mean(), meta)
        if png:
            write_png(png, res.image, args.exposure, args.tonemap,
                      alpha=res.alpha if scene.render.transparent_background else None)
        if args.denoise:
            from ..denoise import write_denoised
            denoised = write_denoised(res.film, meta, out, png or None, args.exposure,
                                      args.tonemap, scene.render.transparent_background)
    except (OSError, RuntimeError) as e:
        raise SceneError("command line", "-o", f"{out} is written, but not all of the files "
                         f"beside it: {e}") from None

    if failure is not None:
        kept = f"the {res.film.spp} spp rendered are in {out} (marked partial)"
        if checkpoint:
            kept += f" and {checkpoint}: continue with --resume {checkpoint}"
        elif res.film.spp:
            kept += " (--checkpoint FILE would keep them for --resume)"
        raise _cluster_error(args, f"{failure.reason}; {kept}")
    if not args.quiet:
        if res.film.spp > scene.render.spp:
            print(f"volmc: note: {args.resume} held {res.film.spp} spp already, more than the "
                  f"{scene.render.spp} asked; the image has them all", file=sys.stderr)
        state = "interrupted, partial image" if res.partial else "done"
        print(f"volmc: {state}: {_summary(out, png, res, scene)}", file=sys.stderr)
        if denoised:
            print(f"volmc: denoised preview: {' + '.join(denoised)}", file=sys.stderr)
    _report(args, res)
    return EXIT_INTERRUPTED if res.partial else 0


def _cluster_error(args, reason):
    """The one-line error of a Dask cluster that failed (distributed.ClusterError)."""
    return SceneError("command line", "--workers" if args.workers else "--scheduler",
                      f"the Dask cluster failed: {reason}")


def _write_or_rescue(out, rgba, meta):
    """The EXR at ``out``, checked writable before the render; should writing it fail all the
    same, the image is rescued (film.rescue_exr) and the one-line error names the copy."""
    from ..film import rescue_exr, write_exr
    try:
        write_exr(out, rgba, meta)
    except (OSError, RuntimeError) as e:
        raise SceneError("command line", "-o", rescue_exr(out, e, rgba, meta)) from None


def _outputs(args, out, png):
    """(path, flag) of every file ``volmc render`` writes for EXR ``out`` and PNG ``png``
    (or None), the flag that asks for it."""
    from ..frames import CLI_KEYS, render_outputs
    files = render_outputs(out, png, args.variance, args.denoise)
    return [(path, CLI_KEYS[role][1]) for role, path in files[-1:] + files[:-1]]   # EXR first


def _render_paths(args):
    """(scene path, EXR path, PNG path or None) of ``volmc render``, the outputs checked."""
    from ..resources import default_scene
    use_default = args.scene is None
    scene_path = str(default_scene()) if use_default else args.scene
    if not os.path.lexists(scene_path):   # before the outputs named after it are checked
        raise SceneError(scene_path, "", "scene file not found")
    stem = os.path.splitext(os.path.basename(scene_path))[0]
    out = args.output or f"{stem}.exr"
    png = args.png   # None, True (--png alone: beside the EXR) or a path
    if png is None and use_default:
        png = True
    if png is True:
        png = os.path.splitext(out)[0] + ".png"
    if not out.lower().endswith(".exr"):   # the render is float: an EXR, a PNG beside it
        raise SceneError("command line", "-o", f"expected a path ending in .exr, got {out!r} "
                                               "(--png writes a PNG preview as well)")
    check_writable(out, "-o")
    if png:
        if not png.lower().endswith(".png"):   # the image writer picks the format by suffix
            raise SceneError("command line", "--png", f"expected a path ending in .png, got "
                                                      f"{png!r}")
        check_writable(png, "--png")
    if args.frames is None:   # the EXR and PNG are checked above
        for path, flag in _outputs(args, out, png):
            if flag in ("--variance", "--denoise"):
                check_writable(path, flag)
    return scene_path, out, png


def _render_defines(args):
    """The -D overrides of ``volmc render`` with --spp and --seed appended."""
    defines = list(args.defines)
    if args.spp is not None:
        defines.append(f"render.spp={args.spp}")
    if args.seed is not None:
        defines.append(f"render.seed={args.seed}")
    return defines


def _check_render_device(args):
    if args.backend == "opencl":
        check_opencl_choices(args.device, args.lanes)
    elif args.lanes is not None:   # as the API's lanes= (the numba backend has no lanes)
        raise SceneError("command line", "--lanes", "a lane width applies to the opencl "
                                                    "backend only")


def _warn_out_of_view(scene, scene_path, prefix=""):
    from ..visibility import medium_in_view
    if not medium_in_view(scene):
        print(f"volmc: warning: {scene_path}: {prefix}medium: no camera ray reaches the medium "
              "box; the image shows only the background", file=sys.stderr)


def _summary(out, png, res, scene):
    """"out.exr + out.png (WxH, N spp, backend, T s)" of a finished render."""
    w, h = scene.camera.resolution
    return (f"{out}{' + ' + png if png else ''} ({w}x{h}, {res.film.spp} spp, {res.backend}, "
            f"{res.seconds:.2f} s)")


def _report(args, res, prefix=""):
    """--stats, and the guard warnings (``prefix``: "frame 7: " in a sequence)."""
    if args.stats:
        if prefix:
            print(prefix.rstrip(": ") + ":")
        for k, v in res.stats().items():
            print(f"  {k:24s} {v:.6g}" if isinstance(v, float) else f"  {k:24s} {v}")
    # Guard "reported counters" (robustness case 10, 19, 20): a render that cut paths, dropped
    # samples or met extinction above its majorant says so even without --stats or with
    # --quiet (the counts are also in the EXR metadata): never a silent bias.
    for text in res.guard_warnings():
        print(f"volmc: warning: {prefix}{text}", file=sys.stderr)


def cmd_render_frames(args, scene_path, out, png, defines):
    """``volmc render --frames``: frames.render_sequence with the command line's output,
    progress and errors."""
    from ..api import RenderedImage
    from ..frames import FrameSequence, frame_path, parse_frames, render_sequence
    from ..render import render
    from ..scene.frames import describe
    from ..scene.loading import read_raw
    frames = parse_frames(args.frames)
    for flag in ("checkpoint", "resume", "checkpoint_every"):
        if getattr(args, flag) is not None:
            raise SceneError("command line", f"--{flag.replace('_', '-')}",
                             "a frame sequence resumes by "
                             "skipping its complete frames; --checkpoint and --resume are "
                             "for a single render")
    _check_render_device(args)
    seq = FrameSequence(read_raw(scene_path, defines), scene_path, None, frames)
    plan = seq.plan(out, args.backend, png, args.variance, args.denoise)
    for p in plan:   # every file of the frames to render or tone, before the first renders
        if not p.complete:
            for path, flag in _outputs(args, p.exr, png and frame_path(png, p.frame)):
                check_writable(path, flag)
        elif p.retone:
            check_writable(frame_path(png, p.frame), "--png")
    if not args.quiet:
        n_done = sum(p.complete for p in plan)
        print(f"volmc: rendering {scene_path}, {describe(seq.frames)} ({len(plan)} frames, "
              f"{n_done} complete; backend {args.backend})", file=sys.stderr, flush=True)
    started = []

    def on_start():
        if not started:
            started.append(True)
            _announce_start()

    def render_one(scene, label):
        _warn_out_of_view(scene, scene_path, label + ": ")
        try:
            res = render(scene, backend=args.backend, progress=False if args.quiet else None,
                         on_start=None if args.quiet else on_start, client=client,
                         device=args.device, lanes=args.lanes, label=label,
                         albedo=args.denoise)
        except ClusterError as e:   # (render_sequence writes a partial frame, then raises)
            raise ClusterError(e.reason, None if e.result is None else
                               RenderedImage(e.result, scene)) from None
        return RenderedImage(res, scene)

    t = time.perf_counter()
    done = skipped = 0
    with dask_session(args) as client:
        try:
            for fr in render_sequence(seq, plan, render_one, png, args.variance,
                                      args.exposure, args.tonemap, args.denoise):
                head = f"frame {fr.index}/{fr.count} ({fr.frame})"
                if fr.image is None:
                    skipped += 1
                    if not args.quiet:
                        print(f"volmc: {head}: {fr.exr} is complete, skipped",
                              file=sys.stderr)
                    continue
                done += 1
                res = fr.image.result
                if not args.quiet:
                    state = "interrupted, partial image" if res.partial else "done"
                    written = _summary(fr.exr, png and frame_path(png, fr.frame), res,
                                       fr.image.scene)
                    print(f"volmc: {head}: {state}: {written}", file=sys.stderr, flush=True)
                _report(args, res, f"frame {fr.frame}: ")
                if res.partial:
                    return EXIT_INTERRUPTED
        except ClusterError as e:
            again = "" if e.result is None else "; run the command again to render it"
            raise _cluster_error(args, e.reason + again) from None
    if not args.quiet:
        print(f"volmc: done: {len(seq.frames)} frames, {done} rendered, {skipped} complete "
              f"already ({time.perf_counter() - t:.2f} s)", file=sys.stderr)
    return 0
