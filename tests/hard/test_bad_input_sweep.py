"""Issue 6, item 5: a property-based sweep of bad input (hypothesis).

Random, mostly invalid scenes, grid files, TOML texts and command lines are fed to the
loader and the CLI. Every input must either

- load into a scene that is valid: it packs (``pack_scene``, with its majorant grid, in
  float64 and float32) into finite parameters and a finite, non-negative float32 grid, and
  its resolved TOML round-trips; or
- raise exactly ``SceneError`` whose one-line message names the file and the key (the key
  of the section that was mutated, or ``medium.density`` of the grid file that was bad).

Never another exception type, a traceback or a hang (a per-example alarm). The CLI gives
exit status 2 and exactly one line
``volmc: error: ...`` on stderr. Hypothesis runs derandomized with a fixed number of
examples and no database, so the sweep is the same on every run. Each bug the sweep found
is pinned by an ``@example``.
"""

import contextlib
import copy
import io
import json
import math
import os
import re
import shutil
import struct
import subprocess
import sys
import tempfile
import tomllib
import zipfile
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, event, example, given, settings
from hypothesis import strategies as st

from volmc.bench.fuzz import time_limit
from volmc.cli import main as cli_main
from volmc.pack import pack_scene
from volmc.scene.bricks import BrickGrid
from volmc.scene import SceneError, load_scene
from volmc.scene.features import features
from volmc.scene.grids import VOL_HEADER, load_grid
from volmc.scene.schema import validate
from volmc.scene.serialize import to_dict, to_toml

#: Wall-clock limit of one example (a hang fails the example). Loading a tiny scene takes
#: milliseconds; the limit is loose because other jobs share the 2 cores. It replaces
#: hypothesis' deadline, which reports a slow first call (JIT compilation) as flaky.
EXAMPLE_LIMIT_S = 30.0
FLT_MAX = float(np.finfo(np.float32).max)


def sweep(max_examples):
    return settings(derandomize=True, database=None, max_examples=max_examples, deadline=None,
                    print_blob=False, suppress_health_check=list(HealthCheck))


@pytest.fixture(scope="module", autouse=True)
def _warm_up():
    """Compile the cloud generator once, outside the timed examples."""
    from volmc.scene.generators import cloud
    cloud(2)


# ---------------------------------------------------------------------------------------
# TOML text of arbitrary values (every key quoted, every control character escaped)


@dataclass(frozen=True)
class Raw:
    """A value written verbatim into the TOML text (big integers, deep nesting, dates)."""
    text: str
    parses: bool = True   # False: tomllib cannot parse it (the file-level error is fine)

    def __repr__(self):   # run-length encoded, so a failing example is short but exact
        runs = [m.group(0) for m in re.finditer(r"(.)\1*", self.text, re.S)]
        text = " + ".join(repr(r) if len(r) < 4 else f"{r[0]!r} * {len(r)}" for r in runs)
        return f"Raw({text or repr('')}, parses={self.parses})"


def _esc(s):
    out = []
    for ch in s:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def toml_value(v):
    if isinstance(v, Raw):
        return v.text
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return _esc(v)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_esc(k)} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def toml_doc(d):
    return "".join(f"{_esc(k)} = {toml_value(v)}\n" for k, v in d.items())


def has_unparseable(v):
    if isinstance(v, Raw):
        return not v.parses
    if isinstance(v, list):
        return any(has_unparseable(x) for x in v)
    if isinstance(v, dict):
        return any(has_unparseable(x) for x in v.values())
    return False


# ---------------------------------------------------------------------------------------
# Oracles


def assert_valid_scene(scene):
    """A scene that loaded must pack into finite parameters on both precisions."""
    event("valid scene")
    w, h = scene.camera.resolution
    assert 1 <= w and 1 <= h and w * h <= 2**31 - 1
    assert 1 <= scene.render.spp <= 2**32 - 1
    if isinstance(scene.grid, BrickGrid):
        g = scene.grid
        assert g.pool.dtype == np.float32 and g.table.dtype == np.int32 and g.size > 0
        assert np.all(np.isfinite(g.pool)) and g.pool.min() >= 0
        assert 0 <= g.table.min() and g.table.max() < len(g.pool)
    elif scene.grid is not None:
        g = scene.grid
        assert g.dtype == np.float32 and g.ndim == 3 and g.size > 0 and g.flags.c_contiguous
        assert np.all(np.isfinite(g)) and g.min() >= 0
    if scene.emission_grid is not None:
        e = scene.emission_grid
        assert e.dtype == np.float32 and e.ndim == 3 and np.all(np.isfinite(e)) and e.min() >= 0
    for real in (np.float64, np.float32):
        with np.errstate(over="ignore", invalid="ignore"):
            params, lights, medium, grid, maj, mnr, *_ = pack_scene(scene, real)
        for arr in (params, lights, medium):
            for name in arr.dtype.names:
                if arr.dtype[name].base.kind == "f":
                    assert np.all(np.isfinite(arr[name])), (real, name, arr[name])
        assert np.all(np.isfinite(grid)) and np.all(grid >= 0)
        assert np.all(np.isfinite(maj)) and np.all(mnr <= maj), real
        p = params[0]
        for v in ("forward", "right", "up"):
            assert abs(np.linalg.norm(p[v].astype(np.float64)) - 1) < 1e-5, (v, p[v])
        for lt in lights:
            if lt["type"] == 0:
                assert abs(np.linalg.norm(lt["vec"].astype(np.float64)) - 1) < 1e-5
    features(scene)
    again = validate(tomllib.loads(to_toml(scene.spec)), scene.file)
    assert to_dict(again) == to_dict(scene.spec)


def _section(key):
    """The first part of a dotted key; unknown keys may be quoted (``"a b".x``)."""
    if key.startswith('"'):
        return json.loads(re.match(r'"(?:[^"\\]|\\.)*"', key).group(0))
    return re.split(r"[.\[]", key, maxsplit=1)[0]


