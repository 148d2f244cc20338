"""``volmc info``: the OpenCL platforms, devices and kernel cache, or the grids of a VDB
file."""

from ..scene.errors import SceneError


def add_info_parser(sub):
    inf = sub.add_parser("info", help="list OpenCL platforms and devices and the kernel "
                                      "cache, or the grids of a .vdb / .nvdb file")
    inf.add_argument("file", nargs="?", help="an OpenVDB or NanoVDB file: list its grids")
    return inf


def cmd_info(args):
    if args.file is not None:
        from ..scene.vdb import describe_grid_file
        print("\n".join(describe_grid_file(args.file)))
        return 0
    from ..cl.build import cache_dir
    from ..cl.device import ENV_VAR, describe, list_devices, select_device
    plats = list_devices()
    if not plats:
        print("no OpenCL platforms found")
    for i, p, devs in plats:
        print(f"platform {i}: {p.name} ({p.version})")
        for j, d in enumerate(devs):
            print(f"  device {i}:{j}: {d.name} ({d.version}, driver {d.driver_version}, "
                  f"{d.max_compute_units} compute units, {d.global_mem_size >> 20} MiB)")
    from ..cl.lanes import (ENV_VAR as LANES_VAR, GATHER_ENV, device_gathers, device_lanes,
                            resolve_gathers, resolve_lanes)
    failed = None   # the one-line error (exit status 2) after the listing
    try:
        dev = select_device()
    except SceneError as e:
        dev, failed = None, e
        print(f"default device: none ({e})")
    if dev is not None:
        # (a bad $VOLMC_LANES or $VOLMC_GATHERS is the one-line error, after the listing)
        print(f"default device: {describe(dev)}")
        print(f"lanes: {resolve_lanes(None, dev)} paths per work-item (the device prefers "
              f"{dev.preferred_vector_width_float} floats a vector, so "
              f"{device_lanes(dev)} by default; --lanes or ${LANES_VAR} set it)")
        print(f"gathers: {resolve_gathers(dev)} ({device_gathers(dev)} by default on this "
              f"device; ${GATHER_ENV} sets it; the images are the same either way)")
    print(f"select another with --device PLATFORM[:DEVICE] or ${ENV_VAR}")
    cdir = cache_dir()
    n = len(list(cdir.glob("*.bin"))) if cdir.is_dir() else 0
    print(f"kernel cache: {cdir} ({n} programs; set VOLMC_CACHE_DIR to move it)")
    if failed is not None:
        raise failed
    return 0
