"""The Python API: load or build a scene, render it, estimate transmittance on your own rays.

Everything here is exported from ``volmc`` (``volmc.load_scene``, ``volmc.render``, ...) and
is a thin layer over what the command line runs: the same loader and validation
(volmc/scene/), the same render driver (volmc/render.py), the same estimator runners
(volmc/bench/transmittance_runner.py). Bad input raises ``volmc.VolmcError`` with the
one-line ``<file>: <key>: <what is wrong>`` message the CLI prints.

Units: lengths are world units, extinction ``scale * density`` is per world unit, radiance
is linear RGB (the scene's units), times are seconds.

Heavy modules (Numba, pyopencl, matplotlib) are imported inside the functions, so
``import volmc`` stays light.
"""

import contextlib
import os
import re
from dataclasses import dataclass, field

# VolmcError and VolmcWarning are exported by volmc/__init__.py, on first use (they live in
# volmc/scene/errors.py, and importing the scene package at once would import Numba).
__all__ = ["load_scene", "scene_from_dict", "render", "render_frames", "estimate_transmittance",
           "RenderedImage", "TransmittanceResult"]


def _error(file, key, message):
    """The SceneError (a VolmcError) for ``file``, ``key`` and ``message``, to raise."""
    from .scene.errors import SceneError as _SceneError
    return _SceneError(file, key, message)


#: Keys whose value may be a numpy array (a grid given directly), in `[medium]` or any
#: `[[media]]` entry (media.N); other arrays become lists.
_GRID_KEY = re.compile(r"(medium|media\.\d+)\.(density|emission\.field|emission\.temperature)")


def _plain(value, path=""):
    """``value`` with numpy scalars as Python numbers, tuples and arrays as lists (the types
    TOML gives the validator), except numpy arrays at a grid key, which are kept as grids."""
    import numpy as np
    if isinstance(value, np.ndarray):
        return value if _GRID_KEY.fullmatch(path) else value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, dict):
        return {k: _plain(v, f"{path}.{k}" if path else str(k)) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v, f"{path}.{i}") for i, v in enumerate(value)]
    return value


def _overrides(overrides):
    """Overrides for the loader: a dict of dotted keys (values made plain), a list of ``-D``
    strings, or one string."""
    if overrides is None:
        return ()
    if isinstance(overrides, dict):
        if not all(isinstance(k, str) for k in overrides):
            raise _error("overrides", "", "the keys of an overrides dict are dotted scene "
                                          "keys (text), such as 'render.spp'")
        return {k: _plain(v, k) for k, v in overrides.items()}
    if isinstance(overrides, str):
        return [overrides]
    if not isinstance(overrides, (list, tuple)) or \
            not all(isinstance(x, str) for x in overrides):
        raise _error("overrides", "", "expected a dict of dotted keys, or -D texts such as "
                                      f"'render.spp=16', got {type(overrides).__name__}")
    return list(overrides)


def load_scene(path=None, overrides=None, frame=None):
    """Load a scene file (TOML, docs/scene_format.md) and return a ``volmc.scene.Scene``.

    path: the ``.toml`` file; None loads the bundled default scene (the procedural cloud,
    ``scenes/cloud.toml``). Relative paths inside the file are relative to it.
    overrides: scene keys to change before validation, either a dict of dotted keys to
    Python values, ``{"render.spp": 16, "camera.resolution": [64, 64], "lights.0.radiance":
    0.5}`` (a numpy array as ``medium.density`` replaces the grid), or the CLI's ``-D``
    strings, ``["render.spp=16"]`` (values parsed as TOML). Array elements are addressed by
    a 0-based index.

    The Scene is immutable: ``scene.camera``, ``scene.medium``, ``scene.lights`` and
    ``scene.render`` are the validated dataclasses of volmc/scene/schema.py, ``scene.grid``
    the float32 density grid [z, y, x] (None when homogeneous). frame: the number put into
    grid file patterns such as ``file = "cache/density_{frame:04d}.vdb"`` (a scene with a
    pattern needs one; ``render_frames`` renders a sequence). Raises VolmcError.
    """
    from .resources import default_scene
    from .scene import load_scene as _load
    if path is not None and not isinstance(path, (str, os.PathLike)):
        raise _error("volmc.load_scene()", "path", f"expected a scene file path, got "
                                                   f"{type(path).__name__}")
    return _load(str(default_scene()) if path is None else os.fspath(path),
                 _overrides(overrides), _frame(frame, "volmc.load_scene()"))


def _frame(frame, where):
    return None if frame is None else _integer(frame, where, "frame", 0, 10**9 - 1)


