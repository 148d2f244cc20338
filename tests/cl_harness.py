"""Build kernels/testing.cl once per session and run its wrapper kernels on numpy arrays."""

import functools

import numpy as np
import pyopencl as cl

from volmc.cl.build import assemble, build_program
from volmc.cl.device import select_device


@functools.lru_cache(maxsize=None)
def harness(options=("-DFEATURE_PHASE_HG", "-DFEATURE_GRID")):
    dev = select_device()
    ctx = cl.Context([dev])
    queue = cl.CommandQueue(ctx)
    prg, _ = build_program(ctx, dev, assemble("testing.cl"), list(options))
    return ctx, queue, prg


@functools.lru_cache(maxsize=None)
def kernel(name):
    """A kernel object, retrieved once."""
    return cl.Kernel(harness()[2], name)


def to_dev(a):
    ctx, _, _ = harness()
    a = np.ascontiguousarray(a)
    return cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR, hostbuf=a)


def out_buf(shape, dtype=np.float32):
    ctx, _, _ = harness()
    host = np.empty(shape, dtype)
    return host, cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, max(host.nbytes, 4))


def run(name, n, *args, outs=()):
    """Launch kernel ``name`` over n work items; copy back the (host, buffer) pairs in outs."""
    _, queue, prg = harness()
    kernel(name)(queue, (n,), None, *args)
    for host, buf in outs:
        cl.enqueue_copy(queue, host, buf)
    queue.finish()
    return [h for h, _ in outs]


def f3(v):
    """float3 kernel argument."""
    return np.array([v[0], v[1], v[2], 0.0], np.float32)


def i3(v):
    """int3 kernel argument."""
    return np.array([v[0], v[1], v[2], 0], np.int32)


def build_source(name, source, options=()):
    """Build a test kernel given as source text (it may include the kernel headers)."""
    ctx, _, _ = harness()
    prg, _ = build_program(ctx, ctx.devices[0], assemble(name, {name: source}), list(options))
    return prg


def run_kernel(program, name, n, *args, outs=()):
    """Launch kernel ``name`` of ``program`` over n work items; copy back ``outs``."""
    _, queue, _ = harness()
    cl.Kernel(program, name)(queue, (n,), None, *args)
    for host, buf in outs:
        cl.enqueue_copy(queue, host, buf)
    queue.finish()
    return [h for h, _ in outs]
