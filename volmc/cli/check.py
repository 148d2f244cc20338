"""``volmc check``: a scene rendered by two backends, the images compared per pixel."""

from ..scene.errors import SceneError
from .common import (add_defines_option, add_device_option, add_scene_argument,
                     check_opencl_choices, scene_path, spp_count)


#: Fewest samples per pixel volmc check compares: the t-test assumes roughly normal pixel
#: means, and a path tracer's samples are discrete (often 0 or one light's value): at 2 and
#: 4 spp such pixels failed most comparisons of identical renders (docs/testing.md).
MIN_CHECK_SPP = 16


def add_check_parser(sub):
    k = sub.add_parser("check", help="render a scene with two backends and compare the images "
                                     "(per-pixel t-test)")
    add_scene_argument(k)
    k.add_argument("--spp", type=spp_count, help="samples per pixel for both renders")
    k.add_argument("--backends", default="opencl,numba", help="two backends (default "
                                                               "opencl,numba)")
    add_device_option(k)
    add_defines_option(k)
    return k


def cmd_check(args):
    from ..check import check_scene
    from ..backends import BACKENDS
    from ..scene import load_scene
    names = [b.strip() for b in args.backends.split(",")]
    if len(names) != 2 or any(b not in BACKENDS for b in names):
        raise SceneError("command line", "--backends",
                         f"expected two of {', '.join(BACKENDS)} separated by a comma, "
                         f"got {args.backends!r}")
    path = scene_path(args)
    scene = load_scene(path, args.defines)
    w, h = scene.camera.resolution
    spp = args.spp or scene.render.spp
    if spp < MIN_CHECK_SPP:
        raise SceneError("command line" if args.spp else path,
                         "--spp" if args.spp else "render.spp",
                         f"volmc check needs at least {MIN_CHECK_SPP} samples per pixel, got "
                         f"{spp}")
    if "opencl" in names:
        check_opencl_choices(args.device)
    print(f"volmc check: {path}: {w}x{h}, {spp} spp, {names[0]} (seed s) vs {names[1]} "
          f"(seed s + 1)", flush=True)
    cmp, ra, rb = check_scene(scene, names, spp=args.spp, device=args.device)
    print(f"  {names[0]}: {ra.seconds:.2f} s, mean {_rgb(cmp.mean_a)}")
    print(f"  {names[1]}: {rb.seconds:.2f} s, mean {_rgb(cmp.mean_b)}")
    print("  " + cmp.summary(names[0], names[1]))
    return 0 if cmp.passed else 1


def _rgb(v):
    return "(" + ", ".join(f"{x:.5g}" for x in v) + ")"