def scene_from_dict(scene, base_dir=".", overrides=None, name="<dict>", frame=None):
    """Build a scene in Python and return a ``volmc.scene.Scene``.

    scene: a dict with the structure of the TOML file (``{"camera": {...}, "medium": {...},
    "lights": [{...}], "render": {...}}``), or a ``volmc.scene.SceneSpec`` built from the
    dataclasses of volmc/scene/schema.py (``Camera``, ``Medium``, ``ConstantDensity``, ...,
    ``ArrayDensity``). Either way it is validated exactly as a file is. Tuples and numpy
    values are accepted where the TOML has arrays and numbers.
    ``medium.density`` (and an emission ``field`` or ``temperature``) may be a numpy array
    [z, y, x] (x fastest, voxel centres as for grid files), checked like a grid file: 3-D,
    non-empty, real, finite and non-negative. The scene keeps a float32 copy.
    base_dir: the directory relative grid-file paths are resolved against.
    overrides, frame: as for ``load_scene``. name: the "file" errors name. Raises VolmcError.
    """
    from .scene import scene_from_dict as _from_dict
    return _from_dict(_scene_dict(scene, name), file=name, base_dir=base_dir,
                      overrides=_overrides(overrides),
                      frame=_frame(frame, "volmc.scene_from_dict()"))


def _scene_dict(scene, name):
    """A dict or SceneSpec as the plain dict the validator takes."""
    from .scene.schema import SceneSpec
    if isinstance(scene, SceneSpec):
        from .scene.serialize import to_dict
        scene = to_dict(scene)
    if not isinstance(scene, dict):
        raise _error(name, "", f"expected a dict or a SceneSpec, got {type(scene).__name__}")
    return _plain(scene)


def _as_scene(scene, where):
    """A Scene from a Scene, a scene file path, a dict or a SceneSpec."""
    from .scene import Scene
    if isinstance(scene, Scene):
        return scene
    if isinstance(scene, (str, os.PathLike)):
        return load_scene(scene)
    if isinstance(scene, dict) or type(scene).__name__ == "SceneSpec":
        return scene_from_dict(scene)
    raise _error(where, "scene", f"expected a Scene, a path or a dict, got "
                                     f"{type(scene).__name__}")


def _integer(v, where, key, lo, hi):
    import numbers
    if isinstance(v, bool) or not isinstance(v, numbers.Integral):
        raise _error(where, key, f"expected an integer, got {type(v).__name__} {v!r}")
    if not lo <= int(v) <= hi:
        raise _error(where, key, f"must be in [{lo}, {hi}], got {v}")
    return int(v)


def _flag(v, where, key):
    """``v`` as a bool: True or False (numpy's too), not any truthy value ("no" is not
    False)."""
    import numpy as np
    if not isinstance(v, (bool, np.bool_)):
        raise _error(where, key, f"expected True or False, got {type(v).__name__} {v!r}")
    return bool(v)


def _path(p, where, key, writable=False):
    """None, or the path ``p`` as a str (its directory must be writable if ``writable``)."""
    if p is None:
        return None
    if not isinstance(p, (str, os.PathLike)):
        raise _error(where, key, f"expected a path, got {type(p).__name__}")
    p = os.fspath(p)
    if writable:
        from .outputs import check_output
        check_output(p, key, where)
    return p


def _seconds(v, where, key):
    """A finite number of seconds >= 0, as float."""
    import math
    import numbers
    if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v) or v < 0:
        raise _error(where, key, f"expected a finite number of seconds >= 0, got {v!r}")
    return float(v)


def _backend_name(backend, device, where):
    from .backends import BACKENDS
    if not isinstance(backend, str) or backend not in BACKENDS:
        raise _error(where, "backend", f"must be one of {', '.join(map(repr, BACKENDS))}, "
                                           f"got {backend!r}")
    if backend != "opencl" and device is not None:
        raise _error(where, "device", "a device applies to the opencl backend only")
    return backend


def _device(device, backend, where, client=None):
    """``device`` as the renderer takes it: None, a pyopencl Device, or a spec string (a
    platform number given as an int becomes its text), checked now: a bad one is the
    one-line error. With a Dask ``client`` the workers choose the device by its spec: a
    Device object cannot travel to them."""
    if backend != "opencl" or device is None:
        return device
    import numbers
    import pyopencl as cl
    if isinstance(device, numbers.Integral) and not isinstance(device, bool):
        device = str(int(device))
    if not isinstance(device, (str, cl.Device)):
        raise _error(where, "device", f"expected a pyopencl Device or a spec such as '0:1', "
                                      f"got {type(device).__name__}")
    if client is not None and isinstance(device, cl.Device):
        raise _error(where, "device", "a Dask cluster's workers choose their device by a spec "
                                      "such as '0:0', not a pyopencl Device")
    from .cl.device import select_device
    from .scene.errors import SceneError
    try:
        select_device(device)
    except SceneError as e:   # named for the command line's --device; here it is device=
        if e.key != "--device":
            raise
        raise _error(where, "device", e.message) from None
    return device


def _lanes(lanes, backend, where):
    """``lanes`` checked (a width of volmc.cl.lanes.LANE_WIDTHS, or None: the default)."""
    if lanes is None:
        return None
    import numbers
    if isinstance(lanes, bool) or not isinstance(lanes, numbers.Integral):
        raise _error(where, "lanes", f"expected an integer, got {type(lanes).__name__} "
                                     f"{lanes!r}")
    from .cl.lanes import check_lanes
    if backend != "opencl":
        raise _error(where, "lanes", "a lane width applies to the opencl backend only")
    return check_lanes(lanes, where, "lanes")


