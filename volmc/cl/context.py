"""OpenCL host plumbing, written once: device, context, queue, program builds, buffers, launches.

The renderer (``volmc.backends.opencl``), the estimator and lookup benchmarks and the test
kernels all go through ``ClContext``. One context is made per device and process
(``cl_context``), so programs built once are reused by every caller (``build.py`` caches them
in memory per context and on disk per device and driver).
"""

import functools

import numpy as np

from .build import assemble, build_program
from .device import select_device


class ClContext:
    """A device with its context and in-order queue."""

    def __init__(self, device):
        import pyopencl as cl
        self.cl = cl
        self.device = device
        self.ctx = cl.Context([device])
        self.queue = cl.CommandQueue(self.ctx)

    def program(self, filename, options=(), extra_headers=None):
        """Build ``kernels/<filename>`` (or a source given in ``extra_headers``) with
        ``options``. Returns (program, how): how is "memory", "disk" or "compiled"."""
        source = assemble(filename, extra_headers)
        return build_program(self.ctx, self.device, source, list(options))

    def kernel(self, program, name):
        """Kernel ``name`` of a built program."""
        return self.cl.Kernel(program, name)

    def to_device(self, array, dtype=None, writable=False):
        """A buffer initialised with a C-contiguous copy of ``array`` (as ``dtype``)."""
        a = np.ascontiguousarray(array, dtype)
        mf = self.cl.mem_flags
        flags = (mf.READ_WRITE if writable else mf.READ_ONLY) | mf.COPY_HOST_PTR
        if a.nbytes == 0:  # OpenCL buffers cannot be empty
            a = np.zeros(1, a.dtype)
        return self.cl.Buffer(self.ctx, flags, hostbuf=a)

    def output(self, shape, dtype=np.float32):
        """(host array, device buffer) pair for a kernel's output."""
        host = np.empty(shape, dtype)
        buf = self.cl.Buffer(self.ctx, self.cl.mem_flags.WRITE_ONLY, max(host.nbytes, 1))
        return host, buf

    def run(self, kernel, global_size, local_size, *args, outs=()):
        """Launch ``kernel`` over ``global_size`` work items (rounded up to a multiple of
        ``local_size``; None lets the driver choose), copy the (host, buffer) pairs of
        ``outs`` back and wait. Returns the host arrays."""
        n = int(global_size)
        if local_size is None:
            gsize, lsize = (n,), None
        else:
            ls = int(local_size)
            gsize, lsize = (-(-n // ls) * ls,), (ls,)
        kernel(self.queue, gsize, lsize, *args)
        for host, buf in outs:
            self.cl.enqueue_copy(self.queue, host, buf)
        self.queue.finish()
        return [h for h, _ in outs]

    def run_lanes(self, kernel, n, lanes, *args, outs=()):
        """Launch a lane-generic test or benchmark kernel (kernels/lane_io.h,
        ``lane_element``) over a batch of n elements at lane width ``lanes``: ceil(n / lanes)
        work-items of work-group size 1, with n appended as the last argument."""
        return self.run(kernel, -(-int(n) // lanes), 1, *args, np.int32(n), outs=outs)

    def run_rays(self, kernel, n_rays, n_per_ray, lanes, *args, outs=()):
        """Launch a lane-generic kernel over batches of rays (``ray_lanes`` in
        kernels/lane_io.h): ceil(n_per_ray / lanes) work-items per ray, so the lanes of a
        work-item share a ray and its medium."""
        return self.run(kernel, int(n_rays) * -(-int(n_per_ray) // lanes), 1, *args, outs=outs)

    def read(self, host, buf):
        """Copy a device buffer into ``host`` and wait."""
        self.cl.enqueue_copy(self.queue, host, buf)
        self.queue.finish()
        return host


@functools.lru_cache(maxsize=None)
def _context_for(device_key, device):
    return ClContext(device)


def cl_context(device=None):
    """The process-wide ClContext of ``device``: a pyopencl Device, a ``--device`` spec
    string, or None for the default device (``VOLMC_CL_DEVICE``, else the first PoCL one)."""
    if device is None or isinstance(device, str):
        device = select_device(device)
    return _context_for(device.int_ptr, device)
