"""Density grids: reading, writing and validating .npy, .npz and Mitsuba .vol files.

Arrays are indexed [z, y, x] (x fastest), the order of Mitsuba's .vol and pbrt's uniformgrid.

Mitsuba .vol layout (little-endian): bytes b"VOL", version byte 3, int32 encoding
(1 = float32), int32 xres, yres, zres, channels, six float32 bounding-box values
(xmin, ymin, zmin, xmax, ymax, zmax), then float32 data indexed
((z * yres + y) * xres + x) * channels + c. volmc reads one-channel (density) volumes.
"""

import math
import os
import struct
import tokenize
import zipfile
import zlib

import numpy as np

from .hostmem import require_host
from .errors import SceneError

VOL_MAGIC = b"VOL"
VOL_VERSION = 3
VOL_ENCODING_FLOAT32 = 1
VOL_HEADER = struct.Struct("<3sBiiiii6f")
GRID_SUFFIXES = (".npy", ".npz", ".vol")


def read_vol(path, key="density"):
    """Read a one-channel Mitsuba .vol file. Returns (float32 array [z, y, x], bbox (6,))."""
    with open(path, "rb") as f:
        head = f.read(VOL_HEADER.size)
        if len(head) < VOL_HEADER.size:
            raise SceneError(path, key, f"truncated .vol header ({len(head)} bytes)")
        magic, version, enc, nx, ny, nz, ch, *bbox = VOL_HEADER.unpack(head)
        if magic != VOL_MAGIC:
            raise SceneError(path, key, "not a Mitsuba .vol file (missing 'VOL' magic)")
        if version != VOL_VERSION:
            raise SceneError(path, key, f".vol version {version} unsupported (need 3)")
        if enc != VOL_ENCODING_FLOAT32:
            raise SceneError(path, key, f".vol encoding {enc} unsupported (need 1 = float32)")
        if ch != 1:
            raise SceneError(path, key, f".vol has {ch} channels; a density grid needs 1")
        if min(nx, ny, nz) < 0:
            raise SceneError(path, key, f".vol has negative resolution {nx}x{ny}x{nz}")
        count = nx * ny * nz * ch
        # Check the declared size against the file before reading: a corrupt header must
        # not make numpy allocate (or overflow on) terabytes.
        avail = max(os.fstat(f.fileno()).st_size - VOL_HEADER.size, 0) // 4
        if count > avail:
            raise SceneError(path, key, f"truncated .vol data: {avail} of {count} values")
        # fromfile's array and its float32 copy (validate_grid's masks come after the
        # first is freed, and are smaller).
        require_host(count * 8, path, key, f"loading a {nx}x{ny}x{nz} grid")
        data = np.fromfile(f, dtype="<f4", count=count)
    if data.size != count:
        raise SceneError(path, key, f"truncated .vol data: {data.size} of {count} values")
    return data.reshape(nz, ny, nx).astype(np.float32), np.array(bbox, np.float32)


def write_vol(path, grid, bounds=((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))):
    """Write a [z, y, x] array as a one-channel float32 Mitsuba .vol file."""
    grid = np.ascontiguousarray(grid, dtype="<f4")
    if grid.ndim != 3:
        raise ValueError(f"grid must be 3-D, got shape {grid.shape}")
    nz, ny, nx = grid.shape
    lo, hi = bounds
    from ..outputs import written_whole
    with written_whole(path) as tmp, open(tmp, "wb") as f:
        f.write(VOL_HEADER.pack(VOL_MAGIC, VOL_VERSION, VOL_ENCODING_FLOAT32, nx, ny, nz, 1,
                                *[float(v) for v in lo], *[float(v) for v in hi]))
        f.write(grid.tobytes())


