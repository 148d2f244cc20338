"""Reading environment maps (lights.environment.file): lat-long RGB images, float.

EXR goes through OpenEXR (a dependency; every compression it reads, DWAB included). Other
formats (Radiance .hdr, ...) go through OpenImageIO, the optional extra ``volmc[images]``;
without it they get a one-line error naming the extra. Every texel must be finite and
non-negative; the error counts the bad ones. A luminance channel alone (Y) is taken as grey.
Maps are cached by path, size and modification time: every backend of a render packs the
same map.
"""

import contextlib
import os
import stat
import struct
import sys
import tempfile

import numpy as np

from .errors import SceneError
from .hostmem import require_host

#: Files this large are refused before they are read (a lat-long map of 32768 x 16384 RGB
#: float32 texels is 6 GiB).
MAX_TEXELS = 1 << 29

EXR_MAGIC = 0x01312F76
#: Bytes of an EXR's headers read before OpenEXR is trusted with the file.
EXR_HEADER_BYTES = 1 << 20
EXR_PIXEL_BYTES = {0: 4, 1: 2, 2: 4}   # uint, half, float

_cache = {}


def read_env_map(path, scene_file, key):
    """The map at ``path`` as float32 [H, W, 3]; SceneError(scene_file or path, key) if it
    cannot be read or has bad texels."""
    try:
        st = os.stat(path)
    except OSError as e:
        raise SceneError(scene_file, key, f"cannot read {path}: {e.strerror}") from None
    if not stat.S_ISREG(st.st_mode):   # a directory fails late; a FIFO would block the read
        raise SceneError(scene_file, key, f"not a regular file: {path}")
    tag = (str(path), st.st_size, st.st_mtime_ns)
    if tag not in _cache:
        _cache.clear()   # one map at a time: a scene has at most one
        _cache[tag] = _validated(_read(path, key), path, key)
    return _cache[tag]


def light_texels(light, scene_file, i):
    """The texels of environment light ``light`` (lights[i] of ``scene_file``): those the
    loaded scene carries, else read from its file."""
    if light.texels is not None:
        return light.texels
    return read_env_map(light.resolved, scene_file, f"lights[{i}].file")


def _read(path, key):
    if str(path).lower().endswith(".exr"):
        return _read_exr(path, key)
    try:
        import OpenImageIO as oiio
    except ImportError:
        raise SceneError(path, key, "reading this format needs OpenImageIO: pip install "
                                    "'volmc[images]' (or give an OpenEXR .exr map)") from None
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise SceneError(path, key, f"not an image OpenImageIO reads: {oiio.geterror()}")
    try:
        spec = inp.spec()
        if spec.width * spec.height > MAX_TEXELS:
            raise SceneError(path, key, f"{spec.width} x {spec.height} texels; at most "
                                        f"{MAX_TEXELS} are read")
        px = inp.read_image(0, 0, 0, min(spec.nchannels, 3), "float")
    finally:
        inp.close()
    if px is None:
        raise SceneError(path, key, f"cannot read the pixels: {oiio.geterror()}")
    px = np.asarray(px, np.float32).reshape(spec.height, spec.width, -1)
    return px if px.shape[2] == 3 else np.repeat(px[..., :1], 3, axis=2)


