"""Frame sequences: ``volmc render --frames 1-48[:step]`` and ``volmc.render_frames``.

A scene whose grid files name the frame (``file = "cache/fluid_data_{frame:04d}.vdb"``;
scene/frames.py substitutes it) renders once per frame, each frame exactly as a single
render of that frame's scene: the same image bit for bit, here or on a Dask cluster (each
frame's chunks are the cluster's tasks, render.py and distributed.py). Frame f goes to
``<stem>.<f:04d>.exr`` beside the output path, with the PNG and variance images named
alike.

The EXR is written last and atomically (a temporary file, then a rename), and it records
the frame and an identity of what it is a render of (the scene's raw TOML or dict,
overrides included, the frame and the backend; not the grid files' bytes, which would
have to be read for every frame only to skip it). A frame is complete, and is skipped, when
its EXR reads whole, is not partial (the ``partial`` flag an interrupted render writes, as
for a single render) and has this identity, and every other file asked for (PNG, variance,
denoised preview) is there; so a killed run resumes at the first frame it had not
finished, and a run that asks for more files than the last renders the frames again. A
frame's file that cannot be written ends the run with the one-line error, the frame's
image saved to the temporary directory (film.rescue_exr).
"""

import hashlib
import json
import os
import re
import sys
import warnings
from contextlib import contextmanager
from dataclasses import dataclass

from .scene.errors import SceneError

#: Frames one request may name; a typo such as 1-100000000 fails at once instead of
#: building a plan of that size.
MAX_FRAMES = 1_000_000

_SPEC = re.compile(r"(\d{1,9})(?:-(\d{1,9}))?(?::(\d{1,9}))?")


def parse_frames(text, file="command line", key="--frames"):
    """The frames of ``FIRST-LAST[:STEP]`` (LAST included) or of one number ``N``, as a
    range. Anything else is a SceneError(file, key)."""
    m = _SPEC.fullmatch(text.strip()) if isinstance(text, str) else None
    if m is None:
        raise SceneError(file, key, f"expected FIRST-LAST[:STEP] or a frame number, e.g. "
                                    f"1-48 or 1-48:2 or 7, got {text!r}")
    first = int(m.group(1))
    last = first if m.group(2) is None else int(m.group(2))
    step = 1 if m.group(3) is None else int(m.group(3))
    if last < first:
        raise SceneError(file, key, f"{text!r}: the last frame ({last}) is before the first "
                                    f"({first})")
    if step < 1:
        raise SceneError(file, key, f"{text!r}: the step must be at least 1, got {step}")
    return check_count(range(first, last + 1, step), file, key)


def check_count(frames, file, key):
    if len(frames) > MAX_FRAMES:
        raise SceneError(file, key, f"{len(frames)} frames; at most {MAX_FRAMES} in one run")
    return frames


def frame_path(path, frame):
    """``out/fire.exr`` -> ``out/fire.0007.exr`` (4 digits, more when the number needs)."""
    stem, ext = os.path.splitext(path)
    return f"{stem}.{frame:04d}{ext}"


def _canonical(value):
    """What json.dumps cannot write itself: a numpy grid of a scene built in Python (by its
    bytes), numpy numbers, and anything else TOML may hold (dates) by its text."""
    import numpy as np
    if isinstance(value, np.ndarray):
        a = np.ascontiguousarray(value)
        h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
        h.update(memoryview(a).cast("B"))
        return {"array": h.hexdigest()}
    if isinstance(value, np.generic):
        return value.item()
    return str(value)


def identity(raw, frame, backend):
    """The hex SHA-256 of a frame's render: the raw scene (file patterns unformatted,
    overrides, spp and seed in), the frame number and the backend name. The lane width and
    the device are left out: they change an image's rounding, not what it is a render of."""
    text = json.dumps([raw, frame, backend], sort_keys=True, default=_canonical)
    return hashlib.sha256(text.encode()).hexdigest()


def is_complete(exr, ident):
    """True if ``exr`` holds a finished (not partial) render with identity ``ident``, every
    pixel of it readable (a file cut short keeps its header)."""
    from .film import read_exr
    if not os.path.isfile(exr):
        return False
    try:
        with _quiet_stderr():
            meta = read_exr(exr, alpha=True)[1]
    except Exception:   # noqa: BLE001 -- unreadable for any reason: not complete, render it
        return False
    return meta.get("partial") == 0 and meta.get("frame_identity") == ident


