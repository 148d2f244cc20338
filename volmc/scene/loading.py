"""Loading a scene: TOML file -> ``-D`` overrides -> validation -> grid -> ``Scene``.

``-D`` overrides name a dotted key path and a TOML value: ``render.spp=256``,
``medium.albedo=[0.9, 0.8, 0.7]``, ``medium.phase.g=0.3``, ``lights.1.irradiance=5``
(array elements by 0-based index). A value that is not valid TOML is taken as a string, so
``camera.type=orthographic`` works unquoted.
"""

import os
import tomllib
from dataclasses import dataclass, field, replace
from typing import Optional

import numpy as np

from .errors import SceneError
from .grids import load_grid, validate_grid
from .schema import (FLOAT32_MAX, ConstantDensity, FileDensity, GeneratedDensity, SceneSpec,
                     validate)


@dataclass(frozen=True)
class Scene:
    """A validated scene with its density grid loaded.

    ``grid`` is a float32 [z, y, x] array, or None for a homogeneous medium.
    """
    spec: SceneSpec
    grid: Optional[np.ndarray] = field(default=None, compare=False, repr=False)

    @property
    def file(self):
        return self.spec.file

    @property
    def camera(self):
        return self.spec.camera

    @property
    def medium(self):
        return self.spec.medium

    @property
    def lights(self):
        return self.spec.lights

    @property
    def render(self):
        return self.spec.render

    def with_render(self, **keys):
        """This scene with some ``render`` keys replaced (spp, seed, techniques); the
        grid is shared, not copied. The values are taken as given (not re-validated)."""
        spec = replace(self.spec, render=replace(self.spec.render, **keys))
        return Scene(spec, self.grid)


def read_toml(path):
    """Parse a TOML file; unreadable or malformed files raise SceneError."""
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise SceneError(path, "", "scene file not found") from None
    except IsADirectoryError:
        raise SceneError(path, "", "is a directory, not a scene file") from None
    except OSError as e:
        raise SceneError(path, "", f"cannot read: {e.strerror}") from None
    except UnicodeDecodeError:
        raise SceneError(path, "", "not a text (UTF-8) file") from None
    except tomllib.TOMLDecodeError as e:
        raise SceneError(path, "", f"malformed TOML: {e}") from None
    except ValueError as e:   # e.g. an integer longer than Python's 4300-digit limit
        raise SceneError(path, "", f"malformed TOML: {(str(e).splitlines() or [''])[0]}") from None
    except RecursionError:
        raise SceneError(path, "", "malformed TOML: arrays or tables nested too deeply") \
            from None


def parse_override(text, file):
    """Split ``section.key=value`` into (["section", "key"], python value)."""
    if "=" not in text:
        raise SceneError(file, f"-D {text}", "expected section.key=value")
    key, value = text.split("=", 1)
    key = key.strip()
    parts = key.split(".")
    if len(parts) < 2 or any(not p.strip() for p in parts):
        raise SceneError(file, f"-D {text}", "expected section.key=value")
    value = value.strip()
    if value == "":
        raise SceneError(file, f"-D {text}", "missing value after '='")
    try:
        parsed = tomllib.loads(f"v = {value}")["v"]
    except (ValueError, RecursionError):   # not TOML (or too long/deep for tomllib)
        parsed = value
    return [p.strip() for p in parts], parsed


def _is_index(part):
    """An array index: ASCII digits only ("²".isdigit() is true, but int("²") fails)."""
    return part.isascii() and part.isdigit()


def apply_overrides(raw, overrides, file):
    """Apply ``-D`` overrides (list of strings) to a raw scene dictionary, in order."""
    for text in overrides:
        parts, value = parse_override(text, file)
        node = raw
        for depth, part in enumerate(parts[:-1]):
            shown = ".".join(parts[:depth + 1])
            if isinstance(node, list):
                if not _is_index(part) or int(part) >= len(node):
                    raise SceneError(file, f"-D {text}",
                                     f"'{shown}': no element {part} (there are {len(node)})")
                node = node[int(part)]
            elif isinstance(node, dict):
                if part not in node:
                    node[part] = {}
                node = node[part]
            else:
                raise SceneError(file, f"-D {text}", f"'{shown}' is not a table")
        last = parts[-1]
        if isinstance(node, list):
            if not _is_index(last) or int(last) >= len(node):
                raise SceneError(file, f"-D {text}", f"no element {last} (there are {len(node)})")
            node[int(last)] = value
        elif isinstance(node, dict):
            node[last] = value
        else:
            raise SceneError(file, f"-D {text}", f"'{'.'.join(parts[:-1])}' is not a table")
    return raw


def load_density(spec: SceneSpec):
    """The scene's density grid (float32 [z, y, x]) or None for a homogeneous medium."""
    d = spec.medium.density
    if isinstance(d, ConstantDensity):
        return None
    if isinstance(d, FileDensity):
        if not os.path.exists(d.resolved):
            raise SceneError(spec.file, "medium.density.file", f"grid file not found: {d.path}")
        grid = load_grid(d.resolved, "medium.density")
    elif isinstance(d, GeneratedDensity):
        from .generators import cloud
        grid = validate_grid(cloud(d.resolution, d.seed), spec.file, "medium.density")
    else:
        raise TypeError(d)
    # The float32 kernels hold the global majorant scale * max(density).
    if spec.medium.scale * float(grid.max()) > FLOAT32_MAX:
        raise SceneError(spec.file, "medium.scale",
                         f"scale * max(density) = {spec.medium.scale * float(grid.max()):g} "
                         f"overflows float32 (at most {FLOAT32_MAX:g})")
    return grid


def load_scene(path, overrides=()):
    """Read, override, validate and load a scene file. Raises SceneError on bad input."""
    path = str(path)
    raw = read_toml(path)
    apply_overrides(raw, list(overrides), path)
    spec = validate(raw, path)
    return Scene(spec, load_density(spec))


def scene_from_dict(raw, file="<dict>", base_dir=".", overrides=()):
    """Build a Scene from an in-memory dictionary (relative paths resolve against base_dir)."""
    import copy
    raw = apply_overrides(copy.deepcopy(raw), list(overrides), file)
    spec = validate(raw, file, file_dir=os.path.abspath(base_dir))
    return Scene(spec, load_density(spec))
