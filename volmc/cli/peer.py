"""``volmc peer``: a scene rendered by volmc and by a peer renderer (Mitsuba 3, Blender
Cycles): agreement, and speed against error."""

import os

from ..scene.errors import SceneError
from .common import (add_defines_option, add_device_option, add_scene_argument,
                     check_directory, check_outputs, positive_int, reference_spp_count,
                     scene_path, spp_count)


def reference_spp_or_zero(text):
    """--reference-spp: 0 (agreement only), or a reference_spp_count."""
    return 0 if text.strip() == "0" else reference_spp_count(text)


def add_peer_parser(sub):
    pe = sub.add_parser("peer", help="render a scene with volmc and with a peer renderer "
                                     "(Mitsuba 3, Blender Cycles): agreement and speed "
                                     "against error")
    pe.add_argument("peer", choices=["mitsuba", "cycles"], help="the peer renderer")
    add_scene_argument(pe)
    pe.add_argument("--spp", type=spp_count, help="samples per pixel of both renders "
                                                     "(default: the scene's)")
    pe.add_argument("--passes", type=positive_int, default=16,
                    help="the peer renders in this many independent launches, whose spread "
                         "gives its per-pixel variance (default 16)")
    pe.add_argument("--reference-spp", type=reference_spp_or_zero, default=None,
                    help="samples per pixel of the volmc reference for RMSE (default 8 x spp; "
                         "0: agreement only)")
    add_device_option(pe)
    add_defines_option(pe)
    pe.add_argument("--json", help="write the report to this JSON file")
    pe.add_argument("--images", metavar="DIR",
                    help="write volmc.exr, PEER.exr (and reference.exr) into DIR, with "
                         "volmc.var.exr and PEER.var.exr, their variances of the mean")
    return pe


def cmd_peer(args):
    from ..peers import PeerUnavailable, compare_with_peer
    from ..scene import load_scene
    path = scene_path(args)
    if args.images:
        check_directory(args.images, "--images")
    names = ("volmc", args.peer, "reference", "volmc.var", f"{args.peer}.var")
    check_outputs({"--json": args.json,
                   "--images": args.images and [os.path.join(args.images, f"{n}.exr")
                                                for n in names]}, [path])
    scene = load_scene(path, args.defines)   # rejects a box of zero thickness
    print(f"volmc peer {args.peer}: {path}", flush=True)
    try:
        report, images = compare_with_peer(args.peer, scene, args.spp, args.passes,
                                           args.reference_spp, args.device)
    except PeerUnavailable as e:
        raise SceneError("command line", "peer", str(e)) from None
    if args.json:
        from ..outputs import write_json
        report["scene"] = os.path.abspath(path)
        write_json(args.json, report)
    if args.images:
        from ..film import write_exr
        for name, img in images.items():
            write_exr(os.path.join(args.images, f"{name}.exr"), img, {"renderer": name})
    return 0 if report["agreement"]["passed"] else 1