@contextlib.contextmanager
def _output_to(sink):
    """Redirect file descriptors 1 and 2, where OpenEXR's bindings and library report damage
    they read past, to the file ``sink`` for the block."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    try:
        os.dup2(sink.fileno(), 1)
        os.dup2(sink.fileno(), 2)
        yield
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        for fd, old in zip((1, 2), saved):
            os.dup2(old, fd)
            os.close(old)


def _exr_needs(path, key):
    """(texels, bytes per texel of all channels) of the largest part of an EXR, from its
    headers: OpenEXR's bindings allocate every channel of the data window as the header
    declares it, so a damaged dataWindow would have them ask for terabytes."""
    def bad(why):
        return SceneError(path, key, f"not a readable OpenEXR file: damaged header ({why})")

    with open(path, "rb") as f:
        data = f.read(EXR_HEADER_BYTES)
    if len(data) < 8 or struct.unpack_from("<I", data)[0] != EXR_MAGIC:
        raise bad("no OpenEXR magic number")
    flags = struct.unpack_from("<I", data, 4)[0]
    pos, parts, part = 8, [], {}
    while True:
        end = data.find(b"\0", pos)
        if end < 0:
            raise bad("the headers do not end")
        name = data[pos:end]
        pos = end + 1
        if not name:                       # the end of a header
            parts.append(part)
            if not flags & 0x1000 or data[pos:pos + 1] == b"\0":   # single part, or last
                break
            part = {}
            continue
        end = data.find(b"\0", pos)
        if end < 0 or end + 5 > len(data):
            raise bad("an attribute runs past the headers")
        type_name = data[pos:end]
        size = struct.unpack_from("<i", data, end + 1)[0]
        pos = end + 5
        if size < 0 or pos + size > len(data):
            raise bad(f"attribute {name[:40]!r} of {size} bytes")
        value = data[pos:pos + size]
        pos += size
        if name == b"dataWindow" and type_name == b"box2i" and size == 16:
            x0, y0, x1, y1 = struct.unpack("<4i", value)
            part["texels"] = max(x1 - x0 + 1, 0) * max(y1 - y0 + 1, 0)
        elif name == b"channels" and type_name == b"chlist":
            nbytes, at = 0, 0
            while at < len(value) and value[at:at + 1] != b"\0":
                e = value.find(b"\0", at)
                if e < 0 or e + 17 > len(value):
                    raise bad("channel list")
                nbytes += EXR_PIXEL_BYTES.get(struct.unpack_from("<i", value, e + 1)[0], 4)
                at = e + 17
            part["bytes"] = nbytes
    return max(((p.get("texels", 0), p.get("bytes", 0)) for p in parts),
               key=lambda tb: tb[0] * max(tb[1], 1))


def _read_exr(path, key):
    import OpenEXR
    texels, nbytes = _exr_needs(path, key)
    if texels > MAX_TEXELS:
        raise SceneError(path, key, f"{texels} texels; at most {MAX_TEXELS} are read")
    # The channels as OpenEXR holds them, their float32 planes and the stacked map.
    require_host(texels * (nbytes + 4 * 3 * 2), path, key,
                 f"reading a map of {texels} texels")
    with tempfile.TemporaryFile() as log:
        try:
            with _output_to(log), OpenEXR.File(str(path), separate_channels=True) as f:
                ch = f.channels()
                names = "RGB" if all(c in ch for c in "RGB") else "YYY" if "Y" in ch else None
                if names is None:
                    raise SceneError(path, key, f"no R, G, B (or Y) channels; the file has "
                                                f"{', '.join(sorted(ch)) or 'none'}")
                planes = [np.asarray(ch[c].pixels, np.float32) for c in names]
        except SceneError:
            raise
        except Exception as e:   # OpenEXR raises bare exceptions on damaged files
            raise SceneError(path, key, f"not a readable OpenEXR file: "
                                        f"{(str(e).splitlines() or [type(e).__name__])[0]}") \
                from None
        log.seek(0)
        said = log.read().decode("utf-8", "replace").strip()
    if said:   # the library read past damage (a truncated file: missing scanlines)
        raise SceneError(path, key, "not a readable OpenEXR file: "
                                    f"{said.splitlines()[0].strip()[:200]}")
    if planes[0].ndim != 2 or planes[0].size > MAX_TEXELS:
        raise SceneError(path, key, f"expected a 2-D image of at most {MAX_TEXELS} texels, "
                                    f"got shape {planes[0].shape}")
    return np.stack(planes, axis=-1)


def _validated(px, path, key):
    if px.shape[0] < 1 or px.shape[1] < 1:
        raise SceneError(path, key, "the map has no texels")
    bad = ~np.isfinite(px) | (px < 0.0)
    if bad.any():
        n = int(bad.any(axis=2).sum())
        raise SceneError(path, key, f"{n} of {px.shape[0] * px.shape[1]} texels are negative, "
                                    "NaN or infinite; an environment's radiance must be "
                                    "finite and >= 0")
    return np.ascontiguousarray(px, np.float32)
