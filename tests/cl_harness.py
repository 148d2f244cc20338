"""Test kernels (kernels/testing.cl and sources given as text) on the shared OpenCL context
(volmc.cl.context): build once per session and lane width, launch on numpy arrays.

The kernels are lane-generic (kernels/lanes.h): the tests that use this harness run at every
lane width through the ``lanes`` fixture (tests/conftest.py), which sets ``LANES``; a batch
of n elements is ceil(n / LANES) work-items with n appended as the last kernel argument
(``ClContext.run_lanes``)."""

import functools

import numpy as np

from volmc.cl.context import cl_context

#: The lane width the kernels are built and launched with (set by the ``lanes`` fixture).
LANES = 1


def clc():
    """The default device's ClContext (shared with the renderer and the benchmarks)."""
    return cl_context()


def lane_options(options=()):
    """``options`` with the current lane width and the device's gather kind."""
    from volmc.cl.lanes import lane_options as lanes, resolve_gathers
    return tuple(options) + tuple(lanes(LANES, resolve_gathers(clc().device)))


@functools.lru_cache(maxsize=None)
def _harness(options):
    return clc().program("testing.cl", options)[0]


def harness(options=()):
    """The program built from kernels/testing.cl at the current lane width."""
    return _harness(lane_options(options))


@functools.lru_cache(maxsize=None)
def _kernel(name, options):
    return clc().kernel(_harness(options), name)


def kernel(name):
    """A kernel of testing.cl, retrieved once per lane width."""
    return _kernel(name, lane_options())


def to_dev(a):
    return clc().to_device(a)


def out_buf(shape, dtype=np.float32):
    return clc().output(shape, dtype)


def run(name, n, *args, outs=()):
    """Launch testing.cl kernel ``name`` on a batch of n elements; copy back the (host,
    buffer) pairs in outs."""
    return clc().run_lanes(kernel(name), n, LANES, *args, outs=outs)


def run_rays(name, n_rays, n_per_ray, *args, outs=()):
    """Launch testing.cl kernel ``name`` on n_rays rays of n_per_ray estimates each (the
    lanes of a work-item share a ray); n_rays n_per_ray is appended as the batch size."""
    return clc().run_rays(kernel(name), n_rays, n_per_ray, LANES, *args,
                          np.int32(n_rays * n_per_ray), outs=outs)


def build_source(name, source, options=()):
    """Build a test kernel given as source text (it may include the kernel headers) at the
    current lane width."""
    return clc().program(name, lane_options(options), {name: source})[0]


def run_kernel(program, name, n, *args, outs=()):
    """Launch lane-generic kernel ``name`` of ``program`` on a batch of n elements."""
    return clc().run_lanes(clc().kernel(program, name), n, LANES, *args, outs=outs)


def f3(v):
    """float3 kernel argument."""
    return np.array([v[0], v[1], v[2], 0.0], np.float32)


def i3(v):
    """int3 kernel argument."""
    return np.array([v[0], v[1], v[2], 0], np.int32)
