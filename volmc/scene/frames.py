"""Frame patterns in grid file names: ``file = "cache/fluid_data_{frame:04d}.vdb"``.

A grid source's ``file`` is a pattern when it holds a Python format field named ``frame``
(any format spec). Before a scene is validated, ``substitute`` formats every pattern of the
raw scene (``[medium]`` and each ``[[media]]`` entry, at any depth, so every grid source is
covered) with the frame number. A scene loaded without a frame number that holds a pattern,
and a frame whose file is missing, are one-line errors; the second lists the frames that
exist, found by globbing the pattern.
"""

import glob
import os
import re
import string

from .errors import SceneError

#: The sections whose ``file`` keys name grids (a light's ``file`` is an environment map).
GRID_SECTIONS = ("medium", "media")

_FRAME_FIELD = re.compile(r"frame(?![A-Za-z0-9_])")


def _fields(path):
    """The format fields of ``path`` as (literal, field name or None) pieces, or None when
    it is not a format string (an unmatched brace: a literal file name, as before patterns
    existed)."""
    try:
        return [(lit, name) for lit, name, _, _ in string.Formatter().parse(path)]
    except ValueError:
        return None


def is_pattern(path):
    """True if ``path`` names the frame in a format field."""
    pieces = _fields(path) if isinstance(path, str) else None
    return bool(pieces) and any(n is not None and _FRAME_FIELD.match(n) for _, n in pieces)


def grid_files(raw):
    """[(key, table)] of every table under the grid sections with a string ``file``, keyed
    as the validator names them ("medium.density", "media[1].emission.temperature")."""
    out = []

    def walk(node, key):
        if isinstance(node, dict):
            if isinstance(node.get("file"), str):
                out.append((key, node))
            for k, v in node.items():
                walk(v, f"{key}.{k}")
        elif isinstance(node, list):
            for i, v in enumerate(node):
                walk(v, f"{key}[{i}]")
    for section in GRID_SECTIONS:
        if isinstance(raw, dict) and section in raw:
            walk(raw[section], section)
    return out


def patterns(raw):
    """[(key, pattern)] of the grid files of ``raw`` that name the frame."""
    return [(key, t["file"]) for key, t in grid_files(raw) if is_pattern(t["file"])]


def format_path(pattern, frame, file, key):
    """``pattern`` with the frame number in; a field other than ``frame`` or a format spec
    an integer does not take is a SceneError(file, key), as is a width or precision of more
    than two digits (a file name has no use for it, and Python would build the string)."""
    import re
    import string
    try:
        for _, name, spec, _ in string.Formatter().parse(pattern):
            if name is not None and (name != "frame" or re.search(r"\d{3,}", spec or "")):
                raise KeyError(name)
        return pattern.format(frame=frame)
    except (KeyError, IndexError, AttributeError, TypeError):
        raise SceneError(file, key, f"{pattern!r}: only {{frame}} (with a format spec, e.g. "
                                    "{frame:04d}) can be substituted") from None
    except ValueError as e:
        raise SceneError(file, key, f"{pattern!r}: {e}") from None


def substitute(raw, frame, file, file_dir=None):
    """``raw`` with each grid file pattern formatted with ``frame`` (the tables changed are
    copies; ``raw`` is left as it was). ``frame`` None: the scene must hold no pattern. A
    frame whose file is missing raises SceneError(file, key) listing the frames on disk."""
    found = patterns(raw)
    if frame is None:
        if found:
            key, pattern = found[0]
            raise SceneError(file, key + ".file", f"{pattern!r} names a frame: render a frame "
                                                  "sequence with --frames (volmc.render_frames"
                                                  "), or one frame with load_scene(frame=)")
        return raw
    if not found:
        return raw
    base = file_dir if file_dir is not None else os.path.dirname(os.path.abspath(file))
    out = _copy_containers(raw)
    for key, table in grid_files(out):
        pattern = table["file"]
        if not is_pattern(pattern):
            continue
        path = format_path(pattern, frame, file, key + ".file")
        resolved = path if os.path.isabs(path) else os.path.join(base, path)
        if not os.path.exists(resolved):
            raise SceneError(file, key + ".file", f"frame {frame}: grid file not found: {path} "
                                                  f"(the pattern {pattern!r} has "
                                                  f"{describe(existing_frames(pattern, base))})")
        table["file"] = path
    return out


def _copy_containers(node):
    """A copy of the dicts and lists of ``node`` (so tables can be changed), sharing the
    leaves (numpy grids of a scene built in Python are not copied)."""
    if isinstance(node, dict):
        return {k: _copy_containers(v) for k, v in node.items()}
    if isinstance(node, list):
        return [_copy_containers(v) for v in node]
    return node


def existing_frames(pattern, base):
    """Sorted frame numbers whose file the pattern names and which exist (relative to
    ``base``). A file counts only if formatting its number gives its name back exactly, so
    any format spec works and stray files that merely match the glob do not count."""
    pieces = _fields(pattern)
    spec = "".join(glob.escape(lit) + ("*" if name is not None else "") for lit, name in pieces)
    full = spec if os.path.isabs(pattern) else os.path.join(glob.escape(base), spec)
    found = set()
    for hit in glob.glob(full):
        for digits in re.findall(r"\d+", os.path.relpath(hit, base)):
            n = int(digits)
            try:
                name = pattern.format(frame=n)
            except (KeyError, IndexError, AttributeError, ValueError):
                return []
            if os.path.normpath(os.path.join(base, name)) == os.path.normpath(hit):
                found.add(n)
                break
    return sorted(found)


def describe(frames, limit=8):
    """"frames 1-12, 14" (runs of consecutive numbers; at most ``limit`` runs shown), or
    "no frames on disk"."""
    if not frames:
        return "no frames on disk"
    runs, start = [], frames[0]
    for a, b in zip(frames, frames[1:] + [None]):
        if b != a + 1:
            runs.append(str(start) if start == a else f"{start}-{a}")
            start = b
    more = f", ... ({len(frames)} frames)" if len(runs) > limit else ""
    return "frames " + ", ".join(runs[:limit]) + more
