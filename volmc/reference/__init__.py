"""Numba float64 reference implementations (twins of kernels/).

Numba's on-disk cache checks only the source file of each cached function, not the modules
it calls, so after an upgrade a cached integrator could run stale inlined code. The cache
therefore lives in a folder keyed by a hash of every reference module, volmc/params.py and
volmc/constants.py (whose values the compiled functions freeze in):
``~/.cache/volmc/numba/<hash>`` (unless NUMBA_CACHE_DIR is set).
"""

import hashlib
import os
from pathlib import Path


def _set_numba_cache_dir():
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    here = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for f in sorted(here.glob("*.py")) + [here.parent / "params.py", here.parent / "constants.py"]:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    import numba
    numba.config.CACHE_DIR = str(base / "volmc" / "numba" / h.hexdigest()[:16])


_set_numba_cache_dir()
