"""Checkpoints of a render in progress, and resuming from them.

A checkpoint holds what a render has accumulated -- the film's per-pixel sums of sample
values and of their squares, the samples per pixel done (the finished global sample range
[0, spp) of every pixel), the counters and the rendering time so far -- and what it is a
render *of*: the resolved scene (its TOML as ``serialize.to_toml`` writes it, so overrides
count), a SHA-256 of each grid the scene holds (density and emission), the seed, the
backend and the sampler. Resuming refuses, with the one-line error, a checkpoint of any
other scene, grid, seed, backend or sampler, since its samples would not be the ones the
requested render draws.

Checkpoints are written only between chunks, and chunks follow the fixed schedule of
``render.chunk_schedule``, so a render resumed from a checkpoint adds the same chunks in
the same order as an uninterrupted one: the image is the same bit for bit. Writes are atomic (a temporary
file in the same directory, then ``os.replace``), so a render killed at any moment, even by
SIGKILL, leaves the previous checkpoint intact and loses at most one interval of work.

File format: a NumPy ``.npz`` archive (whatever the file's name) with arrays ``sum`` and
``sum_sq`` (float64 [height, width, 3]), ``counters`` (int64 [N_COUNTERS], in
``params.COUNTER_NAMES`` order) and ``header``, a JSON string: format version, spp done,
seconds, the identity above, and ``digest``, a SHA-256 of the other fields and the arrays
(``content_digest``): an edit that leaves every value plausible (spp 100 for 4096 made the
resumed image 1.98x too bright, with coverage 1.86) is refused as one.
"""

import hashlib
import json
import math
import os

import numpy as np

from .film import ALBEDO_CHANNELS, Film
from .outputs import written_whole
from .params import COUNTER_NAMES
from .scene.schema import MAX_SPP
from .scene.errors import SceneError
from .scene.grids import npy_header

#: Bumped when the layout changes; older files are refused with a message saying so. 2: the
#: lane counters, and the lane width in the identity. 3: the film's A channel (RGBA sums).
#: 4: the scene frame in the identity (several media moved to the nearest box's frame).
#: 5: the content digest, and every medium's grids hashed.
FORMAT_VERSION = 5

#: What must match for a checkpoint to be resumed, with the words the error uses.
IDENTITY = (("seed", "seed"), ("sampler", "render.sampler"), ("backend", "backend"),
            ("lanes", "lane width"), ("grids", "grids"), ("frame", "scene frame"),
            ("scene_toml", "scene"))


def grid_hashes(scene):
    """{name: SHA-256 hex} of the density and emission grids the scene holds, of every
    medium ("density", "emission" for the first, "media[i].density", ... for the others;
    exact bytes, shape and dtype), so a grid file changed on disk is noticed. (The first
    medium's alone were hashed: a resume mixed two renders of a changed second medium.)"""
    out = {}
    grids = []
    for i, part in enumerate(scene.media_scenes):
        at = "" if i == 0 else f"media[{i}]."
        grids += [(at + "density", part.grid), (at + "emission", part.emission_grid)]
    for name, arr in grids:
        if arr is not None:
            h = hashlib.sha256()
            _hash_array(h, arr)
            out[name] = h.hexdigest()
    return out


def _hash_array(h, arr):
    """Feed hash ``h`` an array's dtype, shape and exact bytes (C order)."""
    a = np.ascontiguousarray(arr)
    h.update(f"{a.dtype.str}{a.shape}".encode())
    h.update(memoryview(a).cast("B"))