def render(scene, spp=None, seed=None, backend="opencl", device=None, progress=True,
           client=None, checkpoint=None, checkpoint_every=60.0, resume=None, lanes=None,
           albedo=False):
    """Render a scene; returns a ``RenderedImage`` (``.image``, ``.variance``, ``.save()``).

    scene: a Scene (``load_scene``, ``scene_from_dict``), a scene file path or a scene dict.
    spp: samples per pixel (default: the scene's ``render.spp``). seed: in [0, 2^64)
    (default: ``render.seed``). The same scene, spp and seed give the same image, bit for
    bit, on a backend. backend: "opencl" (the kernels) or "numba" (the float64 reference).
    device: OpenCL device, a pyopencl Device or a spec string as for ``--device`` ("pocl",
    "0:1"; default ``$VOLMC_CL_DEVICE``, else the first PoCL device). lanes: OpenCL's paths
    per work-item, 1, 4, 8 or 16 (default ``$VOLMC_LANES``, else the device's preferred float
    vector width); the image depends on it only through the vector maths library's
    rounding, and a checkpoint records it. progress: show a tqdm
    bar on stderr. An interrupt (Ctrl-C, or the notebook's stop button) stops after the
    current chunk and returns the samples so far with ``partial`` True. Raises VolmcError.
    A guard that fired (lookups above the majorant, walks cut by render.max_steps, dropped
    samples: the image may be biased) issues a ``volmc.VolmcWarning``.

    client: render on a Dask cluster (``volmc[dask]``): a ``distributed.Client``, or a
    scheduler address such as "tcp://10.0.0.1:8786" (a client is opened and closed here).
    The image is the single-process one bit for bit; a worker that dies has its chunks run
    again. A cluster that fails (no worker within Dask's connect timeout, a task whose
    workers kept dying, the scheduler gone) raises ``volmc.distributed.ClusterError``, a
    VolmcError whose ``.result`` is the RenderedImage of the samples merged before (partial;
    None if there were none), which the checkpoint also holds. checkpoint: a path written
    atomically every ``checkpoint_every`` seconds and at the end (also when interrupted, or
    when the cluster failed); resume: a checkpoint of this scene, seed, sampler and
    backend to continue from (another is refused with VolmcError), which is then also the
    checkpoint unless ``checkpoint`` names another. The result equals an uninterrupted
    render bit for bit.

    albedo: also accumulate the albedo AOV (``RenderedImage.albedo``), which guides
    ``RenderedImage.denoised()``; the image is the same with it or without it.
    """
    from .render import render as _render
    where = "volmc.render()"
    scene = _as_scene(scene, where)
    keys = _render_keys(spp, seed, where)
    if keys:
        scene = scene.with_render(**keys)
    name = _backend_name(backend, device, where)
    device = _device(device, name, where, client)
    lanes = _lanes(lanes, name, where)
    albedo = _flag(albedo, where, "albedo")
    # As on the command line, a resumed render goes on checkpointing to its file.
    resume = _path(resume, where, "resume", writable=checkpoint is None)
    checkpoint = _path(checkpoint, where, "checkpoint", writable=True) or resume
    from .checkpoint import refuse_overwrite
    refuse_overwrite(checkpoint, resume, where, "checkpoint", "resume=")
    every = _seconds(checkpoint_every, where, "checkpoint_every")
    with _client(client, where) as client:
        # By name: the driver checks the memory the scene needs before it builds the backend.
        from .scene.errors import VolmcError
        try:
            result = _render(scene, backend=name, device=device, progress=bool(progress),
                             client=client, checkpoint=checkpoint, checkpoint_every=every,
                             resume=resume, lanes=lanes, albedo=albedo)
        except VolmcError as e:
            from .distributed import ClusterError
            if isinstance(e, ClusterError):
                raise _cluster_failed(e, where, scene, checkpoint) from e.__cause__
            if e.key != "--resume":
                raise
            # The checkpoint's errors name the command line's option; here it is resume=.
            raise _error(e.file, "resume", e.message) from None
    _warn_guards(result)
    return RenderedImage(result, scene)


def _cluster_failed(e, where, scene, checkpoint):
    """The ClusterError ``volmc.render`` raises for the driver's ``e``: its message says what
    failed and where the samples rendered before are (``.result``, a partial RenderedImage,
    and the checkpoint, which ``resume=`` continues)."""
    from .distributed import ClusterError
    if e.result is None or e.result.film.spp == 0:
        return ClusterError(e.reason, None, where, "client",
                            f"the Dask cluster failed: {e.reason}; nothing was rendered")
    image = RenderedImage(e.result, scene)
    kept = f"the {image.spp} spp rendered are this error's .result (partial)"
    if checkpoint is not None:
        kept += f" and in {checkpoint}: resume={checkpoint!r} continues the render"
    return ClusterError(e.reason, image, where, "client",
                        f"the Dask cluster failed: {e.reason}; {kept}")


