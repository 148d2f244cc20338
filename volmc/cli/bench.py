"""``volmc bench``: the benchmarks, each subcommand a parser builder and a handler in
``BENCHES``."""

import os
import sys
import time

from ..outputs import write_json
from ..scene.errors import SceneError
from ..scene.hostmem import require_host
from .common import (Parser, add_cluster_options, add_defines_option, add_device_option,
                     add_ladder_arguments, add_lanes_option, add_scene_argument,
                     check_directory, check_figure_path, check_outputs, check_writable,
                     comma_list, dask_session, finite_float, positive_int,
                     reference_spp_count, scene_path, spp_count, spp_levels)


def add_bench_transmittance_parser(sub):
    bt = sub.add_parser("transmittance", help="every transmittance estimator on 1-D profiles and "
                                              "on the segments a render traces: error against "
                                              "cost, and maps of which wins where")
    bt.add_argument("scenes", nargs="*", help="grid scenes whose recorded segments are replayed "
                                              "(default: the cloud, the plume and the scan)")
    bt.add_argument("--estimators", help="comma-separated subset (default: all)")
    bt.add_argument("--quick", action="store_true", help="a small sweep (seconds, for tests)")
    bt.add_argument("--rays", type=positive_int, default=1024,
                    help="recorded camera and shadow segments replayed per grid scene "
                         "(default 1024 each; a quarter with --quick)")
    bt.add_argument("--json", help="write the full report to this JSON file")
    bt.add_argument("--figures", help="write PNG figures into this directory")
    add_device_option(bt)
    add_cluster_options(bt, "run the sweep's cases")
    add_defines_option(bt, "override a key of every scene")
    return bt


#: The files bench transmittance --figures writes into its folder.
TRANSMITTANCE_FIGURES = ("estimators_heatmap.png", "estimators_variance_cost.png",
                         "estimators_error_time.png", "estimators_segment_maps.png",
                         "estimators_winner_map.png")


def cmd_bench_transmittance(args):
    from ..bench import transmittance as bt
    from ..scene.bricks import stores_bricks
    from ..techniques import ESTIMATORS
    from ..resources import default_scene, scenes_dir
    from ..scene import load_scene
    names = list(ESTIMATORS)
    if args.estimators:
        names = comma_list(args.estimators, "--estimators", tuple(ESTIMATORS))
    paths = args.scenes or [str(default_scene()), str(scenes_dir() / "gallery" / "plume.toml"),
                            str(scenes_dir() / "gallery" / "scan.toml")]
    if args.figures:
        check_directory(args.figures, "--figures")
    check_outputs({"--json": args.json,
                   "--figures": args.figures and [os.path.join(args.figures, name)
                                                  for name in TRANSMITTANCE_FIGURES]}, paths)
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
    with dask_session(args) as client:
        report = bt.run(names, scenes, n_rays=args.rays, quick=args.quick, device=args.device,
                        client=client)
    report["seconds"] = time.perf_counter() - t
    bt.print_report(report)
    if args.json:
        write_json(args.json, report, indent=1, default=float)
    if args.figures:
        from ..bench import plots
        heat, cost, error, maps, winner = (os.path.join(args.figures, name)
                                           for name in TRANSMITTANCE_FIGURES)
        plots.heatmaps(report, heat)
        plots.convergence_plots(report, cost, error)
        if report.get("maps"):
            plots.segment_maps(report, maps)
            plots.winner_map(report, winner)
    print(f"\nvolmc bench transmittance: {report['seconds']:.0f} s", file=sys.stderr)
    return 0


def add_bench_render_parser(sub):
    br = sub.add_parser("render", help="RMSE against wall time for every configuration "
                                       "(backend x majorant x free flight x shadow estimator, "
                                       "and Mitsuba 3 when it runs)")
    add_scene_argument(br)
    add_cluster_options(br, "render volmc's configurations")
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
    add_ladder_arguments(br, repeats=1)
    add_device_option(br)
    add_defines_option(br)
    br.add_argument("--json", help="also write the report to this JSON file")
    br.add_argument("--plot", help="write the RMSE-against-time figure (PNG) here")
    br.add_argument("--no-ceiling", action="store_true",
                    help="skip the raw-lookup ceiling measurement")
    br.add_argument("--baseline", action="append", default=[], metavar="DIR",
                    help="also render with the volmc checkout in DIR (an earlier version, "
                         "OpenCL, the scene's own techniques); repeatable")
    return br


