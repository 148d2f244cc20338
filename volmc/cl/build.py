"""Program build with an on-disk binary cache.

Kernel sources in ``kernels/`` are assembled into one translation unit: ``#include "x.h"``
lines are replaced by the file's text (once each); ``params.h`` is generated from
volmc/params.py and volmc/constants.py, ``features.h`` from volmc/scene/features.py. The
cache key is the SHA-256 of that full text, the build options, and the device identity
(platform, device name, version, driver), so any change to a header, a flag or the driver
rebuilds. Binaries live in VOLMC_CACHE_DIR (default ~/.cache/volmc/cl).
"""

import hashlib
import os
import re
from pathlib import Path

from ..resources import kernels_dir
from ..scene.features import features_header
from .structs import params_header

CACHE_ENV = "VOLMC_CACHE_DIR"
_INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)".*$', re.M)
_memory_cache = {}

#: Options every build gets. No fast-math flags: see docs/numerical_robustness.md, "Fast math".
BASE_OPTIONS = ("-cl-std=CL1.2",)


def cache_dir() -> Path:
    """Folder of cached program binaries."""
    d = os.environ.get(CACHE_ENV)
    return Path(d) if d else Path.home() / ".cache" / "volmc" / "cl"


def assemble(filename, extra_headers=None):
    """Full source text of ``kernels/<filename>`` with includes expanded (each once)."""
    headers = {"params.h": params_header(), "features.h": features_header()}
    headers.update(extra_headers or {})
    seen = set()
    kdir = kernels_dir()

    def expand(name):
        if name in seen:
            return ""
        seen.add(name)
        text = headers[name] if name in headers else (kdir / name).read_text()
        return _INCLUDE.sub(lambda m: expand(m.group(1)), text)

    return expand(filename)


def device_identity(device):
    """String identifying a device and driver for the cache key."""
    return "|".join([device.platform.name, device.platform.version, device.name,
                     device.version, device.driver_version])


def cache_key(source, options, device):
    h = hashlib.sha256()
    for part in (source, " ".join(options), device_identity(device)):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()


def build_program(context, device, source, options=()):
    """Build (or load from the caches) a program for one device. Returns (program, how)
    where how is "memory", "disk" or "compiled"."""
    import pyopencl as cl
    options = list(BASE_OPTIONS) + list(options)
    key = cache_key(source, options, device)
    mkey = (key, context.int_ptr)
    if mkey in _memory_cache:
        return _memory_cache[mkey], "memory"
    path = cache_dir() / f"{key}.bin"
    if path.exists():
        try:
            prg = cl.Program(context, [device], [path.read_bytes()]).build(options=options)
            _memory_cache[mkey] = prg
            return prg, "disk"
        except (cl.Error, OSError):
            pass  # stale or corrupt binary: rebuild below
    prg = cl.Program(context, source).build(options=options, devices=[device])
    try:
        binary = prg.get_info(cl.program_info.BINARIES)[0]
        if binary:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix(f".tmp{os.getpid()}")
            tmp.write_bytes(binary)
            os.replace(tmp, path)
    except (cl.Error, OSError):
        pass  # caching is an optimisation; a read-only home must not stop a render
    _memory_cache[mkey] = prg
    return prg, "compiled"