def _render_keys(spp, seed, where):
    """{"spp": .., "seed": ..} of the ones given, checked."""
    keys = {}
    if spp is not None:
        keys["spp"] = _integer(spp, where, "spp", 1, 2**32 - 1)
    if seed is not None:
        keys["seed"] = _integer(seed, where, "seed", 0, 2**64 - 1)
    return keys


@contextlib.contextmanager
def _client(client, where):
    """The Dask client of a ``client`` argument: None, a Client as given, or one opened on a
    scheduler address and closed on leaving."""
    own = isinstance(client, str)
    if own and not client.strip():
        raise _error(where, "client", "expected a scheduler address such as "
                                      "'tcp://10.0.0.1:8786', got an empty string")
    if own:
        from .distributed import connect
        client = connect(scheduler=client, file=where, key="client")[0]
    elif client is not None and not hasattr(client, "submit"):
        raise _error(where, "client", f"expected a distributed.Client or a scheduler address, "
                                      f"got {type(client).__name__}")
    try:
        yield client
    finally:
        if own:
            from .distributed import close
            close(client)


def _warn_guards(result, prefix=""):
    """A VolmcWarning per guard that fired (the line ``volmc render`` prints)."""
    import warnings
    from .scene.errors import VolmcWarning
    for text in result.guard_warnings():
        # stacklevel 3: the caller of the API function
        warnings.warn(prefix + text, VolmcWarning, stacklevel=3)


def render_frames(scene, frames, output=None, spp=None, seed=None, backend="opencl",
                  device=None, progress=True, client=None, lanes=None, overrides=None,
                  base_dir=".", png=False, variance=False, exposure=0.0, tonemap="filmic",
                  denoise=False):
    """Render a frame sequence: the scene once per frame, its grid file patterns (``file =
    "cache/fluid_data_{frame:04d}.vdb"``) filled with the frame number.

    scene: a scene file path, or a scene dict (relative paths against ``base_dir``); not a
    loaded Scene, whose grids are one frame's. overrides: as for ``load_scene``.
    frames: frame numbers (``range(1, 49)``, a list, one int) or the ``--frames`` text
    ("1-48", "1-48:2", "7"). spp, seed, backend, device, lanes, progress, client: as for
    ``render``; each frame is the image ``render`` gives for the scene of that frame
    (``load_scene(..., frame=f)``), bit for bit, here or on the cluster.

    output: None renders in memory and returns {frame: RenderedImage}. An EXR path
    ("out/fire.exr") writes frame f to "out/fire.0001.exr" (4 digits), as
    ``volmc render --frames`` does, and returns {frame: EXR path}; frames whose EXR is
    complete (finished, not partial, of this scene, frame and backend) are skipped, so a
    call that was stopped or killed goes on where it was. png: also write "out/fire.0001.png"
    (``exposure``, ``tonemap`` as for ``RenderedImage.save``); variance: also
    "out/fire.0001.var.exr"; denoise: render with the albedo AOV and also write each
    frame's denoised preview, "out/fire.0001.denoised.exr" (and ".denoised.png" with png),
    as ``volmc render --frames --denoise``. Every frame's grid files are checked before the first frame
    renders: a missing one raises VolmcError naming the file and key and listing the frames
    on disk. An interrupt stops after the current frame, which is returned (and written)
    with ``partial`` True. A guard that fired issues a ``volmc.VolmcWarning`` naming the
    frame. Raises VolmcError.
    """
    from .frames import FrameSequence, render_sequence
    from .render import render as _render
    from .scene import Scene
    from .scene.loading import apply_overrides, raw_from_dict, read_raw
    where = "volmc.render_frames()"
    if isinstance(scene, Scene):
        raise _error(where, "scene", "a loaded Scene holds one frame's grids: pass the scene "
                                     "file or dict")
    if isinstance(scene, (str, os.PathLike)):
        file, file_dir = os.fspath(scene), None
        raw = read_raw(file, _overrides(overrides))
    else:
        file, file_dir = "<dict>", os.path.abspath(base_dir)
        raw = raw_from_dict(_scene_dict(scene, file), file, _overrides(overrides))
    keys = _render_keys(spp, seed, where)
    apply_overrides(raw, {f"render.{k}": v for k, v in keys.items()}, file)
    frames = _frame_list(frames, where)
    name = _backend_name(backend, device, where)
    device = _device(device, name, where, client)
    lanes = _lanes(lanes, name, where)
    png, variance, denoise = (_flag(v, where, k) for v, k in ((png, "png"),
                                                               (variance, "variance"),
                                                               (denoise, "denoise")))
    output = _path(output, where, "output", writable=True)
    if output is not None and (not output.lower().endswith(".exr")
                               or os.path.basename(output).lower() == ".exr"):
        raise _error(where, "output", f"expected a path ending in .exr after a name, got "
                                      f"{output!r}")
    if png:
        exposure, tonemap = _display(exposure, tonemap, where)
    if (png or variance or denoise) and output is None:
        raise _error(where, "png" if png else "variance" if variance else "denoise",
                     "needs an output path")
    if denoise:   # a missing denoiser fails before the first frame renders
        from .denoise import oidn
        oidn(where, "denoise")
    png = os.path.splitext(output)[0] + ".png" if png else None
    seq = FrameSequence(raw, file, file_dir, frames, "frames")
    plan = seq.plan(output, name, png, variance, denoise)

    with _client(client, where) as client:
        def render_one(frame_scene, label):
            from .distributed import ClusterError
            try:
                result = _render(frame_scene, backend=name, device=device,
                                 progress=bool(progress), client=client, lanes=lanes,
                                 label=label, albedo=bool(denoise))
            except ClusterError as e:   # (render_sequence writes a partial frame, then raises)
                raise _cluster_failed(e, where, frame_scene, None) from e.__cause__
            return RenderedImage(result, frame_scene)
        out = {}
        keys = {role: (where, role) for role in ("png", "variance", "denoise")}
        for done in render_sequence(seq, plan, render_one, png, variance, exposure, tonemap,
                                    bool(denoise), {**keys, "exr": (where, "output")}):
            out[done.frame] = done.exr if output else done.image
            if done.image is not None:
                _warn_guards(done.image.result, f"frame {done.frame}: ")
    return out


