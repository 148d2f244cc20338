"""OpenCL platform and device choice.

Default: the first PoCL device (CPU OpenCL from PyPI). Another device is picked with
``--device`` or the environment variable VOLMC_CL_DEVICE, both in the form
``PLATFORM[:DEVICE]``: a platform index or a case-insensitive substring of its name, and a
device index within it (default 0), e.g. ``pocl``, ``0:1``, ``nvidia``.
"""

import os

from ..scene.errors import SceneError

ENV_VAR = "VOLMC_CL_DEVICE"
POCL_NAME = "Portable Computing Language"


def list_devices():
    """[(platform index, platform, [devices])] for every platform pyopencl sees."""
    import pyopencl as cl
    try:
        platforms = cl.get_platforms()
    except cl.Error:
        return []
    return [(i, p, p.get_devices()) for i, p in enumerate(platforms)]


def select_device(spec=None):
    """The pyopencl Device named by ``spec`` (or VOLMC_CL_DEVICE, or PoCL by default)."""
    source = "--device"
    if spec is None:
        spec = os.environ.get(ENV_VAR) or None
        source = ENV_VAR
    plats = list_devices()
    if not plats:
        raise SceneError("OpenCL", "platforms", "no OpenCL platform found (is "
                         "pocl-binary-distribution installed?)")
    if spec is None:
        for _, p, devs in plats:
            if POCL_NAME in p.name and devs:
                return devs[0]
        for _, p, devs in plats:
            if devs:
                return devs[0]
        raise SceneError("OpenCL", "devices", "no OpenCL device found")
    plat_part, _, dev_part = str(spec).partition(":")
    chosen = None
    if plat_part.isascii() and plat_part.isdigit():   # "²".isdigit(), but int("²") fails
        idx = int(plat_part)
        if idx < len(plats):
            chosen = plats[idx]
    else:
        for entry in plats:
            if plat_part.lower() in entry[1].name.lower() or \
                    (plat_part.lower() == "pocl" and POCL_NAME in entry[1].name):
                chosen = entry
                break
    if chosen is None:
        names = ", ".join(f"{i}: {p.name}" for i, p, _ in plats)
        raise SceneError(source, spec, f"no such OpenCL platform (have {names})")
    devs = chosen[2]
    if dev_part == "":
        dev_idx = 0
    elif dev_part.isascii() and dev_part.isdigit():
        dev_idx = int(dev_part)
    else:
        raise SceneError(source, spec, "device part must be an index, e.g. 0:1")
    if dev_idx >= len(devs):
        raise SceneError(source, spec, f"platform '{chosen[1].name}' has {len(devs)} device(s)")
    return devs[dev_idx]


def describe(device):
    """One-line description of a device."""
    return (f"{device.platform.name} / {device.name} ({device.version}, driver "
            f"{device.driver_version}, {device.max_compute_units} compute units)")
