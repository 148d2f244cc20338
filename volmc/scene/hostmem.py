"""Host memory at hand, and the check a large allocation makes before it is made.

``host_available`` is the figure every check compares with: $VOLMC_MEMORY_LIMIT when set
(bytes, or a K, M, G or T suffix), else /proc/meminfo's MemAvailable, else the free pages
os.sysconf reports. ``require_host`` turns an allocation that would not fit into the
one-line SceneError naming the file and key responsible. The scene loader checks each grid
with it before reading or generating it; volmc/memory.py checks a whole render.
"""

import os

from .errors import SceneError

#: Environment variable overriding the host memory available (bytes, or a K/M/G/T suffix).
ENV_VAR = "VOLMC_MEMORY_LIMIT"
_SUFFIXES = {"": 1, "B": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


def parse_size(text, where=ENV_VAR):
    """Bytes of ``text``: an integer with an optional K, M, G or T suffix (powers of 1024,
    an optional trailing "B" or "iB")."""
    t = str(text).strip().upper().replace("IB", "").rstrip("B") if str(text).strip() else ""
    num, suffix = t, ""
    if t and t[-1] in _SUFFIXES:
        num, suffix = t[:-1], t[-1]
    try:
        v = float(num)
    except ValueError:
        v = float("nan")
    if not (v == v and 0 < v < float("inf")):
        raise SceneError("environment", where, f"expected bytes with an optional K, M, G or T "
                                               f"suffix (e.g. 100M), got {text!r}")
    return int(v * _SUFFIXES[suffix])


def host_available():
    """(bytes of host memory available, where the figure comes from), or (None, why)."""
    env = os.environ.get(ENV_VAR)
    if env:
        return parse_size(env), ENV_VAR
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024, "MemAvailable"
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"), "free pages"
    except (ValueError, OSError, AttributeError):
        return None, "unknown"


def fmt_bytes(n):
    """1.5 GiB, 20.3 MiB, 12 KiB, 100 B."""
    for unit, shift in (("TiB", 40), ("GiB", 30), ("MiB", 20), ("KiB", 10)):
        if n >= 1 << shift:
            return f"{n / (1 << shift):.1f} {unit}"
    return f"{int(n)} B"


def require_host(nbytes, file, key, what):
    """Raise SceneError(file, key, ...) when ``what`` (a description: "generating a 512^3
    cloud") needs more than the host memory available, ``nbytes`` bytes at its peak; does
    nothing when the figure is unknown."""
    available, source = host_available()
    if available is not None and nbytes > available:
        raise SceneError(file, key, f"{what} needs {fmt_bytes(nbytes)} of host memory, "
                                    f"{fmt_bytes(available)} available ({source})")