def identity(scene, backend, lanes=None):
    """The identity record of a render of ``scene`` on ``backend`` (a backend name) at lane
    width ``lanes`` (OpenCL's; None for Numba). The scene's render.spp is left out: a render
    may resume towards more samples. The lane width is in: each lane traces its sample's path,
    but the vector maths library may round differently from the scalar one
    (docs/lanes.md), so another width need not give the same image bit for bit."""
    import dataclasses
    from .pack import scene_frame
    from .scene.serialize import to_toml
    spec = dataclasses.replace(scene.spec, render=dataclasses.replace(scene.spec.render, spp=1))
    centre, unit = scene_frame(scene)   # the kernels' float32 numbers are those of this frame
    # A grid given as a numpy array (Python API) is identified by its hash in "grids"; the
    # TOML records where it stands and its shape.
    return {"scene_toml": to_toml(spec, array_as=_array_stand_in), "grids": grid_hashes(scene),
            "seed": str(scene.render.seed), "backend": backend,
            "lanes": lanes, "sampler": scene.render.sampler,
            "frame": [float(x) for x in centre] + [float(unit)]}


def _array_stand_in(a):
    # The shape only: the values (as the scene holds them, in float32) are in the hash.
    return {"array": [int(n) for n in np.shape(a)]}


def content_digest(header, arrays):
    """SHA-256 (hex) of a checkpoint's header record (without its digest; keys sorted) and
    of its arrays (dtype, shape and bytes, in the order given)."""
    h = hashlib.sha256(json.dumps({k: v for k, v in header.items() if k != "digest"},
                                  sort_keys=True).encode())
    for a in arrays:
        _hash_array(h, a)
    return h.hexdigest()


def save(path, film, counters, seconds, ident):
    """Atomically write a checkpoint: ``film`` (its sums and spp), ``counters`` (dict by
    COUNTER_NAMES), ``seconds`` of rendering so far and the identity record."""
    header = {"format": FORMAT_VERSION, "spp": int(film.spp), "seconds": float(seconds),
              "width": film.width, "height": film.height, **ident}
    cnt = np.array([counters.get(n, 0) for n in COUNTER_NAMES], np.int64)
    header["digest"] = content_digest(header, (film.sum, film.sum_sq, cnt))
    with written_whole(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, sum=film.sum, sum_sq=film.sum_sq, counters=cnt,
                 header=np.array(json.dumps(header)))
        f.flush()
        os.fsync(f.fileno())


def missing(path):
    """The SceneError of a --resume path that is no file (raised by ``load``, and by
    ``volmc render`` before it announces the render): none there, or a directory, FIFO or
    device."""
    if os.path.exists(path):
        return SceneError(path, "--resume", "not a regular file")
    return SceneError(path, "--resume", "no such checkpoint file")


def _check_member_sizes(z, path):
    """Refuse an archive member whose .npy header declares more bytes than the whole file
    holds, before numpy allocates them: volmc writes checkpoints uncompressed, so such a
    header is damage (a flipped bit in a shape can declare terabytes)."""
    limit = os.path.getsize(path)
    for name in z.zip.namelist():
        with z.zip.open(name) as m:
            shape, _, dtype = npy_header(m, z.zip.getinfo(name).file_size)
        if math.prod(shape) * dtype.itemsize > limit:
            raise SceneError(path, "--resume", f"not a volmc checkpoint (its member {name} "
                                               f"declares more bytes than the file holds)")


def held_spp(path):
    """The spp done of the volmc checkpoint at ``path``, or None when there is none (no
    file, or a file of another kind)."""
    if not os.path.isfile(path):
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            _check_member_sizes(z, path)
            header = json.loads(str(z["header"][()]))
    except Exception:   # noqa: BLE001 -- not a checkpoint volmc can read
        return None
    spp = header.get("spp") if isinstance(header, dict) and "format" in header else None
    return spp if type(spp) is int else None


def refuse_overwrite(path, resume, file, key, resume_hint):
    """Raise SceneError(file, key) when the checkpoint a render would write to, ``path``,
    holds another render's work (a checkpoint, not the one it resumes, ``resume``): a
    command run twice must not replace hours of samples with a fresh start. ``resume_hint``:
    how the caller continues one ("--resume", "resume=")."""
    if path is None or (resume is not None and
                        os.path.realpath(path) == os.path.realpath(resume)):
        return
    spp = held_spp(path)
    if spp is not None:
        raise SceneError(file, key, f"{path} holds a checkpoint of {spp} spp: continue it with "
                                    f"{resume_hint}{path}, or delete it to start again")