def assert_scene_error(e, files, sections=None, defines=(), file_only_ok=False, key=None):
    """``e`` is exactly a SceneError with a one-line message naming its file and key."""
    assert type(e) is SceneError, type(e)
    event(f"SceneError: {_section(e.key) if e.key and not e.key.startswith('-D ') else e.key[:2]}")
    msg = str(e)
    assert msg and len(msg.splitlines()) == 1 and "\n" not in msg and "\r" not in msg, msg
    assert "Traceback" not in msg
    assert e.file in files, (e.file, files, msg)
    assert msg.startswith(f"{e.file}: "), msg
    assert isinstance(e.message, str) and e.message.strip(), msg
    if not e.key:
        assert file_only_ok, f"error names no key: {msg}"
        return
    if e.key.isprintable():
        assert msg.startswith(f"{e.file}: {e.key}: "), msg
    if key is not None:
        assert e.key == key, msg
    if e.key.startswith("-D "):
        assert e.key[3:] in defines, msg
    elif sections is not None:
        assert _section(e.key) in sections, (msg, sections)


# ---------------------------------------------------------------------------------------
# Values


SPECIAL_FLOATS = [0.0, -0.0, -1.0, 1.0, 1e-320, 5e-324, 1e-45, 2e-39, 1e-30, 1e30, 3.4e38,
                  3.5e38, 1e300, 1.7976931348623157e308, -1e300, math.nan, math.inf,
                  -math.inf, 179.99999999999997, 180.0, 0.9999999999999999, -1.0000001]
SPECIAL_INTS = [0, -1, -3, 1, 2, 256, 257, 2048, 2049, 2**31 - 1, 2**31, 2**32, 2**63 - 1,
                2**63, 2**64 - 1, 2**64, -2**63, 10**30, 10**400]
SPECIAL_TEXT = ["", " ", "perspective", "Perspective", "orthographic ", "hg", "HG", "isotropic",
                "environment", "Directional", "point", "cloud", "ratio", "power_series",
                "analytic", "grid", "global", "delta", "decomposition", "dëlta", "grïd",
                "\x00", "a\nb", "line\u2028sep", "\x1c", "🙂", "x" * 300, "1.0", "[1, 2, 3]",
                "grid.npy", "nan"]
RAWS = [Raw("9" * 5000, parses=False), Raw("-" + "9" * 4400, parses=False),
        Raw("[" * 2000 + "]" * 2000, parses=False), Raw("[[[[[[[[1]]]]]]]]"),
        Raw("1979-05-27T07:32:00Z"), Raw("1979-05-27"), Raw("07:32:00"), Raw("0x7fffffff"),
        Raw("0b101"), Raw("1_000"), Raw("+inf"), Raw("-nan"), Raw("{a = {b = {c = 1}}}"),
        Raw("'literal\\n'"), Raw('"""multi\nline"""')]

floats = st.one_of(st.sampled_from(SPECIAL_FLOATS), st.floats())
ints = st.one_of(st.sampled_from(SPECIAL_INTS), st.integers(-10**6, 10**6),
                 st.integers(-10**400, 10**400))
texts = st.one_of(st.sampled_from(SPECIAL_TEXT), st.text(max_size=12))
scalars = st.one_of(floats, ints, st.booleans(), texts, st.sampled_from(RAWS))
values = st.recursive(scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=5), st.dictionaries(texts, inner, max_size=3)), max_leaves=8)
vectors = st.one_of(st.lists(floats, min_size=0, max_size=5),
                    st.lists(st.one_of(floats, ints, scalars), min_size=3, max_size=3),
                    st.sampled_from([[], [[0.0, 0.0, 1.0]], [0.0] * 1000, [[], [], []]]))


def misspell(key):
    return st.one_of(
        st.just(key.upper()), st.just(key + "s"), st.just(key[:-1]), st.just("_" + key),
        st.just(key.replace("e", "é")), st.just(key + "\n"), st.just(key + " "),
        st.just(key[::-1]), st.text(max_size=6))


# ---------------------------------------------------------------------------------------
# Valid scenes to start from


def base_scenes():
    """Valid scene dictionaries; grid files they name are written by make_grid_dir."""
    full = {
        "camera": {"type": "perspective", "eye": [0.0, 0.0, 4.0], "target": [0.0, 0.0, 0.0],
                   "up": [0.0, 1.0, 0.0], "fov": 45.0, "size": 2.0, "resolution": [4, 3],
                   "aperture": 0.05, "focus_distance": 3.5},
        "medium": {"bounds": [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]], "density": 1.0,
                   "scale": 20.0, "albedo": 0.8, "phase": {"type": "hg", "g": 0.6}},
        "lights": [
            {"type": "environment", "radiance": 0.3},
            {"type": "directional", "direction": [-1.0, -1.0, -0.5], "irradiance": 3.0},
            {"type": "point", "position": [0.0, 3.0, 0.0], "intensity": [10.0, 9.0, 8.0]},
        ],
        "render": {"spp": 4, "max_depth": 64, "rr_depth": 5, "seed": 0, "max_steps": 1000,
                   "transmittance": "ratio", "majorant": "grid", "free_flight": "delta",
                   "majorant_resolution": [2, 2, 2]},
    }
    grid = {
        "camera": {"type": "orthographic", "eye": [0.5, 0.5, 3.0], "target": [0.5, 0.5, 0.0],
                   "size": 1.5, "resolution": [3, 3]},
        "medium": {"bounds": [[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]], "density": {"file": "grid.npy"},
                   "scale": 5.0, "albedo": [0.9, 0.5, 0.1], "phase": {"type": "isotropic"}},
        "lights": [{"type": "point", "position": [0.5, 3.0, 0.5], "intensity": 2.0}],
        "render": {"max_depth": -1, "transmittance": "track_length",
                   "free_flight": "decomposition"},
    }
    vol = copy.deepcopy(grid)
    vol["medium"]["density"] = {"file": "grid.vol"}
    vol["render"] = {"majorant": "global", "transmittance": "unbiased_raymarch"}
    generated = {
        "camera": {"type": "panoramic", "eye": [0.0, 0.5, 3.0], "target": [0.0, 0.5, 0.0],
                   "resolution": [2, 2]},
        "medium": {"bounds": [[-1.0, 0.0, -1.0], [1.0, 1.0, 1.0]],
                   "density": {"generator": "cloud", "resolution": 4, "seed": 3}},
        "lights": [{"type": "environment", "radiance": [0.1, 0.2, 0.3]}],
    }
    minimal = {"camera": {}, "medium": {"bounds": [[0, 0, 0], [1, 1, 1]], "density": 0}}
    colour = {   # colour-dependent extinction, emission from a field grid, brick storage
        "camera": {"eye": [0.0, 0.0, 3.0], "resolution": [2, 2]},
        "medium": {"bounds": [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]],
                   "density": {"file": "grid.npz", "grid": "density"},
                   "scale": [4.0, 2.0, 1.0], "albedo": 0.7,
                   "emission": {"radiance": [1.0, 0.5, 0.2], "field": {"file": "grid.npy"}}},
        "lights": [{"type": "environment", "radiance": 0.2}],
        "render": {"spectral": "hero", "grid_storage": "bricks"},
    }
    vdb = {   # bounds from the file, temperature from the same file
        "camera": {"eye": [0.2, 0.0, 1.4], "target": [0.2, 0.0, 0.3], "resolution": [2, 2]},
        "medium": {"density": {"file": "blobs.vdb"}, "scale": 10.0,
                   "emission": {"temperature": {"file": "blobs.vdb", "grid": "temperature"},
                                "scale": 1e-4}},
        "lights": [{"type": "environment", "radiance": 0.2}],
    }
    return {"full": full, "grid": grid, "vol": vol, "generated": generated,
            "minimal": minimal, "colour": colour, "vdb": vdb}


