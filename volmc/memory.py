"""Memory limits, checked before any work: what a render will allocate against what there is.

``estimate(scene, backend)`` lists, per component, the bytes a render of a loaded scene
allocates on the host and on the OpenCL device: the film (float64 sums and squares, and the
peak of writing the EXR, variance EXR and PNG at the end), the density grid as the backend
holds it (the scene's float32 copy, the packed copy in the backend's precision, the device
buffer or brick pool), the emission field, the majorant structure (grid or octree, with its
build), and the per-launch buffers of one band of pixels (Numba's counters per pixel; the
OpenCL kernel's samples, at most ``params.launch_spp`` per pixel, their host copy and the
host's float64 temporaries). ``check_memory`` compares
the sums with the host memory available (``host_available``: $VOLMC_MEMORY_LIMIT, else
/proc/meminfo MemAvailable, else os.sysconf) and, for OpenCL, with the device's
global_mem_size and max_mem_alloc_size (one buffer may not exceed it), and raises the
one-line SceneError naming the key of the largest component.

The figures count what exists at the same time: the scene's loaded grids are counted as
needed and as available (they are already held), an OpenCL device of type CPU (PoCL)
allocates its buffers in host memory, so they count against the host as well.

Per-launch buffers grow with the pixels of a launch, so a large image is rendered in bands
of rows (``band_rows``): at most LAUNCH_BUDGET bytes (and 1/LAUNCH_FRACTION of the memory
available) per launch. Samples are keyed by pixel index and sample index, so the image is
the same bit for bit however it is banded.
"""

import math
from dataclasses import dataclass

import numpy as np

from .scene.hostmem import ENV_VAR, fmt_bytes, host_available, parse_size  # noqa: F401
from .film import ALBEDO_CHANNELS, CHANNELS
from .params import N_COUNTERS, launch_spp
from .scene.errors import SceneError

#: Per-launch buffers of one band at most this many bytes...
LAUNCH_BUDGET = 256 << 20
#: ... and at most this fraction of the memory available.
LAUNCH_FRACTION = 8

#: Film: float64 sums and sums of squares, CHANNELS (RGBA) each; the albedo AOV adds its
#: channels.
FILM_BYTES_PER_PIXEL = 2 * CHANNELS * 8
FILM_ALBEDO_BYTES_PER_PIXEL = 2 * ALBEDO_CHANNELS * 8
#: Peak above the film of writing its outputs (volmc render): the mean image (float64) with
#: its float32 EXR copies (37 B/pixel), the variance of the mean with its temporaries
#: (74 B/pixel with --variance) or the PNG (the mean, its 8-bit copy and matplotlib's RGBA:
#: about 64 B/pixel). Measured with tracemalloc on a 512^2 film (tests/test_memory.py).
OUTPUT_BYTES_PER_PIXEL = 80
#: Numba, per pixel of a launch: the per-pixel counters (int64).
COUNTER_BYTES_PER_PIXEL = N_COUNTERS * 8
#: OpenCL, per sample of a launch (the kernel writes every sample, kernels/integrator.cl):
#: float32 RGBA on the device and its host copy. The per-work-item counters are a few bytes
#: per sample more, counted with the samples.
CL_SAMPLE_BYTES = CHANNELS * 4
#: With the albedo AOV a sample is 8 floats (RGBA, the AOV and a pad), 7 of them summed.
CL_ALBEDO_SAMPLE_BYTES = 8 * 4
#: OpenCL, per pixel of a launch and summed channel: the host's float64 temporaries of the
#: accumulation (backends/opencl.py, accumulate_samples: the sum, the sum of squares and one
#: sample column).
CL_TEMP_BYTES_PER_CHANNEL = 3 * 8
CL_COUNTER_BYTES_PER_SAMPLE = 1
#: glibc's largest dynamic mmap threshold (64-bit): smaller arrays may come from the heap,
#: whose freed pages stay resident below a live allocation.
MMAP_THRESHOLD_MAX = 32 << 20