def cmd_bench_render(args):
    from ..bench import convergence as cv
    from ..backends import BACKENDS
    from ..scene import load_scene
    from ..scene.schema import MAJORANTS, SPECTRAL_MODES, ConstantDensity
    backends = comma_list(args.backends, "--backends", BACKENDS)
    majorants = comma_list(args.majorants, "--majorants", MAJORANTS)
    flights = comma_list(args.free_flights, "--free-flights", ("delta", "decomposition"))
    levels = spp_levels(args.spp_levels)
    if args.plot:
        check_figure_path(args.plot, "--plot")
    check_outputs({"--json": args.json, "--plot": args.plot}, [scene_path(args)])
    from ..bench.baseline import check_checkout
    for b in args.baseline:
        check_checkout(b)
    path = scene_path(args)
    scene = load_scene(path, args.defines)
    homogeneous = all(isinstance(m.density, ConstantDensity) for m in scene.spec.media)
    if args.transmittances == "scene":
        ests = [scene.render.transmittance]
    elif args.transmittances:
        from ..techniques import ESTIMATORS
        ests = comma_list(args.transmittances, "--transmittances", tuple(ESTIMATORS))
        exact = [n for n in ests if ESTIMATORS[n].homogeneous_only]
        if exact and not homogeneous:   # it would render the majorant's transmittance
            raise SceneError("command line", "--transmittances",
                             f"{exact[0]} is exact in homogeneous media only, and {path} has "
                             f"a medium whose density is not a constant")
    else:
        from ..techniques import ESTIMATORS
        exact = [n for n, e in ESTIMATORS.items() if e.homogeneous_only]
        ests = (exact if homogeneous else []) + cv.unbiased_grid_estimators()
    peers = []
    if args.peer != "none":
        from ..peers import PEERS, available
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
                 comma_list(args.spectral, "--spectral", SPECTRAL_MODES))
    configs = cv.make_configs(backends, majorants, flights, ests, peers, args.baseline,
                              spectrals)
    w, h = scene.camera.resolution
    print(f"volmc bench render: {path}: {w}x{h}, {len(configs)} configurations",
          flush=True)
    ceiling = None
    if not args.no_ceiling and not homogeneous:
        from ..bench.lookups import lookup_ceiling
        ceiling = lookup_ceiling(scene, backends, device=args.device)
    with dask_session(args) as client:
        report = cv.run(scene, configs, levels, args.reference_spp, args.repeats, args.device,
                        ceiling, defines=args.defines, client=client)
    cv.print_report(report)
    if args.json:
        write_json(args.json, report)
    if args.plot:
        from ..bench.plots import render_convergence_plot
        render_convergence_plot(report, args.plot)
    return 0


def add_bench_lanes_parser(sub):
    from ..cl.lanes import LANE_WIDTHS
    bl = sub.add_parser("lanes", help="samples/s and time to equal error per lane width "
                                      "(paths per work-item) on every shipped scene")
    bl.add_argument("scenes", nargs="*", help="scene files (default: every shipped scene)")
    bl.add_argument("--widths", default=",".join(map(str, LANE_WIDTHS)),
                    help="comma-separated lane widths (default 1,4,8,16)")
    add_ladder_arguments(bl, repeats=2, levels="4,16", reference_spp=256)
    add_device_option(bl)
    add_defines_option(bl, "override a key of every scene (repeatable)")
    bl.add_argument("--no-ceiling", action="store_true",
                    help="skip the raw-lookup ceiling measurement")
    bl.add_argument("--json", help="also write the reports to this JSON file")
    return bl


def cmd_bench_lanes(args):
    from ..bench import lanes
    from ..cl.device import select_device
    from ..cl.lanes import LANE_WIDTHS
    from ..scene import load_scene
    widths = [int(w) for w in comma_list(args.widths, "--widths", tuple(map(str, LANE_WIDTHS)))]
    levels = spp_levels(args.spp_levels)
    select_device(args.device)   # a bad --device fails before anything is rendered
    paths = args.scenes or [str(p) for p in lanes.default_scene_paths()]
    check_outputs({"--json": args.json}, paths)
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


def add_bench_variance_parser(sub):
    from ..backends import BACKENDS
    bv = sub.add_parser("variance", help="relative efficiency of each variance-reduction "
                                         "switch (sampler, light samples, MIS, equiangular, "
                                         "roulette) against the plain renderer")
    bv.add_argument("scenes", nargs="*", help="scene files (default: the cloud, "
                                              "scenes/bench/thin.toml and the lamp in fog)")
    bv.add_argument("--switches", default=None,
                    help="comma-separated subset of the switches (default: all)")
    add_ladder_arguments(bv, repeats=3)
    bv.add_argument("--backend", choices=BACKENDS, default=BACKENDS[0],
                    help="backend of the timed renders (default opencl; the reference is "
                         "always OpenCL)")
    add_device_option(bv)
    add_defines_option(bv, "override a key of every scene (repeatable)")
    bv.add_argument("--json", help="also write the report (every point too) to this JSON file")
    bv.add_argument("--plot", help="write the RMSE-against-spp figure of the samplers (PNG) "
                                   "here")
    return bv