BASES = base_scenes()
#: Keys a grid file's own error may name.
GRID_KEYS = ("medium.density", "medium.emission.field", "medium.emission.temperature")
GRID_NAMES = ["grid.npy", "grid.vol", "grid.npz", "missing.npy", "grid.raw", "", ".", "sub",
              "sub.npy", "/nonexistent/abs.vol", "bad.npy", "bad.vol", "bad.npz", "grïd.npy",
              "a\nb.npy", "../grid.npy", "grid.NPY", "grid.npy/", "empty.npy", "blobs.vdb",
              "blobs_zip.nvdb", "rotated.vdb", "cut.vdb", "levelset.nvdb", "grid.vdb"]
VDB_FIXTURES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                            "data", "vdb")


def make_grid_dir(d):
    """The grid files the base scenes and GRID_NAMES name (valid ones and a few bad)."""
    g = np.random.default_rng(0).random((3, 4, 5)).astype(np.float32)
    np.save(os.path.join(d, "grid.npy"), g)
    np.save(os.path.join(d, "grid.NPY"), g)
    np.savez(os.path.join(d, "grid.npz"), density=g)
    np.save(os.path.join(d, "grïd.npy"), g)
    with open(os.path.join(d, "grid.vol"), "wb") as f:
        f.write(vol_bytes(5, 4, 3) + g.tobytes())
    np.save(os.path.join(d, "grid.raw"), g)
    os.mkdir(os.path.join(d, "sub"))
    os.mkdir(os.path.join(d, "sub.npy"))
    bad = g.copy()
    bad[1, 1, 1] = -1.0
    np.save(os.path.join(d, "bad.npy"), bad)
    np.savez(os.path.join(d, "bad.npz"), dens=g)
    with open(os.path.join(d, "bad.vol"), "wb") as f:
        f.write(vol_bytes(2**20, 2**20, 1) + g.tobytes())
    open(os.path.join(d, "empty.npy"), "wb").close()
    for name in ("blobs.vdb", "blobs_zip.nvdb", "rotated.vdb", "levelset.nvdb"):
        shutil.copy(os.path.join(VDB_FIXTURES, name), os.path.join(d, name))
    with open(os.path.join(VDB_FIXTURES, "blobs.vdb"), "rb") as f:
        data = f.read()
    with open(os.path.join(d, "cut.vdb"), "wb") as f:   # truncated
        f.write(data[: len(data) * 2 // 3])
    np.save(os.path.join(d, "grid.vdb"), g)              # an .npy under a .vdb name


density_values = st.one_of(
    st.builds(lambda f: {"file": f}, st.one_of(st.sampled_from(GRID_NAMES), st.text(max_size=8),
                                              scalars)),
    st.builds(lambda f, x: {"file": f, "generator": x}, st.sampled_from(GRID_NAMES), texts),
    st.builds(lambda g, r, s: {"generator": g, "resolution": r, "seed": s},
              st.one_of(st.just("cloud"), texts),
              st.one_of(st.sampled_from([0, -1, 1, 2, 3, 2049, 1.5, "4", True, None]), scalars),
              st.one_of(st.sampled_from([0, -1, 2**63 - 1, 2**63, 2**64]), scalars)),
    st.builds(lambda g, r: {"generator": g, "resolution": r}, st.just("cloud"),
              st.integers(1, 6)),
    st.sampled_from([{}, {"filee": "grid.npy"}, {"file": "grid.npy", "seed": 1},
                     {"generator": "cloud"}, {"resolution": 4}]),
    floats, ints)

light_templates = st.sampled_from([
    {"type": "environment", "radiance": 1.0},
    {"type": "directional", "direction": [0.0, -1.0, 0.0], "irradiance": [1.0, 2.0, 3.0]},
    {"type": "point", "position": [0.0, 0.0, 0.0], "intensity": 1.0},
    {"type": "environment", "direction": [0.0, -1.0, 0.0], "radiance": 1.0},
    {"type": "directional", "direction": [1e-200, 0.0, 0.0], "irradiance": 1.0},
    {"type": "directional", "direction": [1e200, 1e200, 0.0], "irradiance": 1.0},
    {"radiance": 1.0}, {"type": "spot", "position": [0.0, 0.0, 0.0]}, {}, [], 1.0, "sun",
])


# ---------------------------------------------------------------------------------------
# Mutations: ("set", path, value), ("delete", path), ("rename", path, key),
# ("append", path, value), ("define", path, value) (a -D override), ("rawdefine", text)


def paths_of(node, prefix=()):
    out = [prefix] if prefix else []
    if isinstance(node, dict):
        for k, v in node.items():
            out += paths_of(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += paths_of(v, prefix + (i,))
    return out


def _parent(d, path):
    node = d
    for p in path[:-1]:
        if isinstance(node, dict) and p in node:
            node = node[p]
        elif isinstance(node, list) and isinstance(p, int) and p < len(node):
            node = node[p]
        else:
            return None
    return node


def apply_mutations(raw, mutations):
    """Apply the file-level mutations to a copy of ``raw``; return (raw, -D strings)."""
    d = copy.deepcopy(raw)
    defines = []
    for m in mutations:
        op = m[0]
        if op == "rawdefine":
            defines.append(m[1])
            continue
        path = m[1]
        if op == "define":
            defines.append(".".join(str(p) for p in path) + "=" + toml_value(m[2]))
            continue
        parent = _parent(d, path)
        last = path[-1]
        if isinstance(parent, dict):
            if op == "set":
                parent[last] = m[2]
            elif op == "delete":
                parent.pop(last, None)
            elif op == "rename" and last in parent and m[2] not in parent:
                parent[m[2]] = parent.pop(last)
            elif op == "append" and isinstance(parent.get(last), list):
                parent[last].append(m[2])
        elif isinstance(parent, list) and isinstance(last, int) and last < len(parent):
            if op == "set":
                parent[last] = m[2]
            elif op == "delete":
                del parent[last]
            elif op == "append" and isinstance(parent[last], list):
                parent[last].append(m[2])
    return d, defines


def mutation_sections(mutations):
    out = set()
    for m in mutations:
        if m[0] == "rawdefine":
            out.add(m[1].split("=", 1)[0].split(".")[0].strip())
        else:
            out.add(m[1][0])
            if m[0] == "rename" and len(m[1]) == 1:
                out.add(m[2])    # a renamed section is an unknown key
    return out


_SIMPLE_KEY = re.compile(r"^[A-Za-z0-9_]+$")


def _perturb(value, path):
    """A strategy of values near ``value`` (the right kind, but wrong) or anything at all."""
    name = path[-1] if path and isinstance(path[-1], str) else ""
    if name == "density":
        return density_values
    if isinstance(value, bool):
        return scalars
    if isinstance(value, (int, float)):
        big = value * 10**300 if isinstance(value, int) else value * 1e300
        return st.one_of(floats, ints, st.just(-value), st.just(big),
                         st.just([value] * 3), st.just(str(value)), st.just({"value": value}))
    if isinstance(value, str):
        return st.one_of(misspell(value), texts)
    if isinstance(value, list):
        return st.one_of(vectors, st.just(value[:-1]), st.just(value + value[-1:]),
                         st.just([value]), values)
    if isinstance(value, dict):
        return st.one_of(values, st.just(list(value.values())), st.just([value]))
    return values


@st.composite
def scene_cases(draw):
    """(base name, mutations) with one to three mutations of a valid scene."""
    name = draw(st.sampled_from(sorted(BASES)))
    current = copy.deepcopy(BASES[name])
    mutations = []
    for _ in range(draw(st.integers(1, 3))):
        paths = paths_of(current)
        op = draw(st.sampled_from(["set", "set", "set", "nudge", "nudge", "delete", "rename",
                                   "add", "append", "define", "define", "rawdefine"]))
        if op == "rawdefine":
            text = draw(st.one_of(
                st.sampled_from(["junk", "=", "render.spp", "render.spp=", "=1", "a.b", ".x=1",
                                 "camera..eye=1", "lights.9.type=point", "lights.-1.type=x",
                                 "lights.².type=point", "lights.٣.type=point",
                                 "render.spp.x=1", "medium.density.file.x=1",
                                 "render.spp=" + "9" * 5000, "camera.fov=1e400",
                                 "camera.type=orthographic", "camera.resolution=[2, 2]",
                                 "camera.eye=[1e-170, 0, 0]", "medium.phase.g=0.3 # c",
                                 "render.seed=-1", "render.spp=2**40", "camera.fov=" + "[" * 5000,
                                 "medium.albedo=[0.9, 0.8, 0.7]", "render.majorant=grid "]),
                st.text(max_size=20)))
            mutations.append(("rawdefine", text))
            continue
        if op == "nudge":   # a number becomes another number of its kind: often valid
            numeric = [p for p in paths if type(_parent(current, p)[p[-1]]) in (int, float)]
            if not numeric:
                continue
            path = draw(st.sampled_from(numeric))
            old = _parent(current, path)[path[-1]]
            value = draw(floats if isinstance(old, float) else
                         st.one_of(st.integers(-2, 300), st.sampled_from(SPECIAL_INTS)))
            m = ("set", path, value)
            mutations.append(m)
            current, _ = apply_mutations(current, [m])
            continue
        if not paths:   # everything deleted: nothing left to mutate
            continue
        path = draw(st.sampled_from(paths))
        parent = _parent(current, path)
        old = parent[path[-1]]
        if op in ("set", "define"):
            value = draw(_perturb(old, path))
            if op == "define" and not all(_SIMPLE_KEY.match(str(p)) for p in path):
                op = "set"
            m = (op, path, value)
        elif op == "delete":
            m = ("delete", path)
        elif op == "rename":
            if not isinstance(path[-1], str):
                continue
            m = ("rename", path, draw(misspell(path[-1])))
        elif op == "add":
            table = path if isinstance(old, dict) else path[:-1]
            if not table or not isinstance(_parent(current, table + ("x",)), dict):
                table = ()
            key = draw(st.one_of(st.sampled_from(["fov", "g", "file", "seed", "camera",
                                                  "lights", "spp", "density", "type"]),
                                 misspell("resolution"), texts))
            m = ("set", table + (key,), draw(values))
        else:   # append: a list gets another element (lights get light-like tables)
            lists = [p for p in paths if isinstance(_parent(current, p)[p[-1]], list)]
            if not lists:
                continue
            target = draw(st.sampled_from(lists))
            elem = draw(light_templates if target == ("lights",) else scalars)
            m = ("append", target, copy.deepcopy(elem))
        mutations.append(m)
        current, _ = apply_mutations(current, [m])
    return name, tuple(mutations)


def check_scene_case(case):
    name, mutations = case
    raw, defines = apply_mutations(BASES[name], mutations)
    with tempfile.TemporaryDirectory() as d:
        make_grid_dir(d)
        path = os.path.join(d, "scene.toml")
        with open(path, "w", encoding="utf-8") as f:
            f.write(toml_doc(raw))
        files = {path}
        med = raw.get("medium") if isinstance(raw.get("medium"), dict) else {}
        emis = med.get("emission") if isinstance(med.get("emission"), dict) else {}
        for src in (med.get("density"), emis.get("field"), emis.get("temperature")):
            if isinstance(src, dict) and isinstance(src.get("file"), str) and src["file"]:
                files.add(os.path.abspath(os.path.join(d, src["file"])))
        for text in defines:   # a -D may point a grid source at another file
            m = re.match(r"\s*medium\.(?:density|emission)[.\w]*\s*=\s*(.*)", text, re.S)
            if m:
                for f_ in re.findall(r'"((?:[^"\\]|\\.)*)"', m.group(1)) + [m.group(1).strip()]:
                    files.add(os.path.abspath(os.path.join(d, f_)))
        with time_limit(EXAMPLE_LIMIT_S):
            try:
                scene = load_scene(path, defines)
            except SceneError as e:
                assert_scene_error(e, files, mutation_sections(mutations), defines,
                                   file_only_ok=has_unparseable(raw))
                if e.file != path:
                    assert e.key in GRID_KEYS, str(e)
                return
            assert_valid_scene(scene)


@sweep(max_examples=500)
@given(case=scene_cases())
# Regressions: what each one raised, or which check it failed, before the fix.
@example(case=("full", (("set", ("camera", "fov"), 10**400),)))          # OverflowError
@example(case=("minimal", (("rawdefine", "render.spp=" + "9" * 5000),)))  # ValueError
@example(case=("full", (("set", ("render", "spp"), Raw("9" * 5000, parses=False)),)))  # ValueError
@example(case=("full", (("set", ("camera", "fov"), Raw("[" * 2000 + "]" * 2000, False)),)))
# ^ RecursionError
@example(case=("full", (("rawdefine", "lights.².type=point"),)))         # ValueError: int("²")
@example(case=("full", (("set", ("lights", 1, "direction"), [1e-200, 0.0, 0.0]),)))  # 1 / 0
@example(case=("full", (("set", ("lights", 1, "direction"), [1e200, 1e200, 0.0]),)))  # (0, 0, 0)
@example(case=("full", (("set", ("camera", "eye"), [0.0, 0.0, 1e-170]),
                        ("set", ("camera", "target"), [0.0, 0.0, 0.0]),
                        ("set", ("camera", "up"), [0.0, 1e30, 0.0]))))   # pack_scene: 1 / 0
@example(case=("full", (("set", ("camera", "eye"), [1.7976931348623157e308, 0.0, 0.0]),
                        ("set", ("camera", "target"), [-1.7976931348623157e308, 0.0, 0.0]))))
# ^ NaN camera basis
@example(case=("full", (("set", ("camera", "resolution"), [2**40, 1]),)))  # int32 width
@example(case=("full", (("set", ("render", "spp"), 2**40),)))             # uint32 sample index
@example(case=("full", (("set", ("medium", "density"), 1e300),)))         # inf majorant
@example(case=("full", (("set", ("medium", "scale"), 1e39),)))             # float32 inf
@example(case=("full", (("set", ("medium", "bounds"), [[0.0, 0.0, 0.0], [1e-39, 1.0, 1.0]]),)))
# ^ float32 inf 1 / extent
@example(case=("full", (("set", ("camera", "a\nb"), 1),)))                # two-line message
@example(case=("full", (("rename", ("camera",), "camera\n"),)))          # two-line message
@example(case=("full", (("rawdefine", "\x1e"),)))                        # two-line message
@example(case=("grid", (("set", ("medium", "density"), {"file": "a\nb.npy"}),)))  # two lines
@example(case=("full", (("rename", ("camera",), ""),)))                   # names no key
@example(case=("grid", (("set", ("medium", "density"), {"file": "bad.vol"}),)))  # MemoryError
@example(case=("full", (("set", ("lights", 1, "direction"), [0.0, -1.0, -0.5]),)))
# ^ the written-out scene read back had a direction 1 ulp off (re-normalised)
@example(case=("colour", (("set", ("medium", "emission", "field"), {"file": "cut.vdb"}),)))
@example(case=("vdb", (("set", ("medium", "density"), {"file": "rotated.vdb"}),)))
@example(case=("vdb", (("set", ("medium", "density"), {"file": "levelset.nvdb"}),)))
@example(case=("vdb", (("set", ("medium", "density"), {"file": "grid.vdb"}),)))
@example(case=("vdb", (("set", ("medium", "emission", "temperature", "grid"), "velocity"),)))
@example(case=("colour", (("set", ("render", "transmittance"), "power_series"),)))
def test_scene_sweep(case):
    check_scene_case(case)


# ---------------------------------------------------------------------------------------
# Grid files


def vol_bytes(nx, ny, nz, ch=1, magic=b"VOL", version=3, enc=1, bbox=(0, 0, 0, 1, 1, 1)):
    """A Mitsuba .vol header (any field values that fit its struct)."""
    return VOL_HEADER.pack(magic, version, enc, nx, ny, nz, ch, *bbox)


def npy_header(descr, fortran, shape, version=1):
    h = ("{'descr': %s, 'fortran_order': %s, 'shape': %s, }" % (descr, fortran, shape))
    h = h.encode("latin1")
    head = 10 if version == 1 else 12
    h += b" " * ((-(head + len(h) + 1)) % 64) + b"\n"
    size = struct.pack("<H", len(h)) if version == 1 else struct.pack("<I", len(h))
    return b"\x93NUMPY" + bytes([version, 0]) + size + h


DTYPES = ["<f4", ">f4", "<f8", "<f2", "<i1", ">i4", "<i8", "<u1", "<u8", "?", "<c8", "<U3",
          "S2", "<M8[s]", "<m8[s]", "V4", "O", "g", [("a", "<f4")]]
GRID_VALUES = [0.0, 1.0, 0.5, -1.0, -0.0, math.nan, math.inf, -math.inf, 1e-45, 3.4e38,
               3.5e38, 1e300, 2**64 - 1.0, 255.0]


@st.composite
def arrays(draw):
    dtype = np.dtype(draw(st.sampled_from(DTYPES)))
    shape = tuple(draw(st.one_of(st.lists(st.integers(1, 4), min_size=3, max_size=3),
                                 st.lists(st.integers(0, 3), max_size=5))))
    fill = draw(st.sampled_from(GRID_VALUES))
    specials = draw(st.lists(st.tuples(st.integers(0, 10**6), st.sampled_from(GRID_VALUES)),
                             max_size=3))
    base = np.random.default_rng(draw(st.integers(0, 3))).random(shape) * (fill or 1.0)
    flat = base.reshape(-1)
    for i, v in specials:
        if flat.size:
            flat[i % flat.size] = v
    with np.errstate(all="ignore"), _no_warnings():
        if dtype.kind == "O":
            arr = np.empty(shape, object)
            arr.reshape(-1)[:] = list(flat) if flat.size else []
        elif dtype.kind in "USV":
            arr = flat.astype(str).astype(dtype).reshape(shape) if dtype.kind != "V" \
                else np.zeros(shape, dtype)
        elif dtype.kind in "Mm":
            arr = np.zeros(shape, dtype)
        elif dtype.names:
            arr = np.zeros(shape, dtype)
        else:
            arr = base.astype(dtype)
    if draw(st.booleans()):
        arr = np.asfortranarray(arr)
    return arr


@contextlib.contextmanager
def _no_warnings():
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


def _npy(arr):
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=True)
    return buf.getvalue()


def _npz(arrs, compressed):
    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, **arrs)
    return buf.getvalue()


def _zip_member(data, name="density.npy", method=zipfile.ZIP_STORED):
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", method) as z:
        z.writestr(name, data)
    return buf.getvalue()


@st.composite
def corrupt(draw, data):
    how = draw(st.sampled_from(["none", "none", "truncate", "flip", "insert", "append",
                                "zero_tail"]))
    if how == "none" or not data:
        return data
    k = draw(st.integers(0, max(len(data) - 1, 0)))
    if how == "truncate":
        return data[:k]
    if how == "flip":
        return data[:k] + bytes([data[k] ^ draw(st.integers(1, 255))]) + data[k + 1:]
    if how == "insert":
        return data[:k] + draw(st.binary(min_size=1, max_size=8)) + data[k:]
    if how == "append":
        return data + draw(st.binary(min_size=1, max_size=64))
    return data[:k] + bytes(len(data) - k)


SHAPE_TEXTS = ["(2, 2, 2)", "(100000, 100000, 100000)", "(1048576, 1048576, 1)",
               "(10000000000000000, 100000000000, 100000)", "(-2, 2, 2)", "()", "(2,)",
               "('a', 2, 2)", "(2.0, 2, 2)", "(True, 1, 1)", "(2, 2, 2", "[2, 2, 2]",
               "(99999999999999999999999999, 1, 1)", "(0, 1000000000000000000, 1)"]
DESCR_TEXTS = ["'<f4'", "'<f8'", "'|O'", "'<i4'", "'xx'", "5", "[('a', '<f4')]", "'<U0'",
               "'V0'", "'<f4' 'x'", "None", "'>c16'"]


@st.composite
def grid_files(draw):
    """(file name, bytes) of a density grid file, valid or broken in many ways."""
    kind = draw(st.sampled_from(["npy", "npy", "npz", "vol", "vol", "header", "junk"]))
    if kind == "npy":
        return "g.npy", draw(corrupt(_npy(draw(arrays()))))
    if kind == "npz":
        names = draw(st.lists(st.sampled_from(["density", "density", "Density", "d", "x"]),
                              min_size=0, max_size=2, unique=True))
        data = _npz({n: draw(arrays()) for n in names}, draw(st.booleans()))
        return "g.npz", draw(corrupt(data))
    if kind == "vol":
        dims = st.one_of(st.integers(1, 4), st.sampled_from([0, -1, 2**31 - 1, 2**20, 1000]))
        nx, ny, nz = draw(dims), draw(dims), draw(dims)
        ch = draw(st.sampled_from([1, 1, 1, 0, 3, -1, 2**31 - 1]))
        magic = draw(st.sampled_from([b"VOL", b"VOL", b"VOX", b"vol", b"\0\0\0"]))
        version = draw(st.sampled_from([3, 3, 2, 4, 255]))
        enc = draw(st.sampled_from([1, 1, 1, 0, 2, -1]))
        bbox = draw(st.lists(st.sampled_from([0.0, 1.0, -1.0, math.nan, math.inf]),
                             min_size=6, max_size=6))
        n = max(nx, 0) * max(ny, 0) * max(nz, 0) * max(ch, 0)
        n = min(n, 64) + draw(st.sampled_from([0, 0, 0, -1, 1, 7]))
        with np.errstate(over="ignore"), _no_warnings():
            vals = np.array(draw(st.lists(st.sampled_from(GRID_VALUES), min_size=max(n, 0),
                                          max_size=max(n, 0))), "<f4")
        data = vol_bytes(nx, ny, nz, ch, magic, version, enc, bbox) + vals.tobytes()
        return "g.vol", draw(corrupt(data))
    if kind == "header":
        head = npy_header(draw(st.sampled_from(DESCR_TEXTS)),
                          draw(st.sampled_from(["False", "True", "12"])),
                          draw(st.sampled_from(SHAPE_TEXTS)), draw(st.sampled_from([1, 2, 3])))
        data = head + draw(st.binary(max_size=64))
        if draw(st.booleans()):
            return "g.npy", data
        return "g.npz", _zip_member(data, method=draw(st.sampled_from([zipfile.ZIP_STORED,
                                                                       zipfile.ZIP_DEFLATED])))
    name = draw(st.sampled_from(["g.npy", "g.npz", "g.vol", "g.raw", "g.NPZ", "g"]))
    data = draw(st.one_of(
        st.binary(max_size=200), st.just(b""), st.just(b"PK\x03\x04" + bytes(40)),
        st.just(_npy(np.ones((2, 2, 2), np.float32))),
        st.just(_npz({"density": np.ones((2, 2, 2))}, True)),
        st.just(b"\x80\x04\x95" + bytes(20)), st.just(b"VOL\x03" + bytes(8))))
    return name, data


def check_grid_file(spec):
    name, data = spec
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, name)
        with open(path, "wb") as f:
            f.write(data)
        with time_limit(EXAMPLE_LIMIT_S):
            try:
                g = load_grid(path, "medium.density")
            except SceneError as e:
                assert_scene_error(e, {path}, key="medium.density")
                g = None
            if g is not None:
                assert g.dtype == np.float32 and g.ndim == 3 and g.size > 0
                assert g.flags.c_contiguous and np.all(np.isfinite(g)) and g.min() >= 0
                assert float(g.max()) <= FLT_MAX
            # The same file referenced by a scene: the same verdict, now about the scene.
            raw = copy.deepcopy(BASES["grid"])
            raw["medium"]["density"] = {"file": name}
            spath = os.path.join(d, "scene.toml")
            with open(spath, "w", encoding="utf-8") as f:
                f.write(toml_doc(raw))
            try:
                scene = load_scene(spath)
            except SceneError as e:
                if g is None:
                    assert_scene_error(e, {path}, key="medium.density")
                else:   # a valid grid, but scale * max(grid) overflows the float32 kernels
                    assert_scene_error(e, {spath}, key="medium.scale")
                    assert raw["medium"]["scale"] * float(g.max()) > FLT_MAX
            else:
                assert g is not None and np.array_equal(scene.grid, g)
                assert_valid_scene(scene)
            # And converted by the CLI (in process): status 0, or 2 with one line.
            out = os.path.join(d, "out.vol")
            status, err = run_cli_inprocess(["convert", path, out])
            assert (status == 0) == (g is not None), err
            if status:
                assert_cli_error(status, err)


