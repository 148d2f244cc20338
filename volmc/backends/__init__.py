"""Render backends: the declared interface (base.py) and its two implementations, the OpenCL
kernels (opencl.py, the default) and the Numba float64 reference (numba.py)."""

from .base import BACKENDS, RenderBackend, make_backend, techniques  # noqa: F401