def _display(exposure, tonemap, where):
    """(exposure, tonemap) of a PNG checked: a finite number of stops (at most MAX_EXPOSURE
    either way, as --exposure), and one of TONE_OPERATORS."""
    import math
    import numbers
    from .film import MAX_EXPOSURE, TONE_OPERATORS
    if isinstance(exposure, bool) or not isinstance(exposure, numbers.Real) or \
            not math.isfinite(exposure) or abs(exposure) > MAX_EXPOSURE:
        raise _error(where, "exposure", f"expected a number of stops in [-{MAX_EXPOSURE:g}, "
                                        f"{MAX_EXPOSURE:g}], got {exposure!r}")
    if not isinstance(tonemap, str) or tonemap not in TONE_OPERATORS:
        raise _error(where, "tonemap", f"must be 'filmic' or 'clamp', got {tonemap!r}")
    return float(exposure), tonemap


def _frame_list(frames, where):
    """The frames argument as a list of distinct frame numbers."""
    from .frames import check_count, parse_frames
    if isinstance(frames, str):
        return list(parse_frames(frames, where, "frames"))
    import itertools
    import numbers
    from .frames import MAX_FRAMES
    if not isinstance(frames, bool) and isinstance(frames, numbers.Integral):
        frames = [frames]
    try:   # no more than one past the limit: range(10**9) is not built as a list
        frames = list(itertools.islice(iter(frames), MAX_FRAMES + 1))
    except TypeError:
        raise _error(where, "frames", f"expected frame numbers or a text such as '1-48', got "
                                      f"{type(frames).__name__}") from None
    if len(frames) > MAX_FRAMES:
        raise _error(where, "frames", f"more than {MAX_FRAMES} frames; at most {MAX_FRAMES} "
                                      "in one run")
    out = [_integer(f, where, "frames", 0, 10**9 - 1) for f in frames]
    if len(set(out)) != len(out):
        raise _error(where, "frames", "a frame is named twice")
    return list(check_count(out, where, "frames"))