def cmd_bench_variance(args):
    from ..bench import variance
    from ..scene import load_scene
    allowed = variance.switch_labels()
    labels = allowed if args.switches is None else comma_list(args.switches, "--switches", allowed)
    levels = spp_levels(args.spp_levels)
    if args.plot:
        check_figure_path(args.plot, "--plot")
    paths = args.scenes or [str(p) for p in variance.default_scene_paths()]
    check_outputs({"--json": args.json, "--plot": args.plot}, paths)
    from ..cl.device import select_device
    # The reference is an OpenCL render whatever --backend says: a bad --device fails now,
    # before anything is rendered.
    select_device(args.device)
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
        from ..bench.plots import variance_sampler_plot
        variance_sampler_plot(report, args.plot)
    print(f"\nvolmc bench variance: {report['seconds']:.0f} s", file=sys.stderr)
    return 0


def _add_batch_arguments(p, default_scenes):
    """The arguments of the samples/s benchmarks (specialise, workgroup)."""
    p.add_argument("scenes", nargs="*", help=f"scene files (default: {default_scenes})")
    p.add_argument("--spp", type=spp_count, default=4,
                   help="samples per pixel per timed batch (default 4)")
    p.add_argument("--repeats", type=positive_int, default=3,
                   help="timed batches per configuration; the median is reported")
    add_device_option(p)
    add_defines_option(p)
    p.add_argument("--json", help="also write the figures to this JSON file")


def _samples_per_second(args, default_paths, measure):
    """Run ``measure(scene)`` on each scene of ``args.scenes`` (else ``default_paths()``):
    the shared loop of bench specialise and workgroup, and their JSON report."""
    from ..bench import render as rb
    from ..scene import load_scene
    paths = args.scenes or default_paths()
    check_outputs({"--json": args.json}, paths)
    scenes = [load_scene(p, args.defines) for p in paths]   # every bad scene fails now
    report = {}
    for path, scene in zip(paths, scenes):
        w, h = scene.camera.resolution
        print(f"{path}: {w}x{h}, {args.spp} spp per batch, {args.repeats} repeats", flush=True)
        report[path] = measure(scene)
    if args.json:
        write_json(args.json, {"benchmark": args.bench, "spp": args.spp,
                                  "repeats": args.repeats, "results": report})
    return 0


def add_bench_specialise_parser(sub):
    bb = sub.add_parser("specialise",
                        help="samples/s of the scene's build against each feature switch on")
    _add_batch_arguments(bb, "every shipped scene")
    return bb


def cmd_bench_specialise(args):
    from ..bench import render as rb
    from ..resources import scenes_dir

    def shipped():
        return [str(p) for p in sorted(scenes_dir().glob("*.toml"))
                + sorted((scenes_dir() / "tests").glob("*.toml"))]

    def measure(scene):
        res = rb.bench_specialisation(scene, args.spp, args.repeats, args.device)
        rb.print_table("samples per second:", res, baseline="generic")
        gains = rb.specialisation_gains(res)
        print("  gain of each switch (samples per CPU-second, specialised against the "
              "build with the switch on): " +
              ", ".join(f"{k} x{v:.3f}" for k, v in gains.items()), flush=True)
        return {"configs": res, "gains": gains}
    return _samples_per_second(args, shipped, measure)


def add_bench_workgroup_parser(sub):
    bb = sub.add_parser("workgroup", help="samples/s of the OpenCL kernel per work-group size")
    _add_batch_arguments(bb, "the cloud scene")
    bb.add_argument("--sizes", default="driver,1,2,4,8,16,32,64",
                    help="comma-separated work-group sizes ('driver' = driver's choice)")
    return bb


def cmd_bench_workgroup(args):
    from ..bench import render as rb
    from ..resources import default_scene

    def measure(scene):
        from ..cl.context import cl_context
        sizes = _workgroup_sizes(args.sizes)
        # Above the device's limit the launch fails inside pyopencl (std::bad_cast).
        limit = cl_context(args.device).device.max_work_group_size
        for size in sizes:
            if size is not None and size > limit:
                raise SceneError("command line", "--sizes", f"work-group size {size} is above "
                                 f"the device's maximum, {limit}")
        res = rb.bench_workgroup(scene, sizes, args.spp, args.repeats, args.device)
        rb.print_table("samples per second:", res, baseline="driver" if None in sizes else None)
        return res
    return _samples_per_second(args, lambda: [str(default_scene())], measure)


