"""Speed of the render kernel built with and without -cl-fast-relaxed-math (robustness case 20).

Production builds use no fast-math flag (volmc/cl/build.py BASE_OPTIONS); this measures what
that costs. Both builds render the same scene with the same seed; configurations alternate
within each repetition and the figures are medians (volmc/bench/render.run_configs). The
guards that must survive fast-math are tested in tests/hard/test_case20_fastmath.py.

Run: ``python -m volmc.bench.fastmath [SCENE] [--spp N] [--repeats R] [--json PATH]``.
"""

import argparse

FAST_MATH = "-cl-fast-relaxed-math"


def bench_fastmath(scene, spp=4, repeats=5, device=None, log=print):
    """samples/s of the scene's OpenCL build without and with -cl-fast-relaxed-math."""
    from ..backends.opencl import OpenCLBackend
    from .render import run_configs
    configs = {
        "default": lambda: OpenCLBackend(scene, device=device),
        "fast-relaxed-math": lambda: OpenCLBackend(scene, device=device, options=(FAST_MATH,)),
    }
    return run_configs(scene, configs, spp, repeats, log)


def main(argv=None):
    from ..resources import default_scene
    from ..scene import load_scene
    from ..outputs import write_json
    from .render import print_table
    ap = argparse.ArgumentParser(prog="python -m volmc.bench.fastmath")
    ap.add_argument("scene", nargs="?", default=None)
    ap.add_argument("--spp", type=int, default=4, help="samples per pixel per timed render")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", default=None)
    ap.add_argument("-D", dest="defines", action="append", default=[])
    args = ap.parse_args(argv)
    path = args.scene or str(default_scene())
    scene = load_scene(path, args.defines)
    res = bench_fastmath(scene, args.spp, args.repeats)
    print_table(f"fast-math: {path}, {args.spp} spp x {args.repeats} alternating repeats",
                res, baseline="default")
    if args.json:
        write_json(args.json, {"benchmark": "fastmath", "scene": path, "spp": args.spp,
                               "repeats": args.repeats, "results": res})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
