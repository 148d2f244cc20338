"""Program build with an on-disk binary cache.

Kernel sources in ``kernels/`` are assembled into one translation unit: ``#include "x.h"``
lines are replaced by the file's text (once each); ``params.h`` is generated from
volmc/params.py and volmc/constants.py, ``features.h`` from volmc/scene/features.py. The
cache key is the SHA-256 of that full text, the build options, and the device identity
(platform, device name, version, driver), so any change to a header, a flag or the driver
rebuilds. Binaries live in VOLMC_CACHE_DIR (default ~/.cache/volmc/cl), each behind a magic
and the SHA-256 of its bytes: a file cut short (a full disk, a killed copy) or damaged is
rebuilt, never handed to the driver, since PoCL aborts or crashes on a truncated binary.
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

#: The start of a cache file, before the binary's SHA-256 and the binary.
CACHE_MAGIC = b"VOLMCBIN1\0"

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
    binary = read_cached(path)
    if binary is not None:
        try:
            prg = cl.Program(context, [device], [binary]).build(options=options)
            _memory_cache[mkey] = prg
            return prg, "disk"
        except cl.Error:
            pass  # stale binary: rebuild below
    prg = cl.Program(context, source).build(options=options, devices=[device])
    try:
        write_cached(path, prg.get_info(cl.program_info.BINARIES)[0])
    except cl.Error:
        pass
    _memory_cache[mkey] = prg
    return prg, "compiled"


def read_cached(path):
    """The binary of cache file ``path``, or None when there is none or it is not whole."""
    try:
        data = Path(path).read_bytes()
    except OSError:
        return None
    n = len(CACHE_MAGIC)
    binary = data[n + 32:]
    if not data.startswith(CACHE_MAGIC) or hashlib.sha256(binary).digest() != data[n:n + 32] \
            or not binary:
        return None
    return binary


def write_cached(path, binary):
    """Store ``binary`` at cache file ``path`` whole (a temporary file, then a rename).
    Caching is an optimisation: a read-only or full disk must not stop a render, nor leave
    a temporary file behind."""
    if not binary:
        return
    path = Path(path)
    tmp = path.with_suffix(f".tmp{os.getpid()}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_bytes(CACHE_MAGIC + hashlib.sha256(binary).digest() + binary)
        os.replace(tmp, path)
    except OSError:
        try:
            tmp.unlink()
        except OSError:
            pass