def _workgroup_sizes(text):
    """The ``--sizes`` list: positive integers, None for 'driver'."""
    sizes = []
    for x in text.split(","):
        x = x.strip()
        if x == "driver":
            sizes.append(None)
        elif x.isascii() and x.isdigit() and int(x) > 0:
            sizes.append(int(x))
        else:
            raise SceneError("command line", "--sizes", f"not a work-group size: {x!r}")
        if sizes[-1] in sizes[:-1]:
            raise SceneError("command line", "--sizes", f"{x!r} is named twice in {text!r}")
    return sizes


def add_bench_sparse_parser(sub):
    bs = sub.add_parser("sparse", help="memory and lookup speed of brick (sparse) storage "
                                       "against the dense grid")
    bs.add_argument("--size", type=positive_int, default=512, help="voxels per axis (512)")
    bs.add_argument("--fill", type=finite_float, default=0.03,
                    help="fraction of active voxels (0.03)")
    bs.add_argument("--lookups", type=positive_int, default=1 << 22,
                    help="lookups per timed launch")
    bs.add_argument("--repeats", type=positive_int, default=5)
    bs.add_argument("--backends", default="opencl,numba")
    add_device_option(bs)
    bs.add_argument("--json", help="also write the figures to this JSON file")
    return bs


def cmd_bench_sparse(args):
    from ..backends import BACKENDS
    from ..bench import sparse
    if not 0.0 < args.fill <= 1.0:
        raise SceneError("command line", "--fill", f"must be in (0, 1], got {args.fill}")
    backends = comma_list(args.backends, "--backends", BACKENDS)
    if args.json:
        check_writable(args.json, "--json")
    need = sparse.least_bytes(args.size, args.lookups, backends)
    grid = sparse.least_bytes(args.size, 1, backends)   # the grids alone
    require_host(need, "command line", "--size" if 2 * grid >= need else "--lookups",
                 f"a {args.size}^3 grid and {args.lookups} lookups per launch")
    return sparse.report(args.size, args.fill, args.lookups, args.repeats, backends,
                         args.device, args.json)


def add_bench_denoise_parser(sub):
    bd = sub.add_parser("denoise", help="the denoised preview's error against the unbiased "
                                        "image's per spp, with and without the albedo AOV")
    bd.add_argument("scenes", nargs="*", help="scene files (default: the gallery's)")
    bd.add_argument("--width", type=positive_int, default=160,
                    help="image width; the height keeps the scene's aspect (default 160)")
    bd.add_argument("--spp-levels", default="4,16,64",
                    help="comma-separated spp of the noisy renders (default 4,16,64)")
    bd.add_argument("--reference-spp", type=reference_spp_count, default=2048,
                    help="spp of the reference (default 2048)")
    add_lanes_option(bd)
    bd.add_argument("--json", help="also write the report to this JSON file")
    return bd


def cmd_bench_denoise(args):
    from ..bench import denoise as bench
    from ..denoise import oidn
    oidn("command line", "volmc bench denoise")
    levels = spp_levels(args.spp_levels)
    paths = [str(p) for p in bench.scene_paths(args.scenes)]
    check_outputs({"--json": args.json}, paths)
    from ..scene import load_scene
    for p in paths:   # every bad scene fails now, not after the ones before it
        load_scene(p)
    from ..bench import report_main
    report_main(lambda: bench.run(args.scenes, args.width, levels, args.reference_spp,
                                  args.lanes), bench.print_report, args.json)
    return 0


#: ``volmc bench`` NAME -> (parser builder, handler), in the order ``--help`` lists them.
BENCHES = {
    "transmittance": (add_bench_transmittance_parser, cmd_bench_transmittance),
    "render": (add_bench_render_parser, cmd_bench_render),
    "lanes": (add_bench_lanes_parser, cmd_bench_lanes),
    "variance": (add_bench_variance_parser, cmd_bench_variance),
    "specialise": (add_bench_specialise_parser, cmd_bench_specialise),
    "workgroup": (add_bench_workgroup_parser, cmd_bench_workgroup),
    "sparse": (add_bench_sparse_parser, cmd_bench_sparse),
    "denoise": (add_bench_denoise_parser, cmd_bench_denoise),
}


def add_bench_parser(sub):
    b = sub.add_parser("bench", help="benchmarks (speed of backends, builds, work-group sizes)")
    bsub = b.add_subparsers(dest="bench", required=True, parser_class=Parser)
    for add, _ in BENCHES.values():
        add(bsub)
    return b


def cmd_bench(args):
    if getattr(args, "device", None):
        from ..cl.device import select_device
        select_device(args.device)   # a bad --device fails before any grid is built
    return BENCHES[args.bench][1](args)