@dataclass
class Component:
    """One thing a render allocates: the scene ``key`` responsible, a description, bytes on
    the host and on the device, and the largest single device buffer. ``phase``: None for
    what is held through the whole render, else the step (PHASES) whose transient
    allocation it is: only one step runs at a time."""
    key: str
    what: str
    host: int = 0
    device: int = 0
    buffer: int = 0
    phase: str = None


#: The steps of a render whose allocations do not coexist (``Component.phase``):
#: "majorant", the backend's build of its majorant structure (the partial reductions);
#: "render", the backend's buffers (its packed copies, the device buffers, the launch
#: buffers); "write", writing the outputs at the end.
PHASES = ("majorant", "render", "write")


def _peak(components, side):
    """Bytes of ``side(c)`` held at the peak: the held components plus the largest phase."""
    held = sum(side(c) for c in components if c.phase is None)
    phases = {}
    for c in components:
        if c.phase is not None:
            phases[c.phase] = phases.get(c.phase, 0) + side(c)
    return held + max(phases.values(), default=0)


@dataclass
class Estimate:
    """The components of a render and the band of rows each launch covers."""
    components: list
    band_rows: int
    height: int
    device_is_host: bool = True

    @property
    def host(self):
        """Host bytes at the peak (with the device's on a CPU device): what is held through
        the render and the largest step's transients (``Component.phase``)."""
        return _peak(self.components,
                     lambda c: c.host + (c.device if self.device_is_host else 0))

    @property
    def device(self):
        return _peak(self.components, lambda c: c.device)

    def by_key(self):
        """{key: Component with the bytes of every component of that key at its peak: the
        held ones summed, plus its largest step}."""
        out, groups = {}, {}
        for c in self.components:
            s = out.setdefault(c.key, Component(c.key, c.what))
            s.what = c.what   # the last: what the backend holds
            s.buffer = max(s.buffer, c.buffer)
            groups.setdefault(c.key, []).append(c)
        for key, cs in groups.items():
            out[key].host = _peak(cs, lambda c: c.host)
            out[key].device = _peak(cs, lambda c: c.device)
        return out


def device_limits(device):
    """(global_mem_size, max_mem_alloc_size, is a CPU device, name) of a pyopencl Device."""
    import pyopencl as cl
    return (int(device.global_mem_size), int(device.max_mem_alloc_size),
            bool(device.type & cl.device_type.CPU), device.name.strip())


def _emission_key(scene):
    e = scene.medium.emission
    return "medium.emission.field" if e.radiance is not None else "medium.emission.temperature"


def launch_bytes_per_pixel(backend, width, height, albedo=False):
    """(host, device, largest device buffer) bytes per pixel of one launch of ``backend``
    for a width x height image: OpenCL keeps every sample of a launch, of which a pixel has
    at most ``params.launch_spp`` (the render's batch schedule); ``albedo``: with the
    albedo AOV."""
    if backend == "numba":
        return COUNTER_BYTES_PER_PIXEL, 0, 0
    spp = launch_spp(width * height)
    sample = CL_ALBEDO_SAMPLE_BYTES if albedo else CL_SAMPLE_BYTES
    temp = CL_TEMP_BYTES_PER_CHANNEL * (CHANNELS + (ALBEDO_CHANNELS if albedo else 0))
    return (spp * sample + temp, spp * (sample + CL_COUNTER_BYTES_PER_SAMPLE), spp * sample)