@contextmanager
def _quiet_stderr():
    """The process's stderr (file descriptor 2) closed to output: OpenEXR's library and its
    bindings print their own messages about a file cut short, which here is expected (the
    frame is rendered again), on a run that succeeds. Process-wide for its moment (another
    thread's output then is lost too): used by the command line's frame checks alone."""
    if sys.stderr is not None:
        sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:   # no stderr at all (2>&-, a service): nothing to keep quiet
        yield
        return
    try:
        with open(os.devnull, "w") as null, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            os.dup2(null.fileno(), 2)
            yield
    finally:
        if sys.stderr is not None:
            sys.stderr.flush()
        os.dup2(saved, 2)
        os.close(saved)


def render_outputs(exr, png=None, variance=False, denoise=False):
    """(role, path) of every file a render (a frame, or ``volmc render``) writes, its EXR
    ``exr`` last (the file that marks a frame complete): "png" (``png``, the PNG's path, or
    None), "variance", "denoise" (beside the EXR, and the PNG), "exr"."""
    from .denoise import denoised_path
    from .film import variance_path
    out = [("png", png)] if png else []
    if variance:
        out.append(("variance", variance_path(exr)))
    if denoise:
        out += [("denoise", denoised_path(p)) for p in (exr, png) if p]
    return out + [("exr", exr)]


class FrameSequence:
    """A raw scene (a scene file's TOML or a scene dict, overrides applied) whose grid files
    name the frame, and the frames to render of it."""

    def __init__(self, raw, file, file_dir, frames, key="--frames"):
        from .scene.frames import patterns
        self.raw, self.file, self.file_dir = raw, file, file_dir
        self.frames = list(frames)
        if not self.frames:
            raise SceneError(file, key, "no frames to render")
        if not patterns(raw):
            raise SceneError(file, key, "no grid file of the scene names the frame (write "
                                        "e.g. file = \"cache/density_{frame:04d}.vdb\"), so "
                                        "every frame would be the same image")

    def plan(self, output, backend, png=None, variance=False, denoise=False):
        """[FramePlan] of each frame: its EXR (None without ``output``), its identity and
        whether it is complete (its EXR, and the other files asked for by ``png``, the
        sequence's PNG path, ``variance`` and ``denoise``: render_outputs). A frame to render
        whose grid file is missing raises
        SceneError (naming the scene file and key, listing the frames on disk): before
        anything renders, so a run does not end halfway, and only for those frames, since
        the files of complete frames may be gone."""
        from .scene.frames import substitute
        out = []
        for f in self.frames:
            ident = self.identity(f, backend)
            exr = frame_path(output, f) if output else None
            # A PNG alone missing is toned from the EXR, not rendered (render_sequence):
            # deleting a sequence's PNGs gives them another exposure or tone curve.
            complete = bool(exr) and is_complete(exr, ident) and all(
                os.path.isfile(path) for role, path in
                render_outputs(exr, png and frame_path(png, f), variance, denoise)
                if role != "png")
            retone = complete and bool(png) and not os.path.isfile(frame_path(png, f))
            if not complete:
                substitute(self.raw, f, self.file, self.file_dir)
            out.append(FramePlan(f, ident, exr, complete, retone))
        return out

    def scene(self, frame):
        """The Scene of ``frame`` (its grids loaded)."""
        from .scene.loading import scene_from_raw
        return scene_from_raw(self.raw, self.file, self.file_dir, frame)

    def identity(self, frame, backend):
        return identity(self.raw, frame, backend)


@dataclass
class FramePlan:
    frame: int
    identity: str
    exr: object
    complete: bool
    retone: bool = False   # complete, but its PNG is to be written from its EXR


@dataclass
class FrameDone:
    """One frame of a sequence: its number, its position among the frames asked for
    (``index`` of ``count``, from 1), its EXR path (None when nothing is written) and the
    api.RenderedImage (None when the frame was skipped as complete)."""
    frame: int
    index: int
    count: int
    exr: object
    image: object