class RenderedImage:
    """A finished (or interrupted) render.

    image: linear RGB radiance, float32 [height, width, 3], row 0 at the top.
    alpha: the coverage A = 1 - T per pixel, float32 [height, width]: T the camera ray's
    transmittance to the background, estimated by each sample's own path (with
    ``render.transparent_background``, ``image`` is premultiplied by it: composite with
    ``image + (1 - alpha) x plate``).
    variance: per-pixel variance of the mean (of ``image``), float32 [height, width, 3];
    inf with fewer than 2 samples per pixel. The standard error is ``sqrt(variance)``.
    counters: dict of the render's totals (``lookups``, ``scatter_events``, ``shadow_rays``,
    ``capped``, ``dropped``, ``over_majorant``). seconds: render time (s, without
    compilation). spp: samples per pixel rendered; seed; backend; partial: True if
    interrupted; scene: the Scene rendered; result: the driver's ``volmc.render.RenderResult``
    (its ``film`` holds the float64 sums). ``stats()``: samples/s and per-sample counts.
    ``save(path, variance=False)`` writes an EXR or PNG (and the variance EXR); in Jupyter
    the object shows as a tonemapped PNG.
    albedo: the albedo AOV, float32 [height, width, 3] (``volmc.render(albedo=True)``;
    None without it). ``denoised()``: a denoised preview of ``image`` (``volmc[denoise]``).
    """

    def __init__(self, result, scene):
        import numpy as np
        self.result = result
        self.scene = scene
        self.image = result.film.mean().astype(np.float32)
        self.alpha = result.film.alpha().astype(np.float32)
        self.variance = result.film.variance_of_mean().astype(np.float32)
        aov = result.film.albedo()
        self.albedo = None if aov is None else aov.astype(np.float32)
        self.counters = dict(result.counters)
        self.seconds = result.seconds
        self.spp = result.film.spp
        self.seed = result.seed
        self.backend = result.backend
        self.partial = result.partial

    def denoised(self):
        """A denoised preview of ``image``, float32 [height, width, 3]: Intel Open Image
        Denoise (the ``volmc[denoise]`` extra) on the linear radiance, guided by ``albedo``
        when the render accumulated it (``volmc.render(albedo=True)``), by the colour alone
        otherwise. ``image`` is unchanged: the preview is biased (it is a filter) and is
        for looking at, not for measuring. Raises VolmcError without the extra."""
        from .denoise import denoise
        return denoise(self.image, self.albedo, "RenderedImage.denoised()", "pyoidn",
                       variance=self.variance, coverage=self.alpha)

    def stats(self):
        """samples, samples_per_second, mean_path_length, lookups_per_sample, ... (dict)."""
        return self.result.stats()

    def metadata(self):
        """The EXR metadata ``volmc render`` writes (spp, seed, backend, time, counters, the
        scene as TOML when it has no array grid)."""
        meta = self.result.metadata()
        # As volmc render writes it: a scene file's absolute path ("<dict>" stays as it is).
        f = self.scene.file
        meta["scene"] = os.path.abspath(f) if os.path.isfile(f) else f
        try:
            from .scene.serialize import to_toml
            meta["scene_toml"] = to_toml(self.scene.spec)
        except TypeError:   # a numpy grid has no TOML form
            pass
        return meta

    def save(self, path, exposure=0.0, tonemap="filmic", variance=False, denoised=False):
        """Write the image: ``.exr`` (float32 RGBA with metadata, as ``volmc render``) or
        ``.png`` (tonemapped 8-bit sRGB: ``exposure`` in stops, ``tonemap`` "filmic" or
        "clamp"; RGBA with ``render.transparent_background``), chosen by the extension.
        ``variance``: also write the per-pixel variance of the mean to ``<path without its
        extension>.var.exr``, with the same metadata (as ``volmc render --variance``).
        ``denoised``: also write the denoised preview (``denoised()``, with the unbiased
        alpha) to ``<path without its extension>.denoised.exr`` or ``.png``, its metadata
        marked as denoised (as ``volmc render --denoise``).
        Returns the path of the image. Raises VolmcError."""
        from .film import variance_path, write_exr, write_png
        from .outputs import check_output
        where = "RenderedImage.save()"
        check_output(path, "path", where)
        path = os.fsdecode(path)
        suffix = os.path.splitext(path)[1].lower()
        if suffix not in (".exr", ".png"):
            raise _error(where, "path", f"expected a path ending in .exr or .png, got "
                                            f"{path!r}")
        if suffix == ".png":
            exposure, tonemap = _display(exposure, tonemap, where)
        variance = _flag(variance, where, "variance")
        denoised = _flag(denoised, where, "denoised")
        from .denoise import denoised_path
        # Before the image: a render's files are written all or none.
        if variance:
            check_output(variance_path(path), "variance", where)
        if denoised:   # before any file: a missing denoiser leaves nothing half written
            check_output(denoised_path(path), "denoised", where)
            from .denoise import denoise_film, denoised_metadata
            film = self.result.film
            rgba = denoise_film(film, where, "denoised")
        if suffix == ".exr":
            write_exr(path, self.result.film.rgba(), self.metadata())
        else:
            write_png(path, self.image, exposure, tonemap, alpha=self.alpha if
                      self.scene.render.transparent_background else None)
        if variance:
            write_exr(variance_path(path), self.variance, self.metadata())
        if denoised:
            if suffix == ".exr":
                write_exr(denoised_path(path), rgba,
                          denoised_metadata(self.metadata(), film.has_albedo, path))
            else:
                write_png(denoised_path(path), rgba[..., :3], exposure, tonemap,
                          alpha=rgba[..., 3] if self.scene.render.transparent_background
                          else None)
        return path

    def png_bytes(self, exposure=0.0, tonemap="filmic"):
        """The tonemapped 8-bit sRGB PNG of the image, as bytes: the PNG ``save`` writes
        (RGBA with ``render.transparent_background``)."""
        import io

        from matplotlib import image as mpimg
        from .film import png_pixels
        exposure, tonemap = _display(exposure, tonemap, "RenderedImage.png_bytes()")
        transparent = self.scene.render.transparent_background
        buf = io.BytesIO()
        mpimg.imsave(buf, png_pixels(self.image, exposure, tonemap,
                                     self.alpha if transparent else None), format="png")
        return buf.getvalue()

    def _repr_png_(self):
        return self.png_bytes()

    def __repr__(self):
        h, w = self.image.shape[:2]
        state = ", partial" if self.partial else ""
        return (f"<RenderedImage {w}x{h}, {self.spp} spp, seed {self.seed}, {self.backend}, "
                f"{self.seconds:.2f} s{state}>")