def _deflate_damaged_npz():
    data = _npz({"density": np.linspace(0, 1, 64).reshape(4, 4, 4)}, True)
    return data[:60] + bytes(40) + data[100:]


@sweep(max_examples=400)
@given(spec=grid_files())
# Regressions: what each one raised, or which check it failed, before the fix.
@example(spec=("g.vol", vol_bytes(2**31 - 1, 2**31 - 1, 2**31 - 1) + bytes(64)))  # Overflow
@example(spec=("g.vol", vol_bytes(2**20, 2**20, 1) + bytes(64)))     # MemoryError (4 TiB)
@example(spec=("g.npy", npy_header("'<f4'", "False", "(100000, 100000, 100000)") + bytes(64)))
# ^ MemoryError (3.55 PiB)
@example(spec=("g.npy", npy_header("'<f8'", "False", "(99999999") + bytes(8)))  # TokenError
@example(spec=("g.npz", _deflate_damaged_npz()))                      # zlib.error
@example(spec=("g.npz", _npy(np.ones((2, 2, 2), np.float32))))  # TypeError: .npy named .npz
@example(spec=("g.npy", npy_header("'<U0'", "False", "(True, 1, 1)")))  # TypeError in numpy
@example(spec=("g.npz", _zip_member(npy_header("'<f4'", "False", "(True, 1, 1)") + bytes(4))))
# ^ TypeError in numpy
@example(spec=("g.npy", _npy(np.full((2, 2, 2), 3e38, np.float32))))  # 5 * 3e38: inf majorant
def test_grid_file_sweep(spec):
    check_grid_file(spec)