def band_rows(width, height, backend, available=None, max_alloc=None, albedo=False):
    """Rows of pixels per launch: all of them unless the launch buffers of the whole image
    would exceed LAUNCH_BUDGET, 1/LAUNCH_FRACTION of ``available`` bytes or, per device
    buffer, ``max_alloc``; at least one row."""
    if available is None:
        available = host_available()[0]
    host, device, buffer = launch_bytes_per_pixel(backend, width, height, albedo)
    budget = LAUNCH_BUDGET
    if available is not None:
        budget = min(budget, available // LAUNCH_FRACTION)
    pixels = budget // (host + device)
    if max_alloc is not None and buffer:
        pixels = min(pixels, max_alloc // buffer)   # the largest buffer
    return int(max(1, min(height, pixels // max(width, 1))))


def _reduction_bytes(shape_zyx, cells_zyx):
    """Peak bytes of build_majorant_grid (reference/majorant.py) of a [nz, ny, nx] float32
    grid into (cz, cy, cx) cells: one axis at a time, each step holding its input, the
    per-cell parts and their concatenation (float32), the slab np.take copies for one
    cell, and during the minima's pass the maxima (4 bytes a cell)."""
    nz, ny, nx = shape_zyx
    cz, cy, cx = cells_zyx
    cells = cz * cy * cx
    x = 8 * nz * ny * cx + 4 * nz * ny * (-(-nx // cx) + 2)
    y = 4 * nz * ny * cx + 8 * nz * cy * cx + 4 * nz * (-(-ny // cy) + 2) * cx
    z = 4 * nz * cy * cx + 8 * cells + 4 * (-(-nz // cz) + 2) * cy * cx
    return 4 * cells + max(x, y, z)


def _occupied_bricks(g, n_bricks):
    """Non-empty 8^3 bricks of the dense grid ``g`` (one pass, no copy) when its sides are
    multiples of 8, else ``n_bricks`` (every brick)."""
    nz, ny, nx = g.shape
    if nz % 8 or ny % 8 or nx % 8 or not g.flags.c_contiguous:
        return n_bricks
    b = np.asarray(g).reshape(nz // 8, 8, ny // 8, 8, nx // 8, 8)
    return int(np.count_nonzero(b.max(axis=(1, 3, 5))))


@dataclass
class _Majorant:
    """What packing a scene's majorant structure allocates (_majorant): its scene key, a
    description, the host bytes at the build's peak and those the packed scene keeps, the
    cells of its finest level, and its device bytes and largest buffer."""
    key: str
    what: str
    peak: int
    held: int
    cells: int
    device: int
    buffer: int


def _majorant(scene, g, real):
    """The _Majorant of ``scene``'s majorant structure over grid ``g`` packed in reals of
    ``real`` bytes: the build (and the copies in that precision made while its float32
    result is held), then what the packed scene keeps; None without one (global)."""
    from .reference.majorant import auto_resolution
    from .reference.octree import octree_depth
    m = scene.render.majorant
    if m == "grid":
        res = scene.render.majorant_resolution
        cells_zyx = tuple(reversed(res)) if res else auto_resolution(g.shape)
        cells = math.prod(cells_zyx)
        build = _reduction_bytes(g.shape, cells_zyx)
        # pack_majorant: float32 maxima and minima, then their copies in ``real``.
        peak = max(build, 8 * cells + (2 * cells * real if real != 4 else 0))
        return _Majorant("render.majorant_resolution", "the majorant grid", peak,
                         2 * cells * real, cells, 8 * cells, 4 * cells)
    if m == "octree":
        n = 2 ** octree_depth(g.shape)
        cells = n ** 3
        nodes = cells * 8 // 7 + 1
        build = _reduction_bytes(g.shape, (n, n, n))
        # build_octree, with the finest level held: its pyramid (8/7), per node the bounds
        # and children of the lists, their concatenation and the casts (24 bytes), the
        # frontier's int64 coordinates and float64 spread (32).
        tree = 8 * cells + 8 * cells // 7 + nodes * (12 + 24 + 32)
        held = nodes * (2 * real + 4)
        return _Majorant("render.majorant", "the majorant octree", max(build, tree + held),
                         held, cells, nodes * 12, nodes * 4)
    return None


def _density_components(scene, backend):
    from .scene.bricks import BrickGrid, stores_bricks
    real = 8 if backend == "numba" else 4
    cl = backend != "numba"
    g = scene.grid
    out = []
    if g is None:
        return out
    nz, ny, nx = g.shape
    voxels = nz * ny * nx
    held = g.nbytes if isinstance(g, BrickGrid) else g.size * g.itemsize
    out.append(Component("medium.density", "the loaded density grid", host=held))
    # What density_storage makes for every pack (made), the pack's density in the backend's
    # reals beside it on the host, and the device buffers.
    if stores_bricks(scene):
        n_bricks = math.ceil(nx / 8) * math.ceil(ny / 8) * math.ceil(nz / 8)
        if isinstance(g, BrickGrid):
            slots, made = g.pool.shape[0], 0
        else:   # from the dense grid: its non-empty bricks, and the index table
            slots = _occupied_bricks(g, n_bricks) + 1
            made = 4 * n_bricks + slots * 512 * 4
        table, pool32 = 4 * n_bricks, slots * 512 * 4
        packed = slots * 512 * real if real != 4 else 0   # the table is shared
        what, dev, buf = "the density bricks", table + pool32, pool32
        host = made + packed if cl else packed + table
    else:
        made = voxels * 4 if isinstance(g, BrickGrid) else 0   # the dense array
        copied = not isinstance(g, BrickGrid) and (g.dtype != np.float32
                                                    or not g.flags.c_contiguous)
        # float32 in C order stays shared with the scene
        packed = voxels * real if (real != 4 or copied) else 0
        what, dev, buf = "the density grid", voxels * 4, voxels * 4
        host = made + packed
    maj = _majorant(scene, g, real)
    if maj is not None:
        # A build whose float32 result is small leaves its results on the heap above the
        # partial reductions, so the allocator keeps those pages for the rest of the
        # process (measured: 19 MiB after a 32^3 build of a 256^3 grid); later builds reuse
        # them. A build with large results keeps up to the heap's share (measured: 30 MiB
        # with 256^3 cells).
        small = maj.cells * 4 < MMAP_THRESHOLD_MAX
        out.append(Component(maj.key, f"{maj.what}'s build (pages the allocator keeps)",
                             host=maj.peak if small else min(maj.peak, MMAP_THRESHOLD_MAX)))
        if not small:
            out.append(Component(maj.key, f"{maj.what}'s build", host=made + maj.peak,
                                 phase="majorant"))
        # The backend's pack (OpenCL's until its buffers are made, Numba's through the
        # render) and the device buffers.
        out.append(Component(maj.key, maj.what, host=maj.held, device=maj.device if cl else 0,
                             buffer=maj.buffer if cl else 0, phase="render"))
    out.append(Component("medium.density", what, host=host, device=dev if cl else 0,
                         buffer=buf if cl else 0, phase="render"))
    return out


def _emission_components(scene, backend):
    e = scene.emission_grid
    if e is None:
        return []
    real = 8 if backend == "numba" else 4
    cl = backend != "numba"
    key = _emission_key(scene)
    out = [Component(key, "the loaded emission grid", host=e.size * e.itemsize)]
    copied = real == 8 or e.dtype != np.float32
    out.append(Component(key, "the emission grid", host=e.size * real if copied else 0,
                         device=e.size * 4 if cl else 0, buffer=e.size * 4 if cl else 0,
                         phase="render"))
    return out


def _env_components(scene, backend):
    """The environment map, if any: the texels read (float32, RGB), the sampling density
    built in float64 (pdf and conditional CDF, one value per texel each) and kept in the
    backend's reals with the texels, and for OpenCL the flat buffer of all of it."""
    from .scene.envmap import light_texels
    from .scene.schema import EnvironmentLight
    for i, lt in enumerate(scene.lights):
        if isinstance(lt, EnvironmentLight) and lt.file is not None:
            key = f"lights[{i}].file"
            n = light_texels(lt, scene.file, i).shape[:2]
            n = n[0] * n[1]
            real = 8 if backend == "numba" else 4
            cl = backend != "numba"
            what = "the environment map and its sampling density"
            return [Component(key, what, host=n * 12 + n * 5 * 8 + n * 5 * real
                                    + (n * 20 if cl else 0), device=n * 20 if cl else 0,
                                    buffer=n * 20 if cl else 0, phase="render")]
    return []


def estimate(scene, backend="opencl", rows=None, available=None, max_alloc=None,
             device_is_host=True, film=True, scene_data=True, albedo=False):
    """The ``Estimate`` of a render of ``scene`` with ``backend`` ("opencl" or "numba") in
    bands of ``rows`` rows (None: ``band_rows`` for ``available`` and ``max_alloc``).
    film, scene_data: include the film, and the grids and majorant structure (a render
    given a backend already built has allocated the latter); albedo: with the albedo AOV."""
    w, h = scene.camera.resolution
    if rows is None:
        rows = band_rows(w, h, backend, available, max_alloc, albedo)
    rows = max(1, min(int(rows), h))
    comps = []
    if film:
        what = f"a {w}x{h} film"
        comps.append(Component("camera.resolution", what, host=w * h * (
            FILM_BYTES_PER_PIXEL + (FILM_ALBEDO_BYTES_PER_PIXEL if albedo else 0))))
        comps.append(Component("camera.resolution", what, host=w * h * OUTPUT_BYTES_PER_PIXEL,
                               phase="write"))
    if scene_data:
        parts = scene.media_scenes
        for i, part in enumerate(parts):
            own = _density_components(part, backend) + _emission_components(part, backend)
            if len(parts) > 1:   # each medium's keys, as the scene file names them
                for c in own:
                    c.key = c.key.replace("medium.", f"media[{i}].")
                if backend != "numba":   # pack.shared_buffers: every array once more
                    own.append(Component(f"media[{i}].density", "its share of the media's "
                                         "shared buffers", host=sum(c.device for c in own),
                                         phase="render"))
            comps += own
        comps += _env_components(scene, backend)
    host, device, buffer = launch_bytes_per_pixel(backend, w, h, albedo)
    px = rows * w
    comps.append(Component("camera.resolution",
                           f"the launch buffers of {rows} row{'s' if rows > 1 else ''}",
                           host=px * host, device=px * device, buffer=px * buffer,
                           phase="render"))
    return Estimate(comps, rows, h, device_is_host)


def check_memory(scene, backend="opencl", device=None, rows=None, film=True,
                 scene_data=True, albedo=False):
    """Raise SceneError(scene file, key, what) when a render of ``scene`` would not fit:
    the host's memory, or for "opencl" the device's global memory or its largest buffer.
    The key is that of the largest component. ``device``: a pyopencl Device or a --device
    spec (None: the default). Returns the Estimate."""
    available, source = host_available()
    max_alloc, glob, is_cpu, name = None, None, True, ""
    if backend == "opencl":
        from .cl.device import select_device
        dev = select_device(device) if device is None or isinstance(device, str) else device
        glob, max_alloc, is_cpu, name = device_limits(dev)
    held = 0
    if available is not None and source != ENV_VAR:
        # Already loaded, so not in MemAvailable; counted as needed below.
        held = sum(c.host for c in _density_components(scene, backend)[:1]
                   + _emission_components(scene, backend)[:1]) if scene_data else 0
    est = estimate(scene, backend, rows, None if available is None else available + held,
                   max_alloc, is_cpu, film, scene_data, albedo)
    keys = est.by_key()
    w, h = scene.camera.resolution

    def fail(where, need, have, how):
        # The largest component on that side names the key.
        side = (lambda c: c.host + (c.device if is_cpu else 0)) if where == "host" else \
            (lambda c: c.device)
        top = max(keys.values(), key=side)
        what = f"a {w}x{h} film" if top.key == "camera.resolution" else top.what
        raise SceneError(scene.file, top.key,
                         f"{what} needs {fmt_bytes(side(top))} of {where} memory (the render "
                         f"{fmt_bytes(need)} in all), {fmt_bytes(have)} {how}")

    if available is not None and est.host > available + held:
        fail("host", est.host, available + held, f"available ({source})")
    if backend == "opencl" and est.device > glob:
        fail("device", est.device, glob, f"on {name} (global_mem_size)")
    if max_alloc is not None:
        big = max(est.components, key=lambda c: c.buffer)
        if big.buffer > max_alloc:
            raise SceneError(scene.file, big.key,
                             f"{big.what} needs a device buffer of {fmt_bytes(big.buffer)}, "
                             f"{name} allows {fmt_bytes(max_alloc)} per buffer "
                             "(max_mem_alloc_size)")
    return est