@dataclass
class TransmittanceResult:
    """Transmittance estimates along k rays (``estimate_transmittance``).

    estimates: float64 [k] (or [k, 3] RGB for a medium with colour-dependent extinction),
    per ray the mean of ``n`` independent estimates of T = exp(-optical depth).
    stderr: the standard error of each mean (sample standard deviation / sqrt(n); nan when
    n = 1; 0 for a ray that misses the medium, whose T is exactly 1).
    lookups: float64 [k], mean density lookups per estimate (the estimator's cost).
    t_enter, t_exit: float64 [k], the world-unit distances along each (normalised) ray
    where the estimated segment starts and ends (the ray clipped to the medium box and to
    t_max); nan for a ray with no segment in the box. estimator, n, backend: as asked.
    counters: totals over all estimates (``capped``: walks cut by the step cap;
    ``over_majorant``: lookups above the majorant, both 0 for an unbiased estimate).
    """
    estimates: object
    stderr: object
    lookups: object
    t_enter: object
    t_exit: object
    estimator: str
    n: int
    backend: str
    counters: dict = field(default_factory=dict)


def _medium_scene(medium, where):
    """A Scene from a Scene, path, scene dict or a ``[medium]`` table alone."""
    from .scene.schema import TOP_KEYS
    if isinstance(medium, dict) and not set(TOP_KEYS) & set(medium):
        return scene_from_dict({"camera": {}, "medium": medium}, name="<medium>")
    return _as_scene(medium, where)