# ---------------------------------------------------------------------------------------
# Corrupted TOML text

VALID_TEXT = (
    '[camera]\ntype = "perspective"\neye = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\n'
    'fov = 45.0\nresolution = [4, 3]\n\n[medium]\nbounds = [[-1.0, -1.0, -1.0], '
    '[1.0, 1.0, 1.0]]\ndensity = 1.0\nscale = 20.0\nalbedo = 0.8\nphase = { type = "hg", '
    'g = 0.6 }\n\n[[lights]]\ntype = "environment"\nradiance = 0.3\n\n[[lights]]\n'
    'type = "directional"\ndirection = [-1.0, -1.0, -0.5]\nirradiance = 3.0\n\n[render]\n'
    'spp = 4\nseed = 0\n').encode()
TOML_PIECES = [b"\x00", b"\xff\xfe", b"\xc3", b"\n", b"[", b"]", b"[[lights]]\n", b"=", b'"',
               b"'''", b"#", b"inf", b"nan", b"\t", b"\r", b"\xe2\x80\xa8", b"camera.fov = 1\n",
               b"[camera]\n", b"9" * 5000, b"[" * 3000, b"{", b"1979-05-27", b"\\u0000"]


@st.composite
def toml_texts(draw):
    data = VALID_TEXT
    for _ in range(draw(st.integers(1, 3))):
        k = draw(st.integers(0, len(data)))
        how = draw(st.sampled_from(["truncate", "delete", "insert", "insert", "replace"]))
        if how == "truncate":
            data = data[:k]
        elif how == "delete":
            data = data[:k] + data[k + draw(st.integers(1, 20)):]
        else:
            piece = draw(st.one_of(st.sampled_from(TOML_PIECES), st.binary(min_size=1,
                                                                           max_size=6)))
            data = data[:k] + piece + data[k + (len(piece) if how == "replace" else 0):]
    return data