def read_grid_file(path, key="density", name="density"):
    """Read a grid array from .npy, .npz (array ``name``) or .vol, without validation."""
    suffix = os.path.splitext(path)[1].lower()
    if suffix not in GRID_SUFFIXES:
        raise SceneError(path, key, f"unknown grid format '{suffix}' (use .npy, .npz, .vol, "
                                    ".vdb or .nvdb)")
    if not os.path.isfile(path):
        raise SceneError(path, key, "grid file not found")
    try:
        if suffix == ".vol":
            return read_vol(path, key)[0]
        # np.load picks the format by content; the suffix must agree (a .npz holding an
        # .npy array has no "density" member to read).
        with open(path, "rb") as f:
            magic = f.read(len(np.lib.format.MAGIC_PREFIX))
            if suffix == ".npy":
                if magic != np.lib.format.MAGIC_PREFIX:
                    raise SceneError(path, key, "cannot read grid: not a .npy file")
                f.seek(0)
                _check_npy_size(f, os.fstat(f.fileno()).st_size, path, key)
        if suffix == ".npy":
            return np.load(path, allow_pickle=False)
        if not magic.startswith(b"PK"):
            raise SceneError(path, key, "cannot read grid: not a .npz file (not a zip archive)")
        with np.load(path, allow_pickle=False) as z:
            if name not in z.files:
                raise SceneError(path, key, f".npz has no array '{name}' (has: "
                                 f"{', '.join(z.files) or 'nothing'})")
            # np.load lists a member "x.npy" as "x", and one stored without the suffix as is.
            member = name if name in z.zip.namelist() else f"{name}.npy"
            with z.zip.open(member) as m:
                shape, fortran, dtype = npy_header(m, z.zip.getinfo(member).file_size)
            require_host(load_peak_bytes(math.prod(shape), dtype, fortran), path, key,
                         f"loading a {shape_text(shape)} grid of {dtype}")
            return z[name]
    except SceneError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error, tokenize.TokenError,
            TypeError, OverflowError, MemoryError, NotImplementedError, RuntimeError,
            SyntaxError) as e:
        # Corrupt headers (numpy raises TypeError for a shape such as (True, 1, 1), and
        # SyntaxError for a header dict its literal parser cannot read) or
        # compressed data, sizes too large to allocate, and zip members of a version or
        # compression method zipfile does not implement, or marked encrypted (RuntimeError).
        text = (str(e).splitlines() or [type(e).__name__])[0]
        raise SceneError(path, key, f"cannot read grid: {text}") from None


#: The .npy format versions numpy writes and reads.
NPY_VERSIONS = ((1, 0), (2, 0), (3, 0))


def npy_header(f, size):
    """(shape, Fortran order, dtype) of the .npy stream ``f`` of ``size`` bytes, left at the
    start of its data: what numpy would allocate, read before it does. A header that
    claims more bytes than the stream holds is refused (ValueError) before it is read, since
    numpy reads a header's declared length in one piece (a flipped bit in a 4-byte length
    had it allocate 660 MB)."""
    version = np.lib.format.read_magic(f)
    if version not in NPY_VERSIONS:
        raise ValueError(f"unsupported .npy format version {version[0]}.{version[1]}")
    start = f.tell()
    width = 2 if version == (1, 0) else 4
    length = int.from_bytes(f.read(width), "little")
    if length > size - start - width:
        raise ValueError(f".npy header of {length} bytes in a stream of {size}")
    f.seek(start)
    read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                   else np.lib.format.read_array_header_2_0)
    return read_header(f)


def _check_npy_size(f, file_size, path, key):
    """Reject a .npy header that declares more data than the file holds, or than the host
    memory can load (before numpy allocates it)."""
    shape, fortran, dtype = npy_header(f, file_size)
    declared = math.prod(shape) * dtype.itemsize
    if declared > file_size - f.tell():
        raise SceneError(path, key, f"truncated .npy data: shape {shape} of {dtype} needs "
                                    f"{declared} bytes, the file holds {file_size - f.tell()}")
    require_host(load_peak_bytes(math.prod(shape), dtype, fortran), path, key,
                 f"loading a {shape_text(shape)} grid of {dtype}")