def render_sequence(seq, plan, render_one, png=None, variance=False, exposure=0.0,
                    tonemap="filmic", denoise=False, keys=None):
    """Render the frames of FrameSequence ``seq`` by its ``plan`` (``seq.plan``, given the
    same ``png``, ``variance`` and ``denoise``) in order and yield a FrameDone for each.
    Frame f is written to its EXR (a PNG to ``frame_path(png, f)`` when ``png`` is a path,
    the variance beside the EXR) when the plan has one, and skipped when it is complete.
    ``render_one`` (scene, label) renders a scene into an api.RenderedImage. The sequence
    stops after an interrupted (partial) frame, which is written marked partial. So it does
    when ``render_one`` raises distributed.ClusterError with the frame's partial
    RenderedImage as ``.result`` (the cluster failed during the frame): the frame is written,
    then the error is raised again, its reason and message saying where the partial frame
    is.
    ``denoise``: each frame's denoised preview is written beside its EXR and PNG
    (denoise.write_denoised; render_one then renders with the albedo AOV). Every file comes
    before the EXR that marks the frame complete. ``keys``: role -> (file, key) of the
    one-line error when a frame's file cannot be written (render_outputs' roles; default the
    command line's flags); the frame's image is then saved to the temporary directory."""
    from .distributed import ClusterError
    from .film import rescue_exr, write_exr, write_png
    from .scene.schema import render_settings
    keys = {**CLI_KEYS, **(keys or {})}
    n = len(plan)
    for i, p in enumerate(plan, 1):
        f, ident, exr = p.frame, p.identity, p.exr
        if p.complete:
            if p.retone:
                _tone_from_exr(exr, frame_path(png, f), exposure, tonemap,
                               render_settings(seq.raw, seq.file).transparent_background,
                               keys["png"])
            yield FrameDone(f, i, n, exr, None)
            continue
        try:
            img, failure = render_one(seq.scene(f), f"frame {i}/{n}"), None
        except ClusterError as e:
            if e.result is None:
                raise
            img, failure = e.result, e
        if exr:
            img.result.extra.update(frame=f, frame_identity=ident)
            meta, rgba = img.metadata(), img.result.film.rgba()
            transparent = img.scene.render.transparent_background
            try:
                for role, path in render_outputs(exr, png and frame_path(png, f), variance,
                                                 denoise):
                    if role == "png":
                        write_png(path, img.image, exposure, tonemap,
                                  alpha=img.alpha if transparent else None)
                    elif role == "variance":
                        write_exr(path, img.variance, meta)
                    elif role == "denoise" and path.lower().endswith(".exr"):
                        # both previews at once: the EXR's, and the PNG's (the next role)
                        from .denoise import write_denoised
                        write_denoised(img.result.film, meta, exr,
                                       frame_path(png, f) if png else None, exposure, tonemap,
                                       transparent, *keys["denoise"])
                    elif role == "exr":
                        # Written whole (film.write_exr): a kill while writing leaves no
                        # EXR that looks complete.
                        write_exr(exr, rgba, meta)
            except (OSError, RuntimeError) as e:
                raise SceneError(*keys[role], rescue_exr(path, e, rgba, meta,
                                                         f"frame {f}'s image")) from None
        if failure is not None:
            where = f"; frame {f} is written, marked partial, to {exr} ({img.spp} spp)" \
                if exr else ""
            raise ClusterError(failure.reason + where, img, failure.file, failure.key,
                               failure.message + where) from failure.__cause__
        yield FrameDone(f, i, n, exr, img)
        if img.partial:
            return


def _tone_from_exr(exr, path, exposure, tonemap, transparent, key):
    """Write the PNG ``path`` of a complete frame from its EXR (RGB, and its coverage as the
    PNG's alpha when the background is ``transparent``): the PNG its render would write."""
    from .film import read_exr, write_png
    rgba = read_exr(exr, alpha=True)[0]
    try:
        write_png(path, rgba[..., :3], exposure, tonemap,
                  alpha=rgba[..., 3] if transparent else None)
    except (OSError, RuntimeError) as e:
        raise SceneError(*key, f"cannot write {path}: {getattr(e, 'strerror', None) or e}") \
            from None


#: The (file, key) of the one-line error naming the option that asked for a render's file
#: (render_outputs' roles).
CLI_KEYS = {"exr": ("command line", "-o"), "png": ("command line", "--png"),
            "variance": ("command line", "--variance"), "denoise": ("command line", "--denoise")}