@sweep(max_examples=300)
@given(text=toml_texts())
@example(text=VALID_TEXT.replace(b"spp = 4", b"spp = " + b"9" * 5000))   # ValueError
@example(text=VALID_TEXT.replace(b"fov = 45.0", b"fov = " + b"[" * 3000))  # RecursionError
@example(text=VALID_TEXT.replace(b"fov = 45.0", b'"fov\\u000a" = 1'))    # two-line message
def test_corrupt_toml_sweep(text):
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "scene.toml")
        with open(path, "wb") as f:
            f.write(text)
        with time_limit(EXAMPLE_LIMIT_S):
            try:
                scene = load_scene(path)
            except SceneError as e:
                assert_scene_error(e, {path}, file_only_ok=True)
                return
            assert_valid_scene(scene)


# ---------------------------------------------------------------------------------------
# The command line


def run_cli_inprocess(argv):
    """``volmc.cli.main(argv)`` with stdout/stderr captured: (status, stderr text)."""
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        status = cli_main(argv)
    return status, err.getvalue()


def assert_cli_error(status, stderr):
    assert status == 2, stderr
    lines = stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("volmc: error: "), stderr
    assert "Traceback" not in stderr


TINY = ('[camera]\nresolution = [2, 2]\n[medium]\nbounds = [[-1.0, -1.0, -1.0], [1.0, 1.0, '
        '1.0]]\ndensity = 1.0\nalbedo = 0.0\n[[lights]]\ntype = "environment"\nradiance = '
        '0.5\n[render]\nspp = 1\n')