def load(path, scene, backend, lanes=None, albedo=False):
    """(film, counters dict, seconds) of the checkpoint at ``path``, after checking it is a
    checkpoint of a render of ``scene`` on ``backend`` (a backend name) at lane width
    ``lanes``. Anything else -- no such file, not a checkpoint, another format version,
    another scene, grid, seed, backend, lane width or sampler, another resolution, with or
    without the albedo AOV unlike ``albedo`` -- raises SceneError(path, "--resume", ...)."""
    def bad(what):
        return SceneError(path, "--resume", what)
    if not os.path.isfile(path):
        raise missing(path)
    # Any failure to parse is the file's: it may be damaged, truncated or another .npy/.npz.
    try:
        z = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise missing(path) from None
    except Exception as e:   # noqa: BLE001
        raise bad(f"not a volmc checkpoint ({type(e).__name__})") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise bad("not a volmc checkpoint (an .npy array, not an .npz archive)")
    try:
        with z:
            _check_member_sizes(z, path)
            header = json.loads(str(z["header"][()]))
            s, sq, cnt = z["sum"], z["sum_sq"], z["counters"]
    except SceneError:
        raise
    except Exception as e:   # noqa: BLE001
        raise bad(f"not a volmc checkpoint ({type(e).__name__})") from None
    if not isinstance(header, dict):
        raise bad("not a volmc checkpoint (its header is not a record)")
    if header.get("format") != FORMAT_VERSION:
        raise bad(f"checkpoint format {header.get('format')}, this volmc reads "
                  f"{FORMAT_VERSION}")
    want = identity(scene, backend, lanes)
    for key, words in IDENTITY:
        if header.get(key) != want[key]:
            if key == "scene_toml":
                raise bad("the checkpoint is of a different scene (its resolved TOML differs; "
                          "compare with -D overrides and the scene file)")
            raise bad(f"the checkpoint has {words} {header.get(key)!r}, this render "
                      f"{want[key]!r}" if key != "grids" else
                      "the checkpoint's grids differ from the scene's (a grid file changed, "
                      "or another array was given)")
    w, h = scene.camera.resolution
    film = Film(w, h, albedo)
    if s.shape[-1:] == (film.channels + ALBEDO_CHANNELS,) or \
            s.shape[-1:] == (film.channels - ALBEDO_CHANNELS,):
        raise bad("the checkpoint was rendered " + ("without" if albedo else "with")
                  + " the albedo AOV of --denoise: resume it " + ("with" if not albedo else
                                                                   "without") + " --denoise")
    if s.shape != film.sum.shape or sq.shape != film.sum.shape or \
            cnt.shape != (len(COUNTER_NAMES),):
        raise bad("the checkpoint's arrays do not match the scene's resolution")
    spp, seconds = header.get("spp"), header.get("seconds")
    if type(spp) is not int or not 0 < spp <= MAX_SPP:
        raise bad(f"the checkpoint's spp {spp!r} is not a sample count")
    if type(seconds) not in (int, float) or not 0.0 <= seconds < float("inf"):
        raise bad(f"the checkpoint's seconds {seconds!r} are not a time")
    if s.dtype.kind != "f" or sq.dtype.kind != "f" or cnt.dtype.kind not in "iu" or \
            not (np.isfinite(s).all() and np.isfinite(sq).all()) or (sq < 0.0).any() or \
            (cnt < 0).any():
        raise bad("the checkpoint's sums or counters are damaged (not finite, or negative)")
    if header.get("digest") != content_digest(header, (s, sq, cnt)):
        raise bad("the checkpoint was edited or damaged (its digest does not match its "
                  "contents)")
    film.sum[...] = s
    film.sum_sq[...] = sq
    film.spp = spp
    return film, dict(zip(COUNTER_NAMES, (int(x) for x in cnt))), float(seconds)