def _rays(origins, directions, t_max, where):
    """Broadcast float64 origins [k, 3], unit directions [k, 3] and t_max [k], checked."""
    import numpy as np
    try:
        o = np.atleast_2d(np.asarray(origins, np.float64))
        d = np.atleast_2d(np.asarray(directions, np.float64))
        t = np.atleast_1d(np.asarray(t_max, np.float64))
    except (TypeError, ValueError) as e:
        raise _error(where, "rays", f"expected arrays of numbers: {e}") from None
    for a, key in ((o, "origins"), (d, "directions")):
        if a.ndim != 2 or a.shape[1] != 3:
            raise _error(where, key, f"expected shape [k, 3], got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise _error(where, key, "must be finite")
    if t.ndim != 1:
        raise _error(where, "t_max", f"expected a number or shape [k], got {t.shape}")
    if np.any(np.isnan(t)) or np.any(t < 0):
        raise _error(where, "t_max", "must be >= 0 (inf allowed)")
    try:
        k = np.broadcast_shapes((len(o),), (len(d),), (len(t),))[0]
    except ValueError:
        raise _error(where, "rays", f"origins, directions and t_max disagree on the "
                                        f"number of rays ({len(o)}, {len(d)}, {len(t)})") \
            from None
    # Scaled by the largest component first: 1e200 would overflow the norm, 1e-170
    # underflow it to 0.
    big = np.abs(d).max(axis=1, keepdims=True)
    if np.any(big == 0):
        raise _error(where, "directions", "must not be the zero vector")
    d = d / big
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    o, d, t = (np.broadcast_to(x, (k,) + x.shape[1:]) for x in (o, d, t))
    return o, d, t


def _clip(o, d, t_max, lo, hi):
    """(s, t_enter, t_exit) of rays o + t d (t >= 0) in the box [lo, hi], cut at t_max; the
    slab test of reference/integrator.ray_box, vectorised (a ray parallel to a slab and
    outside it misses). The distances are from o + s d, the ray's nearest approach to the
    box's centre (s >= 0): a box far smaller than its distance from o (1e-4 at 1e12) was
    lost in the rounding of o's own distances and missed."""
    import numpy as np
    s = np.maximum(((0.5 * (lo + hi) - o) * d).sum(axis=1) / (d * d).sum(axis=1), 0.0)
    o = o + s[:, None] * d
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        ta, tb = (lo - o) * inv, (hi - o) * inv
    par = d == 0.0
    inside = (o >= lo) & (o <= hi)
    t_lo = np.where(par, np.where(inside, -np.inf, np.inf), np.minimum(ta, tb))
    t_hi = np.where(par, np.where(inside, np.inf, -np.inf), np.maximum(ta, tb))
    t0 = np.maximum(t_lo.max(axis=1), -s)
    t1 = np.minimum(t_hi.min(axis=1), t_max - s)
    return s, t0, np.maximum(t1, t0)


def estimate_transmittance(scene_or_medium, origins, directions, t_max=float("inf"),
                           estimator="auto", n=64, backend="opencl", seed=0, device=None,
                           lanes=None):
    """Estimate the transmittance along your own rays with any registered estimator.

    scene_or_medium: a Scene (its medium and its majorant structure: ``render.majorant``,
    ``render.majorant_resolution``), a scene file path or dict, or a ``[medium]`` table
    alone, e.g. ``{"bounds": [[-1, -1, -1], [1, 1, 1]], "density": 2.0}`` (homogeneous) or
    ``{"bounds": ..., "density": numpy_grid, "scale": 10.0}`` (grid majorant by default).
    origins [k, 3], directions [k, 3] (normalised here; not zero), t_max: a number or [k]
    (world units along the normalised ray; inf allowed): rays in world coordinates, broadcast
    against each other. Each ray is clipped to the medium box and to [0, t_max], as the
    renderer clips its rays, and estimated in the renderer's scene frame (pack.scene_frame).
    estimator: a name in ``volmc.techniques.ESTIMATORS`` ("auto": volmc's choice for a
    fixed ray; "analytic", exact only in a homogeneous medium, is refused for a grid). n:
    estimates per ray.
    backend: "opencl" or "numba"; seed: in [0, 2^64) (same seed, same estimates); device,
    lanes: as for ``render``. Homogeneous media, and homogeneous majorant cells, are traversed exactly.

    Returns a ``TransmittanceResult`` (estimates, stderr, lookups, t_enter, t_exit, ...).
    Raises VolmcError.
    """
    import numpy as np
    from .bench.transmittance_runner import estimator as make_runner
    from .pack import pack_scene, scene_frame
    from .params import COUNTER_NAMES, C_LOOKUPS
    from .scene.bricks import stores_bricks
    from .scene.schema import ConstantDensity
    from .techniques import ESTIMATORS
    where = "volmc.estimate_transmittance()"
    scene = _medium_scene(scene_or_medium, where)
    if len(scene.media) > 1:
        raise _error(where, "scene_or_medium", f"{len(scene.media)} media: the estimator "
                     "runners take one medium (render the scene for several)")
    if not isinstance(estimator, str) or estimator not in ESTIMATORS:
        raise _error(where, "estimator", f"unknown estimator {estimator!r} (have "
                                             f"{', '.join(ESTIMATORS)})")
    est = ESTIMATORS[estimator]
    if est.homogeneous_only and not isinstance(scene.spec.media[0].density, ConstantDensity):
        # it would return the majorant's transmittance, not the medium's
        raise _error(where, "estimator", f"'{estimator}' is exact in a homogeneous medium "
                     "only, and this medium's density is not a constant")
    chromatic = scene.medium.chromatic
    if chromatic and not est.chromatic:
        raise _error(where, "estimator", f"'{estimator}' estimates grey transmittance only; "
                                             "medium.scale differs per channel")
    n = _integer(n, where, "n", 1, 2**31 - 1)
    seed = _integer(seed, where, "seed", 0, 2**64 - 1)
    backend = _backend_name(backend, device, where)
    device = _device(device, backend, where)
    lanes = _lanes(lanes, backend, where)
    o, d, t_max = _rays(origins, directions, t_max, where)
    # Per estimate, the runners hold its value (float32 on the device and its host copy,
    # float64 after) and its counters (uint64, and int64 after).
    from .params import N_COUNTERS
    from .scene.hostmem import require_host
    require_host(len(o) * n * (3 if chromatic else 1) * 16 + len(o) * n * N_COUNTERS * 16,
                 where, "n", f"{len(o)} rays x {n} estimates")
    if stores_bricks(scene):   # the runners read dense grids
        scene = scene.with_render(grid_storage="dense")
    pk = pack_scene(scene, np.float64)
    m = pk.medium[0]
    centre, unit = scene_frame(scene)
    lo, hi = np.asarray(m["bmin"], np.float64), np.asarray(m["bmax"], np.float64)
    o_local = (o - np.asarray(centre)) / unit
    placed = bool(m["transformed"])
    if placed:   # clipped in the medium's own space (pack.medium_space), as the renderer does
        x = np.asarray(m["xform"], np.float64).reshape(3, 4)
        s, t0, t1 = _clip(o_local @ x[:, :3].T + x[:, 3], d @ x[:, :3].T, t_max / unit, lo,
                          hi)
    else:
        s, t0, t1 = _clip(o_local, d, t_max / unit, lo, hi)
    hit = t1 > t0
    t0, t1 = np.where(hit, t0, np.nan), np.where(hit, t1, np.nan)
    k = len(o)
    shape = (k, 3) if chromatic else (k,)
    mean, stderr = np.ones(shape), np.zeros(shape)
    lookups = np.zeros(k)
    counters = {name: 0 for name in COUNTER_NAMES}
    if hit.any():
        # Each segment starts at its entry point (kept inside the box), as the renderer's
        # entry re-basing does: float32 sees short distances from nearby numbers.
        start = (o_local[hit] + s[hit, None] * d[hit]) + t0[hit, None] * d[hit]
        if not placed:
            start = np.clip(start, lo, hi)
        rays = np.zeros((int(hit.sum()), 9))
        rays[:, :3], rays[:, 3:6], rays[:, 7] = start, d[hit], (t1 - t0)[hit]
        runner = make_runner(backend, estimator, device, chromatic=chromatic, lanes=lanes)
        out, cnt = runner.run(pk.medium, pk.grid, rays, None, n, seed, 0, maj=pk.maj,
                              mnr=pk.mnr, nodes=pk.nodes)
        out = out.reshape((len(rays), n) + shape[1:])
        mean[hit] = out.mean(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            stderr[hit] = out.std(axis=1, ddof=1) / np.sqrt(n) if n > 1 else np.nan
        lookups[hit] = cnt[:, C_LOOKUPS].reshape(len(rays), n).mean(axis=1)
        counters = {name: int(cnt[:, i].sum()) for i, name in enumerate(COUNTER_NAMES)}
    return TransmittanceResult(mean, stderr, lookups, (s + t0) * unit, (s + t1) * unit,
                               estimator, n, backend, counters)