#: Flag values that are wrong (or harmless): a valid value renders a 2x2, 1 spp image.
BAD_FLAGS = {
    "--spp": ["-3", "0", "abc", "", "1.5", "1e3", "²", "99999999999999999999999"],
    "--seed": ["abc", "-1", "18446744073709551616", "", "0x10", "1.0", "٣"],
    "-D": ["junk", "=", "render.spp", "render.spp=", "a.b=1", "lights.5.type=point",
           "lights.².radiance=1", "render.spp=" + "9" * 5000, "camera.fov=" + "[" * 3000,
           "camera.resolution=[0, 2]", "medium.density.file=missing.npy",
           "medium.density.file=/", "render.spp=0", "camera.a\nb=1"],
    "--device": ["9:9", "9", "0:9", "0:x", "nosuchdevice", "²", "0:²", ":", ""],
    "--backend": ["gpu", "", "OPENCL", "numba "],
    "--exposure": ["nan", "inf", "-inf", "1e308", "-1e308", "abc", ""],
    "--tonemap": ["aces", ""],
    "-o": ["", ".", "/", "/nonexistent/dir/x.exr", "{d}", "{d}/sub", "{d}/sub/"],
    "--png": ["", "/", "/nonexistent/x.png", "{d}/sub"],
    "--frobnicate": ["1"],
}


