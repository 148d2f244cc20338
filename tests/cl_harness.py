"""Test kernels (kernels/testing.cl and sources given as text) on the shared OpenCL context
(volmc.cl.context): build once per session, launch on numpy arrays."""

import functools

import numpy as np

from volmc.cl.context import cl_context


def clc():
    """The default device's ClContext (shared with the renderer and the benchmarks)."""
    return cl_context()


@functools.lru_cache(maxsize=None)
def harness(options=()):
    """The program built from kernels/testing.cl."""
    return clc().program("testing.cl", options)[0]


@functools.lru_cache(maxsize=None)
def kernel(name):
    """A kernel of testing.cl, retrieved once."""
    return clc().kernel(harness(), name)


def to_dev(a):
    return clc().to_device(a)


def out_buf(shape, dtype=np.float32):
    return clc().output(shape, dtype)


def run(name, n, *args, outs=()):
    """Launch testing.cl kernel ``name`` over n work items; copy back the (host, buffer)
    pairs in outs."""
    return clc().run(kernel(name), n, None, *args, outs=outs)


def build_source(name, source, options=()):
    """Build a test kernel given as source text (it may include the kernel headers)."""
    return clc().program(name, options, {name: source})[0]


def run_kernel(program, name, n, *args, outs=()):
    """Launch kernel ``name`` of ``program`` over n work items; copy back ``outs``."""
    return clc().run(clc().kernel(program, name), n, None, *args, outs=outs)


def f3(v):
    """float3 kernel argument."""
    return np.array([v[0], v[1], v[2], 0.0], np.float32)


def i3(v):
    """int3 kernel argument."""
    return np.array([v[0], v[1], v[2], 0], np.int32)