def load_peak_bytes(voxels, dtype=np.float32, fortran=False):
    """Peak host bytes of holding a grid of ``voxels`` values of ``dtype`` and validating it
    (validate_grid): the array, and on top of it either the one-byte-per-voxel mask of a
    check or, after the checks, the float32 C-order copy (made unless the array is float32
    in C order already)."""
    dtype = np.dtype(dtype)
    copied = dtype != np.float32 or fortran
    return voxels * (dtype.itemsize + (4 if copied else 1))


def shape_text(shape):
    """A [z, y, x] shape as the text errors use, x first: "512x256x128"."""
    return "x".join(str(n) for n in reversed(tuple(shape)))


def value_problem(v):
    """What makes a grid's values unfit for a density -- "2 NaN, 1 infinite and 3 negative
    values (minimum -0.5)", every kind counted at once, a negative infinity as infinite --
    or None. Its temporaries are a byte a value, one at a time (load_peak_bytes)."""
    real = v.dtype.kind == "f"
    n_nan = int(np.isnan(v).sum()) if real else 0
    n_inf = int(np.isinf(v).sum()) if real else 0
    n_neg = int((v < 0).sum()) - (int(np.isneginf(v).sum()) if real else 0)
    parts = [f"{n} {what}" for n, what in ((n_nan, "NaN"), (n_inf, "infinite"),
                                           (n_neg, "negative")) if n]
    if not parts:
        return None
    text = (", ".join(parts[:-1]) + " and " if len(parts) > 1 else "") + parts[-1] + \
        (" value" if n_nan + n_inf + n_neg == 1 else " values")
    if n_neg:
        low = np.min(v, where=np.isfinite(v), initial=0) if real else v.min()
        text += f" (minimum {float(low):g})"
    return text


def validate_grid(arr, file, key="density", name=None):
    """Check a density array (3-D, non-empty, real, finite, >= 0). Returns float32 C-order.
    ``name``: the grid's name in its file (a VDB file's), for the messages."""
    arr = np.asarray(arr)
    if arr.dtype.kind not in "fiu":
        raise SceneError(file, key, f"grid must hold real numbers, got dtype {arr.dtype}")
    if arr.ndim != 3:
        raise SceneError(file, key, f"grid must be 3-D [z, y, x], got shape {arr.shape}")
    if arr.size == 0:
        raise SceneError(file, key, f"grid is empty (shape {arr.shape})")
    # The checks' temporaries (a byte a voxel, one at a time) and the float32 copy unless the
    # array is one already: an array given in Python (a broadcast view, a memmap) has had no
    # check of its file's size.
    copy = not (arr.dtype == np.float32 and arr.flags.c_contiguous)
    require_host(arr.size * (1 + 4 * copy), file, key,
                 f"checking a {'x'.join(map(str, arr.shape[::-1]))} grid")
    problem = value_problem(arr)
    if problem:
        raise SceneError(file, key, f"{_grid_words(name)} contains {problem}")
    if float(arr.max()) > float(np.finfo(np.float32).max):
        raise SceneError(file, key, f"{_grid_words(name)} values overflow float32")
    out = np.ascontiguousarray(arr, dtype=np.float32)
    return out


def _grid_words(name):
    return "grid" if name is None else f"grid '{name}'"


def load_grid(path, key="density", name="density"):
    """Read and validate a grid file (.npz: its array ``name``); errors name the file and
    ``key``."""
    return validate_grid(read_grid_file(path, key, name), path, key)


def save_grid(path, grid, bounds=((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))):
    """Write a [z, y, x] grid as .npy, .npz (array "density") or .vol by the path's suffix."""
    suffix = os.path.splitext(path)[1].lower()
    if suffix == ".vol":
        write_vol(path, grid, bounds)
    elif suffix in (".npy", ".npz"):
        from ..outputs import written_whole
        with written_whole(path, suffix) as tmp:
            if suffix == ".npy":
                np.save(tmp, np.ascontiguousarray(grid, np.float32))
            else:
                np.savez_compressed(tmp, density=np.ascontiguousarray(grid, np.float32))
    else:
        raise SceneError(path, "output", f"unknown grid format '{suffix}' (use .npy, .npz "
                                         "or .vol)")