@st.composite
def command_lines(draw):
    flag = draw(st.sampled_from(sorted(BAD_FLAGS)))
    # No NUL: a real command line cannot hold one.
    value = draw(st.one_of(st.sampled_from(BAD_FLAGS[flag]),
                           st.text(st.characters(blacklist_characters="\x00"), max_size=8)))
    if flag in ("--spp", "--seed") and _parses_as_int(value):
        value = value + "x"      # a valid, possibly huge, count would render for ages
    return flag, value


def _parses_as_int(text):
    try:
        int(text)
    except ValueError:
        return False
    return True


def _cli_argv(d, flag, value, quiet=True):
    scene = os.path.join(d, "tiny.toml")
    with open(scene, "w") as f:
        f.write(TINY)
    os.makedirs(os.path.join(d, "sub"), exist_ok=True)
    argv = ["render", scene, "-o", os.path.join(d, "out.exr"), "--png"]   # --png: exposure used
    return argv + (["--quiet"] if quiet else []) + [flag, value.replace("{d}", d)]


@sweep(max_examples=60)
@given(cl=command_lines())
# Regressions: each raised after (or instead of) a render before the fix.
@example(cl=("-o", "{d}/sub"))         # RuntimeError: cannot open image file, a directory
@example(cl=("--png", "{d}/sub"))      # ValueError: unknown image file extension
@example(cl=("--png", "0"))            # ValueError: unknown image file extension
@example(cl=("--exposure", "1e308"))   # OverflowError in 2 ** exposure
@example(cl=("-D", "lights.².radiance=1"))      # ValueError: int("²")
@example(cl=("--device", "²"))                  # ValueError: int("²")
@example(cl=("-D", "render.spp=" + "9" * 5000))  # ValueError: int over 4300 digits
def test_cli_flag_sweep(cl):
    flag, value = cl
    with tempfile.TemporaryDirectory() as d, contextlib.chdir(d):  # relative outputs land in d
        with time_limit(60.0):
            status, err = run_cli_inprocess(_cli_argv(d, flag, value))
        event(f"exit status {status}")
        if status != 0:
            assert_cli_error(status, err)


def run_cli(args, cwd):
    env = dict(os.environ)
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    env["PYTHONPATH"] = os.pathsep.join([root, env.get("PYTHONPATH", "")])
    return subprocess.run([sys.executable, "-m", "volmc.cli", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=120)


def test_cli_subprocess_bad_flags(tmp_path):
    """The real CLI, one process per command line: exit 2, one line, no traceback."""
    cases = [("--spp", "-3"), ("--seed", "abc"), ("-D", "junk"), ("--device", "9:9"),
             ("--exposure", "1e308"), ("-o", "{d}/sub"), ("-D", "lights.².radiance=1")]
    for flag, value in cases:
        # Not --quiet: nothing but the error may reach stderr.
        r = run_cli(_cli_argv(str(tmp_path), flag, value, quiet=False), tmp_path)
        assert_cli_error(r.returncode, r.stderr)
        assert not (tmp_path / "out.exr").exists()
    r = run_cli(["check", str(tmp_path / "tiny.toml"), "--backends", "opencl,cuda"], tmp_path)
    assert_cli_error(r.returncode, r.stderr)
    r = run_cli(["info", "--verbose"], tmp_path)
    assert_cli_error(r.returncode, r.stderr)


@settings(derandomize=True, database=None, max_examples=6, deadline=None,
          suppress_health_check=list(HealthCheck))
@given(case=scene_cases(), spec=grid_files(), which=st.sampled_from(["render", "check"]))
def test_cli_subprocess_generated_bad_files(case, spec, which):
    """Generated bad scenes and grid files through the real CLI: the same one-line error as
    the loader, exit status 2, no traceback. (Inputs that load are skipped: no renders.)"""
    name, data = spec
    with tempfile.TemporaryDirectory() as d:
        make_grid_dir(d)
        with open(os.path.join(d, name), "wb") as f:
            f.write(data)
        raw, defines = apply_mutations(BASES[case[0]], case[1])
        if isinstance(raw.get("medium"), dict) and "g" in name:
            raw["medium"]["density"] = {"file": name}
        path = os.path.join(d, "scene.toml")
        with open(path, "w", encoding="utf-8") as f:
            f.write(toml_doc(raw))
        try:
            load_scene(path, defines)
        except SceneError as e:
            expected = f"volmc: error: {e}"
        else:
            assume(False)   # it loads: the CLI would render it
        args = [which, path, "--spp", "1"] + [a for t in defines for a in ("-D", t)]
        if which == "render":
            args += ["-o", os.path.join(d, "out.exr")]
        r = run_cli(args, d)
        assert_cli_error(r.returncode, r.stderr)
        assert r.stderr.splitlines()[0] == expected.splitlines()[0]
