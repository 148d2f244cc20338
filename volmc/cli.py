"""Command line: ``volmc render``, ``check``, ``peer``, ``bench``, ``convert``, ``info``.

Bad input (scene files, grids, flag values) prints one line
``volmc: error: <file>: <key>: <what is wrong>`` and exits with status 2, no traceback.
Ctrl-C during a render writes what was accumulated (marked partial) and exits 130.
"""

import argparse
import contextlib
import math
import os
import sys
import time

from .scene.errors import SceneError

EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error (no usage dump) and exit status 2."""

    def error(self, message):
        raise SceneError("command line", "", message)


def _positive_int(text):
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {v}")
    return v


def _nonnegative_seconds(text):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not (v >= 0.0 and math.isfinite(v)):
        raise argparse.ArgumentTypeError(f"must be a finite number of seconds >= 0, got {v}")
    return v


def _add_cluster_options(parser, what):
    """--workers N | --scheduler ADDRESS (rendering on Dask; see _dask_session)."""
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=_positive_int, metavar="N",
                       help=f"{what} on a new local Dask cluster of N worker processes "
                            "(needs volmc[dask])")
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help=f"{what} on the running Dask scheduler at ADDRESS, e.g. "
                            "tcp://10.0.0.1:8786 (its workers need volmc installed)")


def _seed(text):
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer in [0, 2^64), got {text!r}") \
            from None
    if not 0 <= v < 2**64:
        raise argparse.ArgumentTypeError(f"must be in [0, 2^64), got {v}")
    return v


def _finite_float(text):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if v != v or v in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return v


def _exposure(text):
    v = _finite_float(text)
    if abs(v) > 100.0:   # 2 ** exposure must stay a finite float
        raise argparse.ArgumentTypeError(f"must be in [-100, 100] stops, got {text!r}")
    return v


def _ladder_arguments(p, repeats, levels="4,16,64", reference_spp=1024):
    """--spp-levels, --reference-spp and --repeats of the speed-against-error benchmarks."""
    p.add_argument("--spp-levels", default=levels,
                   help=f"comma-separated samples per pixel of the timed renders (default "
                        f"{levels})")
    p.add_argument("--reference-spp", type=_positive_int, default=reference_spp,
                   help=f"samples per pixel of the reference (default {reference_spp})")
    p.add_argument("--repeats", type=_positive_int, default=repeats,
                   help=f"passes over the spp ladder (default {repeats})")


def _lanes(text):
    from .cl.lanes import check_lanes
    return check_lanes(text)


def _add_lanes_option(parser):
    parser.add_argument("--lanes", type=_lanes, metavar="W",
                        help="OpenCL paths per work-item, 1, 4, 8 or 16 (default: $VOLMC_LANES, "
                             "else the device's preferred float vector width)")


def build_parser():
    from .backends import BACKENDS
    from .cl.lanes import LANE_WIDTHS
    p = _Parser(prog="volmc", description="Monte Carlo volume path tracer")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)

    r = sub.add_parser("render", help="render a scene to EXR (and PNG)")
    r.add_argument("scene", nargs="?", help="scene .toml (default: the bundled cloud scene)")
    r.add_argument("-o", "--output", help="EXR path (default: <scene name>.exr here)")
    r.add_argument("--spp", type=_positive_int, help="samples per pixel (overrides render.spp)")
    r.add_argument("--seed", type=_seed, help="random seed (overrides render.seed)")
    r.add_argument("--backend", choices=BACKENDS, default=BACKENDS[0],
                   help="render backend (default opencl; numba is the float64 reference)")
    r.add_argument("--device", help="OpenCL device as PLATFORM[:DEVICE] (index or name "
                                    "substring; default: $VOLMC_CL_DEVICE, else PoCL)")
    _add_lanes_option(r)
    r.add_argument("-D", dest="defines", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a scene key (repeatable), e.g. -D medium.albedo=0.9")
    r.add_argument("--png", nargs="?", const="", default=None, metavar="PATH",
                   help="also write a tonemapped sRGB PNG preview (default path: EXR name with "
                        ".png); on by default when no scene is given")
    r.add_argument("--exposure", type=_exposure, default=0.0,
                   help="PNG exposure in stops (default 0)")
    r.add_argument("--tonemap", choices=("filmic", "clamp"), default="filmic",
                   help="PNG tone curve (default filmic)")
    r.add_argument("--variance", action="store_true",
                   help="also write <output>.var.exr: per-pixel variance of the mean")
    r.add_argument("--quiet", action="store_true", help="no progress bar and no summary")
    r.add_argument("--stats", action="store_true",
                   help="print samples/s, path length, lookups and guard counters")
    _add_cluster_options(r, "render")
    r.add_argument("--checkpoint", metavar="FILE",
                   help="write the accumulated samples to FILE (atomically) every "
                        "--checkpoint-every seconds and at the end")
    r.add_argument("--checkpoint-every", type=_nonnegative_seconds, default=60.0,
                   metavar="SECONDS", help="checkpoint interval in seconds (default 60)")
    r.add_argument("--resume", metavar="FILE",
                   help="continue the render saved in checkpoint FILE to the requested spp "
                        "(it must be of the same scene, seed, sampler and backend); "
                        "checkpoints go on to FILE unless --checkpoint says otherwise")
    r.add_argument("--frames", metavar="FIRST-LAST[:STEP]",
                   help="render a frame sequence: the scene once per frame, its grid file "
                        "patterns ({frame:04d}) filled in, to <name>.0001.exr, ...; frames "
                        "whose EXR is complete are skipped (e.g. 1-48, 1-48:2, 7)")

    k = sub.add_parser("check", help="render a scene with two backends and compare the images "
                                     "(per-pixel z-test)")
    k.add_argument("scene", nargs="?", help="scene .toml (default: the bundled cloud scene)")
    k.add_argument("--spp", type=_positive_int, help="samples per pixel for both renders")
    k.add_argument("--backends", default="opencl,numba", help="two backends (default "
                                                               "opencl,numba)")
    k.add_argument("--device", help="OpenCL device (as for render)")
    k.add_argument("-D", dest="defines", action="append", default=[],
                   metavar="SECTION.KEY=VALUE", help="override a scene key (repeatable)")

    inf = sub.add_parser("info", help="list OpenCL platforms and devices and the kernel "
                                      "cache, or the grids of a .vdb / .nvdb file")
    inf.add_argument("file", nargs="?", help="an OpenVDB or NanoVDB file: list its grids")

    pe = sub.add_parser("peer", help="render a scene with volmc and with a peer renderer "
                                     "(Mitsuba 3, Blender Cycles): agreement and speed "
                                     "against error")
    pe.add_argument("peer", choices=["mitsuba", "cycles"], help="the peer renderer")
    pe.add_argument("scene", nargs="?", help="scene .toml (default: the bundled cloud scene)")
    pe.add_argument("--spp", type=_positive_int, help="samples per pixel of both renders "
                                                      "(default: the scene's)")
    pe.add_argument("--passes", type=_positive_int, default=16,
                    help="the peer renders in this many independent launches, whose spread "
                         "gives its per-pixel variance (default 16)")
    pe.add_argument("--reference-spp", type=int, default=None,
                    help="samples per pixel of the volmc reference for RMSE (default 8 x spp; "
                         "0: agreement only)")
    pe.add_argument("--device", help="OpenCL device (as for render)")
    pe.add_argument("-D", dest="defines", action="append", default=[],
                    metavar="SECTION.KEY=VALUE", help="override a scene key (repeatable)")
    pe.add_argument("--json", help="write the report to this JSON file")
    pe.add_argument("--images", metavar="DIR",
                    help="write volmc.exr, PEER.exr (and reference.exr) into DIR")

    b = sub.add_parser("bench", help="benchmarks (speed of backends, builds, work-group sizes)")
    bsub = b.add_subparsers(dest="bench", required=True, parser_class=_Parser)
    bt = bsub.add_parser("transmittance", help="every transmittance estimator on 1-D profiles and "
                                               "on the segments a render traces: error against "
                                               "cost, and maps of which wins where")
    bt.add_argument("scenes", nargs="*", help="grid scenes whose recorded segments are replayed "
                                              "(default: the cloud, the plume and the scan)")
    bt.add_argument("--estimators", help="comma-separated subset (default: all)")
    bt.add_argument("--quick", action="store_true", help="a small sweep (seconds, for tests)")
    bt.add_argument("--rays", type=_positive_int, default=1024,
                    help="recorded camera and shadow segments replayed per grid scene "
                         "(default 1024 each; a quarter with --quick)")
    bt.add_argument("--json", help="write the full report to this JSON file")
    bt.add_argument("--figures", help="write PNG figures into this directory")
    bt.add_argument("--device", help="OpenCL device (as for render)")
    _add_cluster_options(bt, "run the sweep's cases")
    bt.add_argument("-D", dest="defines", action="append", default=[],
                    metavar="SECTION.KEY=VALUE", help="override a key of every scene")
    br = bsub.add_parser("render", help="RMSE against wall time for every configuration "
                                        "(backend x majorant x free flight x shadow estimator, "
                                        "and Mitsuba 3 when it runs)")
    br.add_argument("scene", nargs="?", help="scene .toml (default: the bundled cloud scene)")
    _add_cluster_options(br, "render volmc's configurations")
    br.add_argument("--backends", default="opencl,numba",
                    help="comma-separated volmc backends (default opencl,numba)")
    br.add_argument("--majorants", default="grid,global",
                    help="comma list of grid, global, octree (default grid,global)")
    br.add_argument("--spectral", default=None,
                    help="comma-separated render.spectral modes to compare (tracking, "
                         "channel; default: the scene's own)")
    br.add_argument("--free-flights", default="delta,decomposition",
                    help="default delta,decomposition")
    br.add_argument("--transmittances", default=None,
                    help="shadow-ray estimators (default: every unbiased grid estimator; "
                         "'scene' = the scene's own)")
    br.add_argument("--peer", choices=["mitsuba", "cycles", "all", "none", "auto"],
                    default="auto",
                    help="include peer renderers (auto: every one that can run; mitsuba, "
                         "cycles or all: required)")
    _ladder_arguments(br, repeats=1)
    br.add_argument("--device", help="OpenCL device (as for render)")
    br.add_argument("-D", dest="defines", action="append", default=[],
                    metavar="SECTION.KEY=VALUE", help="override a scene key (repeatable)")
    br.add_argument("--json", help="also write the report to this JSON file")
    br.add_argument("--plot", help="write the RMSE-against-time figure (PNG) here")
    br.add_argument("--no-ceiling", action="store_true",
                    help="skip the raw-lookup ceiling measurement")
    br.add_argument("--baseline", action="append", default=[], metavar="DIR",
                    help="also render with the volmc checkout in DIR (an earlier version, "
                         "OpenCL, the scene's own techniques); repeatable")
    bl = bsub.add_parser("lanes", help="samples/s and time to equal error per lane width "
                                       "(paths per work-item) on every shipped scene")
    bl.add_argument("scenes", nargs="*", help="scene files (default: every shipped scene)")
    bl.add_argument("--widths", default=",".join(map(str, LANE_WIDTHS)),
                    help="comma-separated lane widths (default 1,4,8,16)")
    _ladder_arguments(bl, repeats=2, levels="4,16", reference_spp=256)
    bl.add_argument("--device", help="OpenCL device (as for render)")
    bl.add_argument("-D", dest="defines", action="append", default=[],
                    metavar="SECTION.KEY=VALUE", help="override a key of every scene "
                                                      "(repeatable)")
    bl.add_argument("--no-ceiling", action="store_true",
                    help="skip the raw-lookup ceiling measurement")
    bl.add_argument("--json", help="also write the reports to this JSON file")
    bv = bsub.add_parser("variance", help="relative efficiency of each variance-reduction "
                                          "switch (sampler, light samples, MIS, equiangular, "
                                          "roulette) against the plain renderer")
    bv.add_argument("scenes", nargs="*", help="scene files (default: the cloud, "
                                              "scenes/bench/thin.toml and the lamp in fog)")
    bv.add_argument("--switches", default=None,
                    help="comma-separated subset of the switches (default: all)")
    _ladder_arguments(bv, repeats=3)
    bv.add_argument("--backend", choices=BACKENDS, default=BACKENDS[0],
                    help="backend of the timed renders (default opencl; the reference is "
                         "always OpenCL)")
    bv.add_argument("--device", help="OpenCL device (as for render)")
    bv.add_argument("-D", dest="defines", action="append", default=[],
                    metavar="SECTION.KEY=VALUE", help="override a key of every scene "
                                                      "(repeatable)")
    bv.add_argument("--json", help="also write the report (every point too) to this JSON file")
    bv.add_argument("--plot", help="write the RMSE-against-spp figure of the samplers (PNG) "
                                   "here")
    for name, helptext in (
            ("specialise", "samples/s of the scene's build against each feature switch on"),
            ("workgroup", "samples/s of the OpenCL kernel per work-group size")):
        bb = bsub.add_parser(name, help=helptext)
        bb.add_argument("scenes", nargs="*", help="scene files (default: "
                        + ("every shipped scene)" if name == "specialise" else "the cloud scene)"))
        bb.add_argument("--spp", type=_positive_int, default=4,
                        help="samples per pixel per timed batch (default 4)")
        bb.add_argument("--repeats", type=_positive_int, default=3,
                        help="timed batches per configuration; the median is reported")
        bb.add_argument("--device", help="OpenCL device (as for render)")
        bb.add_argument("-D", dest="defines", action="append", default=[],
                        metavar="SECTION.KEY=VALUE", help="override a scene key (repeatable)")
        bb.add_argument("--json", help="also write the figures to this JSON file")
        if name == "workgroup":
            bb.add_argument("--sizes", default="driver,1,2,4,8,16,32,64",
                            help="comma-separated work-group sizes ('driver' = driver's choice)")

    bs = bsub.add_parser("sparse", help="memory and lookup speed of brick (sparse) storage "
                                        "against the dense grid")
    bs.add_argument("--size", type=_positive_int, default=512, help="voxels per axis (512)")
    bs.add_argument("--fill", type=_finite_float, default=0.03,
                    help="fraction of active voxels (0.03)")
    bs.add_argument("--lookups", type=_positive_int, default=1 << 22,
                    help="lookups per timed launch")
    bs.add_argument("--repeats", type=_positive_int, default=5)
    bs.add_argument("--backends", default="opencl,numba")
    bs.add_argument("--device", help="OpenCL device (as for render)")
    bs.add_argument("--json", help="also write the figures to this JSON file")

    c = sub.add_parser("convert", help="convert a density grid between .npy, .npz and .vol")
    c.add_argument("input")
    c.add_argument("output")
    c.add_argument("--bounds", type=_finite_float, nargs=6,
                   metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
                   help="bounding box written into .vol headers (default: the input .vol's "
                        "box, else the unit cube)")
    return p


def _check_writable(path, flag, where="command line"):
    """Raise SceneError(where, flag, ...) unless ``path`` names a file in a writable
    directory."""
    if not path or path.endswith(("/", os.sep)) or os.path.isdir(path):
        raise SceneError(where, flag, f"expected a file path, got {path!r}")
    d = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(d):
        raise SceneError(where, flag, f"directory does not exist: {d}")
    if not os.access(d, os.W_OK):
        raise SceneError(where, flag, f"directory is not writable: {d}")


@contextlib.contextmanager
def _dask_session(args):
    """The Dask client of --workers or --scheduler (None without either), closed with the
    local cluster it started on leaving; a one-line error without Dask or when the scheduler
    cannot be reached (distributed.connect)."""
    if not (args.workers or args.scheduler):
        yield None
        return
    from .distributed import connect
    client, cluster = connect(args.workers, args.scheduler, "command line",
                              "--workers" if args.workers else "--scheduler")
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _announce_start():
    # Printed once the backend is ready and Ctrl-C keeps the samples rendered so far.
    print("volmc: started (Ctrl-C stops after the current chunk and writes the partial image)",
          file=sys.stderr, flush=True)


def cmd_render(args):
    from .film import write_exr, write_png
    from .render import render
    from .scene import load_scene
    from .scene.serialize import to_toml

    scene_path, out, png = _render_paths(args)
    defines = _render_defines(args)
    if args.frames is not None:
        return cmd_render_frames(args, scene_path, out, png, defines)
    scene = load_scene(scene_path, defines)

    _check_render_device(args)
    from .memory import check_memory
    check_memory(scene, args.backend, args.device)   # a render that cannot fit fails now
    if not args.quiet:
        w, h = scene.camera.resolution
        print(f"volmc: rendering {scene_path} ({w}x{h}, {scene.render.spp} spp, "
              f"backend {args.backend})", file=sys.stderr, flush=True)
    checkpoint = args.checkpoint or args.resume
    if checkpoint:
        _check_writable(checkpoint, "--checkpoint" if args.checkpoint else "--resume")
    _warn_out_of_view(scene, scene_path)
    with _dask_session(args) as client:
        # By name: the driver reads a --resume checkpoint (and refuses a wrong one) before
        # it builds and compiles the backend.
        res = render(scene, backend=args.backend, progress=False if args.quiet else None,
                     on_start=None if args.quiet else _announce_start, checkpoint=checkpoint,
                     checkpoint_every=args.checkpoint_every, resume=args.resume,
                     client=client, device=args.device, lanes=args.lanes)
    meta = res.metadata()
    meta["scene"] = os.path.abspath(scene_path)
    meta["scene_toml"] = to_toml(scene.spec)
    write_exr(out, res.film.rgba(), meta)
    if args.variance:
        write_exr(os.path.splitext(out)[0] + ".var.exr", res.film.variance_of_mean(), meta)
    if png:
        write_png(png, res.image, args.exposure, args.tonemap,
                  alpha=res.alpha if scene.render.transparent_background else None)

    if not args.quiet:
        state = "interrupted, partial image" if res.partial else "done"
        print(f"volmc: {state}: {_summary(out, png, res, scene)}", file=sys.stderr)
    _report(args, res)
    return EXIT_INTERRUPTED if res.partial else 0


def _render_paths(args):
    """(scene path, EXR path, PNG path or None) of ``volmc render``, the outputs checked."""
    from .resources import default_scene
    use_default = args.scene is None
    scene_path = str(default_scene()) if use_default else args.scene
    stem = os.path.splitext(os.path.basename(scene_path))[0]
    out = args.output or f"{stem}.exr"
    png = args.png
    if png is None and use_default:
        png = ""
    if png == "":
        png = os.path.splitext(out)[0] + ".png"
    if not out.lower().endswith(".exr"):   # the render is float: an EXR, a PNG beside it
        raise SceneError("command line", "-o", f"expected a path ending in .exr, got {out!r} "
                                               "(--png writes a PNG preview as well)")
    _check_writable(out, "-o")
    if png:
        if not png.lower().endswith(".png"):   # the image writer picks the format by suffix
            raise SceneError("command line", "--png", f"expected a path ending in .png, got "
                                                      f"{png!r}")
        _check_writable(png, "--png")
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
        from .cl.device import select_device
        from .cl.lanes import resolve_lanes
        select_device(args.device)   # a bad --device fails before anything is printed
        resolve_lanes(args.lanes, args.device)   # and so does a bad $VOLMC_LANES


def _warn_out_of_view(scene, scene_path, prefix=""):
    from .visibility import medium_in_view
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
    from .api import RenderedImage
    from .frames import FrameSequence, frame_path, parse_frames, render_sequence
    from .render import render
    from .scene.frames import describe
    from .scene.loading import read_raw
    frames = parse_frames(args.frames)
    for flag in ("checkpoint", "resume"):
        if getattr(args, flag):
            raise SceneError("command line", f"--{flag}", "a frame sequence resumes by "
                             "skipping its complete frames; --checkpoint and --resume are "
                             "for a single render")
    _check_render_device(args)
    seq = FrameSequence(read_raw(scene_path, defines), scene_path, None, frames)
    plan = seq.plan(out, args.backend)
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
        res = render(scene, backend=args.backend, progress=False if args.quiet else None,
                     on_start=None if args.quiet else on_start, client=client,
                     device=args.device, lanes=args.lanes, label=label)
        return RenderedImage(res, scene)

    t = time.perf_counter()
    done = skipped = 0
    with _dask_session(args) as client:
        for fr in render_sequence(seq, plan, render_one, png, args.variance, args.exposure,
                                  args.tonemap):
            head = f"frame {fr.index}/{fr.count} ({fr.frame})"
            if fr.image is None:
                skipped += 1
                if not args.quiet:
                    print(f"volmc: {head}: {fr.exr} is complete, skipped", file=sys.stderr)
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
    if not args.quiet:
        print(f"volmc: done: {len(seq.frames)} frames, {done} rendered, {skipped} complete "
              f"already ({time.perf_counter() - t:.2f} s)", file=sys.stderr)
    return 0


def cmd_check(args):
    from .check import check_scene
    from .backends import BACKENDS
    from .resources import default_scene
    from .scene import load_scene
    names = [b.strip() for b in args.backends.split(",")]
    if len(names) != 2 or any(b not in BACKENDS for b in names):
        raise SceneError("command line", "--backends",
                         f"expected two of {', '.join(BACKENDS)} separated by a comma, "
                         f"got {args.backends!r}")
    scene_path = str(default_scene()) if args.scene is None else args.scene
    scene = load_scene(scene_path, args.defines)
    w, h = scene.camera.resolution
    spp = args.spp or scene.render.spp
    print(f"volmc check: {scene_path}: {w}x{h}, {spp} spp, {names[0]} (seed s) vs {names[1]} "
          f"(seed s + 1)", flush=True)
    cmp, ra, rb = check_scene(scene, names, spp=args.spp, device=args.device)
    print(f"  {names[0]}: {ra.seconds:.2f} s, mean {_rgb(cmp.mean_a)}")
    print(f"  {names[1]}: {rb.seconds:.2f} s, mean {_rgb(cmp.mean_b)}")
    print("  " + cmp.summary(names[0], names[1]))
    return 0 if cmp.passed else 1


def cmd_peer(args):
    from .peers import PeerUnavailable, compare_with_peer
    from .resources import default_scene
    from .scene import load_scene
    if args.reference_spp is not None and args.reference_spp < 0:
        raise SceneError("command line", "--reference-spp",
                         f"must be 0 or a positive integer, got {args.reference_spp}")
    if args.json:
        _check_writable(args.json, "--json")
    if args.images and not os.path.isdir(args.images):
        raise SceneError("command line", "--images", f"not a directory: {args.images}")
    scene_path = str(default_scene()) if args.scene is None else args.scene
    scene = load_scene(scene_path, args.defines)   # rejects a box of zero thickness
    print(f"volmc peer {args.peer}: {scene_path}", flush=True)
    try:
        report, images = compare_with_peer(args.peer, scene, args.spp, args.passes,
                                           args.reference_spp, args.device)
    except PeerUnavailable as e:
        raise SceneError("command line", "peer", str(e)) from None
    if args.json:
        import json
        report["scene"] = os.path.abspath(scene_path)
        with open(args.json, "w") as f:
            json.dump(report, f, indent=2)
    if args.images:
        from .film import write_exr
        for name, img in images.items():
            write_exr(os.path.join(args.images, f"{name}.exr"), img, {"renderer": name})
    return 0 if report["agreement"]["passed"] else 1


def _rgb(v):
    return "(" + ", ".join(f"{x:.5g}" for x in v) + ")"


def cmd_bench_transmittance(args):
    from .bench import transmittance as bt
    from .scene.bricks import stores_bricks
    from .techniques import ESTIMATORS
    from .resources import default_scene, scenes_dir
    from .scene import load_scene
    names = list(ESTIMATORS)
    if args.estimators:
        names = [x.strip() for x in args.estimators.split(",")]
        bad = [n for n in names if n not in ESTIMATORS]
        if bad:
            raise SceneError("command line", "--estimators",
                             f"unknown estimator {bad[0]!r} (have {', '.join(ESTIMATORS)})")
    for path in (args.json,):
        if path:
            _check_writable(path, "--json")
    if args.figures and not os.path.isdir(args.figures):
        raise SceneError("command line", "--figures", f"not a directory: {args.figures}")
    paths = args.scenes or [str(default_scene()), str(scenes_dir() / "gallery" / "plume.toml"),
                            str(scenes_dir() / "gallery" / "scan.toml")]
    # The recorded render is small; a -D of the caller's comes later and wins.
    w, h = bt.QUICK_RESOLUTION if args.quick else bt.RECORD_RESOLUTION
    scenes = []
    for p in paths:
        s = load_scene(p, [f"camera.resolution=[{w}, {h}]"] + args.defines)
        if s.grid is None:
            raise SceneError(p, "medium.density", "the transmittance benchmark needs a grid")
        if stores_bricks(s):
            raise SceneError(p, "render.grid_storage", "the transmittance benchmark replays "
                                                       "dense grids: set it to \"dense\"")
        scenes.append(s)
    t = time.perf_counter()
    with _dask_session(args) as client:
        report = bt.run(names, scenes, n_rays=args.rays, quick=args.quick, device=args.device,
                        client=client)
    report["seconds"] = time.perf_counter() - t
    bt.print_report(report)
    if args.json:
        bt.write_json(args.json, report)
    if args.figures:
        from .bench import plots
        plots.heatmaps(report, os.path.join(args.figures, "estimators_heatmap.png"))
        plots.convergence_plots(report, os.path.join(args.figures, "estimators_variance_cost.png"),
                                os.path.join(args.figures, "estimators_error_time.png"))
        if report.get("maps"):
            plots.segment_maps(report, os.path.join(args.figures,
                                                    "estimators_segment_maps.png"))
            plots.winner_map(report, os.path.join(args.figures, "estimators_winner_map.png"))
    print(f"\nvolmc bench transmittance: {report['seconds']:.0f} s", file=sys.stderr)
    return 0


def _list(text, flag, allowed):
    items = [x.strip() for x in text.split(",") if x.strip()]
    bad = [x for x in items if x not in allowed]
    if not items or bad:
        raise SceneError("command line", flag, f"expected a comma-separated list of "
                                               f"{', '.join(allowed)}, got {text!r}")
    return items


def _spp_levels(text):
    """The ``--spp-levels`` list: positive integers separated by commas."""
    levels = []
    for x in text.split(","):
        if not (x.strip().isascii() and x.strip().isdigit()) or int(x) < 1:
            raise SceneError("command line", "--spp-levels",
                             f"expected positive integers separated by commas, got {text!r}")
        levels.append(int(x))
    return levels


def cmd_bench_render(args):
    from .bench import convergence as cv
    from .bench.render import write_json
    from .backends import BACKENDS
    from .resources import default_scene
    from .scene import load_scene
    from .scene.schema import MAJORANTS, SPECTRAL_MODES, ConstantDensity
    backends = _list(args.backends, "--backends", BACKENDS)
    majorants = _list(args.majorants, "--majorants", MAJORANTS)
    flights = _list(args.free_flights, "--free-flights", ("delta", "decomposition"))
    levels = _spp_levels(args.spp_levels)
    for path, flag in ((args.json, "--json"), (args.plot, "--plot")):
        if path:
            _check_writable(path, flag)
    scene_path = str(default_scene()) if args.scene is None else args.scene
    scene = load_scene(scene_path, args.defines)
    homogeneous = isinstance(scene.spec.medium.density, ConstantDensity)
    if args.transmittances == "scene":
        ests = [scene.render.transmittance]
    elif args.transmittances:
        from .techniques import ESTIMATORS
        ests = _list(args.transmittances, "--transmittances", tuple(ESTIMATORS))
    else:
        from .techniques import ESTIMATORS
        exact = [n for n, e in ESTIMATORS.items() if e.homogeneous_only]
        ests = (exact if homogeneous else []) + cv.unbiased_grid_estimators()
    peers = []
    if args.peer != "none":
        from .peers import PEERS, available
        wanted = list(PEERS) if args.peer in ("auto", "all") else [args.peer]
        for name in wanted:
            version, why = available(name, scene)
            if version is None and args.peer != "auto":
                raise SceneError("command line", "--peer", why)
            print(f"peer: {PEERS[name][0]} " + (version if version else f"none ({why})"),
                  flush=True)
            if version:
                peers.append(name)
    spectrals = ([""] if args.spectral is None else
                 _list(args.spectral, "--spectral", SPECTRAL_MODES))
    configs = cv.make_configs(backends, majorants, flights, ests, peers, args.baseline,
                              spectrals)
    w, h = scene.camera.resolution
    print(f"volmc bench render: {scene_path}: {w}x{h}, {len(configs)} configurations",
          flush=True)
    ceiling = None
    if not args.no_ceiling and not homogeneous:
        from .bench.lookups import lookup_ceiling
        ceiling = lookup_ceiling(scene, backends, device=args.device)
    with _dask_session(args) as client:
        report = cv.run(scene, configs, levels, args.reference_spp, args.repeats, args.device,
                        ceiling, defines=args.defines, client=client)
    cv.print_report(report)
    if args.json:
        write_json(args.json, report)
    if args.plot:
        from .bench.plots import render_convergence_plot
        render_convergence_plot(report, args.plot)
    return 0


def cmd_bench_variance(args):
    from .bench import variance
    from .bench.render import write_json
    from .scene import load_scene
    allowed = variance.switch_labels()
    labels = allowed if args.switches is None else _list(args.switches, "--switches", allowed)
    levels = _spp_levels(args.spp_levels)
    for path, flag in ((args.json, "--json"), (args.plot, "--plot")):
        if path:
            _check_writable(path, flag)
    from .cl.device import select_device
    # The reference is an OpenCL render whatever --backend says: a bad --device fails now,
    # before anything is rendered.
    select_device(args.device)
    paths = args.scenes or [str(p) for p in variance.default_scene_paths()]
    scenes = [load_scene(p, args.defines) for p in paths]
    t = time.perf_counter()
    report = variance.run(scenes, labels, levels, args.reference_spp, args.repeats,
                          args.backend, args.device)
    report["seconds"] = time.perf_counter() - t
    for rep in report["scenes"]:
        variance.print_scene(rep)
    variance.print_combined(report)
    if args.json:
        write_json(args.json, report)
    if args.plot:
        from .bench.plots import variance_sampler_plot
        variance_sampler_plot(report, args.plot)
    print(f"\nvolmc bench variance: {report['seconds']:.0f} s", file=sys.stderr)
    return 0


def cmd_bench_lanes(args):
    from .bench import lanes
    from .bench.render import write_json
    from .cl.device import select_device
    from .cl.lanes import LANE_WIDTHS
    from .scene import load_scene
    widths = [int(w) for w in _list(args.widths, "--widths", tuple(map(str, LANE_WIDTHS)))]
    levels = _spp_levels(args.spp_levels)
    if args.json:
        _check_writable(args.json, "--json")
    select_device(args.device)   # a bad --device fails before anything is rendered
    paths = args.scenes or [str(p) for p in lanes.default_scene_paths()]
    scenes = [load_scene(p, args.defines) for p in paths]   # every bad scene fails now
    out = {"widths": widths, "scenes": {}}
    for path, scene in zip(paths, scenes):
        report = lanes.run_scene(scene, widths, levels, args.reference_spp, args.repeats,
                                 args.device, not args.no_ceiling, log=lambda s: None)
        lanes.print_summary(path, report)
        out["scenes"][path] = report
    if args.json:
        write_json(args.json, out)
    return 0


def cmd_bench(args):
    if args.bench == "lanes":
        return cmd_bench_lanes(args)
    if args.bench == "transmittance":
        return cmd_bench_transmittance(args)
    if args.bench == "variance":
        return cmd_bench_variance(args)
    if args.bench == "render":
        return cmd_bench_render(args)
    if args.bench == "sparse":
        from .backends import BACKENDS
        from .bench import sparse
        if not 0.0 < args.fill <= 1.0:
            raise SceneError("command line", "--fill", f"must be in (0, 1], got {args.fill}")
        backends = _list(args.backends, "--backends", BACKENDS)
        if args.json:
            _check_writable(args.json, "--json")
        argv = ["--size", str(args.size), "--fill", str(args.fill), "--lookups",
                str(args.lookups), "--repeats", str(args.repeats), "--backends",
                ",".join(backends)] + (["--device", args.device] if args.device else []) + \
            (["--json", args.json] if args.json else [])
        return sparse.main(argv)
    from .bench import render as rb
    from .resources import default_scene, scenes_dir
    from .scene import load_scene
    if args.scenes:
        paths = args.scenes
    elif args.bench == "specialise":
        paths = [str(p) for p in sorted(scenes_dir().glob("*.toml"))
                 + sorted((scenes_dir() / "tests").glob("*.toml"))]
    else:
        paths = [str(default_scene())]
    if args.json:
        _check_writable(args.json, "--json")
    report = {}
    for path in paths:
        scene = load_scene(path, args.defines)
        w, h = scene.camera.resolution
        print(f"{path}: {w}x{h}, {args.spp} spp per batch, {args.repeats} repeats", flush=True)
        if args.bench == "specialise":
            res = rb.bench_specialisation(scene, args.spp, args.repeats, args.device)
            rb.print_table("samples per second:", res, baseline="generic")
            gains = rb.specialisation_gains(res)
            print("  gain of each switch (samples per CPU-second, specialised against the "
                  "build with the switch on): " +
                  ", ".join(f"{k} x{v:.3f}" for k, v in gains.items()), flush=True)
            res = {"configs": res, "gains": gains}
        else:
            sizes = []
            for x in args.sizes.split(","):
                x = x.strip()
                if x == "driver":
                    sizes.append(None)
                elif x.isascii() and x.isdigit() and int(x) > 0:
                    sizes.append(int(x))
                else:
                    raise SceneError("command line", "--sizes", f"not a work-group size: {x!r}")
            res = rb.bench_workgroup(scene, sizes, args.spp, args.repeats, args.device)
            rb.print_table("samples per second:", res,
                           baseline="driver" if None in sizes else None)
        report[path] = res
    if args.json:
        rb.write_json(args.json, {"benchmark": args.bench, "spp": args.spp,
                                  "repeats": args.repeats, "results": report})
    return 0


def cmd_info(args):
    if args.file is not None:
        from .scene.vdb import describe_grid_file
        print("\n".join(describe_grid_file(args.file)))
        return 0
    from .cl.build import cache_dir
    from .cl.device import ENV_VAR, describe, list_devices, select_device
    plats = list_devices()
    if not plats:
        print("no OpenCL platforms found")
    for i, p, devs in plats:
        print(f"platform {i}: {p.name} ({p.version})")
        for j, d in enumerate(devs):
            print(f"  device {i}:{j}: {d.name} ({d.version}, driver {d.driver_version}, "
                  f"{d.max_compute_units} compute units, {d.global_mem_size >> 20} MiB)")
    try:
        from .cl.lanes import ENV_VAR as LANES_VAR, device_lanes, resolve_lanes
        dev = select_device()
        print(f"default device: {describe(dev)}")
        print(f"lanes: {resolve_lanes(None, dev)} paths per work-item (the device prefers "
              f"{dev.preferred_vector_width_float} floats a vector, so "
              f"{device_lanes(dev)} by default; --lanes or ${LANES_VAR} set it)")
    except SceneError as e:
        print(f"default device: none ({e})")
    print(f"select another with --device PLATFORM[:DEVICE] or ${ENV_VAR}")
    cdir = cache_dir()
    n = len(list(cdir.glob("*.bin"))) if cdir.is_dir() else 0
    print(f"kernel cache: {cdir} ({n} programs; set VOLMC_CACHE_DIR to move it)")
    return 0


def cmd_convert(args):
    from .scene.grids import load_grid, read_vol, save_grid
    grid = load_grid(args.input, "input")
    bounds = ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    if args.bounds is not None:
        b = args.bounds
        bounds = (tuple(b[:3]), tuple(b[3:]))
    elif args.input.lower().endswith(".vol"):
        bb = read_vol(args.input)[1]
        bounds = (tuple(bb[:3]), tuple(bb[3:]))
    _check_writable(args.output, "output")
    save_grid(args.output, grid, bounds)
    nz, ny, nx = grid.shape
    print(f"volmc: wrote {args.output} ({nx}x{ny}x{nz} [x, y, z])", file=sys.stderr)
    return 0


def main(argv=None):
    """Entry point of the ``volmc`` console script; returns the exit status."""
    try:
        args = build_parser().parse_args(argv)
        if args.command == "render":
            return cmd_render(args)
        if args.command == "convert":
            return cmd_convert(args)
        if args.command == "check":
            return cmd_check(args)
        if args.command == "info":
            return cmd_info(args)
        if args.command == "bench":
            return cmd_bench(args)
        if args.command == "peer":
            return cmd_peer(args)
    except SceneError as e:
        print(f"volmc: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("volmc: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    return 0


if __name__ == "__main__":
    sys.exit(main())
