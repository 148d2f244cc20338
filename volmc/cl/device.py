"""OpenCL platform and device choice.

Default: the first PoCL device (CPU OpenCL from PyPI) whose compiler works. Another device
is picked with ``--device`` or the environment variable VOLMC_CL_DEVICE, both in the form
``PLATFORM[:DEVICE]``: a platform index or a case-insensitive substring of its name (the
first matching platform whose compiler works, if any does), and a device index within it
(default 0), e.g. ``pocl``, ``0:1``, ``nvidia``.

"Whose compiler works": the PyPI PoCL (3.0, LLVM 14) cannot compile anything on a CPU its
LLVM does not know (AMD Zen 5, family 26: "unknown target CPU 'generic'"). A machine may
also have a newer PoCL installed system-wide (Debian: pocl-opencl-icd), which pyopencl's
ICD loader lists too; the default takes the first PoCL that builds a one-line kernel
(``compiler_error``; the verdict is cached on disk per device and driver).
"""

import functools
import json
import os

from ..scene.errors import SceneError
from .build import cache_dir, device_identity

ENV_VAR = "VOLMC_CL_DEVICE"
POCL_NAME = "Portable Computing Language"
_PROBE_SOURCE = "kernel void volmc_probe(global float *a) { a[0] = sqrt(a[0]); }"
_PROBE_FILE = "compilers.json"


def list_devices():
    """[(platform index, platform, [devices])] for every platform pyopencl sees."""
    import pyopencl as cl
    try:
        platforms = cl.get_platforms()
    except cl.Error:
        return []
    return [(i, p, p.get_devices()) for i, p in enumerate(platforms)]


@functools.lru_cache(maxsize=None)
def _probe(identity, device):
    path = cache_dir() / _PROBE_FILE
    try:
        known = json.loads(path.read_text())
    except (OSError, ValueError):
        known = {}
    if isinstance(known, dict) and identity in known:
        return known[identity]
    import pyopencl as cl
    try:
        cl.Program(cl.Context([device]), _PROBE_SOURCE).build(devices=[device])
        verdict = None
    except cl.Error as e:
        lines = [ln.strip() for ln in str(e).splitlines()]
        verdict = next((ln for ln in lines if ln.startswith("error:")), lines[0] if lines
                       else "build failed")
    try:
        known = known if isinstance(known, dict) else {}
        known[identity] = verdict
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".tmp{os.getpid()}")
        tmp.write_text(json.dumps(known, indent=1))
        os.replace(tmp, path)
    except OSError:
        pass   # the verdict is an optimisation, as the program cache is
    return verdict


def compiler_error(device):
    """None if ``device``'s OpenCL C compiler builds a one-line kernel, else the first error
    line of its build log (e.g. "error: unknown target CPU 'generic'")."""
    return _probe(device_identity(device), device)


def _compiler_advice(failures):
    """The one-line message for devices whose compilers all failed."""
    what = "; ".join(f"{d.name} ({d.platform.version.split('  ')[0]}): {err}"
                     for d, err in failures)
    hint = (" (PoCL's LLVM does not know this processor: install a PoCL built on a newer "
            "LLVM, e.g. Debian's pocl-opencl-icd, or choose a device with --device)"
            if any("target CPU" in err for _, err in failures) else "")
    return f"no OpenCL device here can compile kernels: {what}{hint}"


def select_device(spec=None):
    """The pyopencl Device named by ``spec`` (or VOLMC_CL_DEVICE, or PoCL by default); a
    pyopencl Device is itself."""
    import pyopencl as cl
    if isinstance(spec, cl.Device):
        return spec
    where, key = "command line", "--device"
    if spec is None:
        spec = os.environ.get(ENV_VAR) or None
        where, key = "environment", ENV_VAR
    plats = list_devices()
    if not plats:
        raise SceneError("OpenCL", "platforms", "no OpenCL platform found (is "
                         "pocl-binary-distribution installed?)")
    if spec is None:
        candidates = ([devs[0] for _, p, devs in plats if POCL_NAME in p.name and devs]
                      + [devs[0] for _, p, devs in plats if POCL_NAME not in p.name and devs])
        if not candidates:
            raise SceneError("OpenCL", "devices", "no OpenCL device found")
        failures = []
        for dev in candidates:
            err = compiler_error(dev)
            if err is None:
                return dev
            failures.append((dev, err))
        raise SceneError("OpenCL", "devices", _compiler_advice(failures))
    plat_part, _, dev_part = str(spec).partition(":")
    if not plat_part:
        raise SceneError(where, key, f"{spec}: expected PLATFORM[:DEVICE], e.g. 0 or pocl:0")
    chosen = None
    if plat_part.isascii() and plat_part.isdigit():   # "²".isdigit(), but int("²") fails
        idx = int(plat_part)
        if idx < len(plats):
            chosen = plats[idx]
    else:
        matches = [entry for entry in plats
                   if plat_part.lower() in entry[1].name.lower()
                   or (plat_part.lower() == "pocl" and POCL_NAME in entry[1].name)]
        # Several platforms match (two PoCLs): the first whose compiler works, if any does.
        working = [e for e in matches if e[2] and compiler_error(e[2][0]) is None]
        chosen = (working or matches or [None])[0]
    if chosen is None:
        names = ", ".join(f"{i}: {p.name}" for i, p, _ in plats)
        raise SceneError(where, key, f"{spec}: no such OpenCL platform (have {names})")
    devs = chosen[2]
    if dev_part == "":
        dev_idx = 0
    elif dev_part.isascii() and dev_part.isdigit():
        dev_idx = int(dev_part)
    else:
        raise SceneError(where, key, f"{spec}: the device part must be an index, e.g. 0:1")
    if dev_idx >= len(devs):
        raise SceneError(where, key, f"{spec}: platform '{chosen[1].name}' has {len(devs)} "
                                     "device(s)")
    return devs[dev_idx]


def describe(device):
    """One-line description of a device."""
    return (f"{device.platform.name} / {device.name} ({device.version}, driver "
            f"{device.driver_version}, {device.max_compute_units} compute units)")
