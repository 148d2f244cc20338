"""Mutation fuzzing of the binary readers: ``python -m volmc.bench.fuzz --cases N``.

Each case takes a fixture (the committed OpenVDB / NanoVDB files of tests/data, an EXR map,
a density grid as .npy, .npz and .vol, and a render checkpoint, the last four written by
volmc), damages it -- a truncation, bit flips, a byte burst, or a 4- or 8-byte
word overwritten with a huge, negative or boundary value (half the time at a word that
holds a count, a length or an offset of the original, so the damage lands on structure
rather than on voxel values) -- and reads it with the reader users reach: ``read_vdb`` of
one of the file's grids, ``list_grids``, ``read_env_map``, ``load_grid``, and
``checkpoint.load`` (``--resume``) against the scene it was written for.

A case passes when the read ends in a grid (map) or in the readers' one-line SceneError.
It fails when it raises anything else (a warning included), runs longer than the per-case time limit (a SIGALRM
interrupts Python-level loops; the readers' loops are bounded by the file's bytes, so a
case that needs it is a bug), or allocates more than the memory check approved: the cases
run with $VOLMC_MEMORY_LIMIT at ``memory`` bytes, so every large allocation a reader makes
through ``require_host`` is refused above it, and tracemalloc's peak of the case must stay
under that limit plus a few times the file's size (the copies a reader makes of its input).

The same ``run_case`` drives tests/test_fuzz_readers.py (hypothesis draws the mutations) and
this benchmark (a seeded RNG draws them), which prints the outcome counts, the cases per
second and every failing case (fixture, mutation, message) for the record.
"""

import argparse
import contextlib
import gzip
import os
import signal
import sys
import tempfile
import time
import tracemalloc
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Per-case wall-time limit (s) and the memory limit the cases run under (bytes).
CASE_SECONDS = 10.0
MEMORY_LIMIT = 64 << 20

#: The test fixtures of a checkout (the tests pass their own folder: an installed volmc has
#: no tests/ beside it).
DATA = Path(__file__).resolve().parents[2] / "tests" / "data"
VDB_FIXTURES = ["fire/cache_fluid/data/fluid_data_0013.vdb",
                "fire/resumable/cache_fluid/data/fluid_data_0016.vdb", "fire/houdini_pyro.vdb",
                "fire/embergen.vdb", "fire/double.vdb", "vdb/quirks.vdb", "vdb/quirks_zip.vdb",
                "vdb/quirks_mask.vdb", "vdb/half_zip.vdb", "vdb/blobs_zip.vdb",
                "vdb/quirks.nvdb", "vdb/blobs_zip.nvdb", "vdb/blobs_blosc.nvdb",
                "vdb/levelset.nvdb", "vdb/blobs_none.nvdb.gz", "vdb/inactive.vdb",
                "vdb/inactive.nvdb"]
KINDS = ("truncate", "flip", "burst", "word4", "word8")
#: The readers fuzzed, by fixture kind.
KINDS_READ = ("vdb", "exr", "grid", "checkpoint")
HUGE4 = (0xFFFFFFFF, 0x7FFFFFFF, 0x80000000, 0x40000000, 0x00010000, 0)
HUGE8 = ((1 << 64) - 1, (1 << 63) - 1, 1 << 63, 1 << 62, 1 << 40, 1 << 32, 0)


class Hang(BaseException):
    """A case ran past its time limit (BaseException: no ``except Exception`` in a reader
    can turn it into an ordinary error)."""


@contextlib.contextmanager
def time_limit(seconds):
    """Raise Hang in the block once ``seconds`` have passed (SIGALRM: Python-level code)."""
    def on_alarm(signum, frame):
        raise Hang(f"input took more than {seconds} s")
    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


@dataclass
class Fixture:
    """A file to mutate: its bytes, its kind (one of KINDS_READ), the grids it holds, the
    offsets of its words that look like structure (counts, lengths, in-file offsets), and
    for a checkpoint the scene it belongs to."""
    name: str
    kind: str
    data: bytes
    grids: list
    structural: np.ndarray
    scene: object = None


@dataclass
class Outcome:
    status: str          # "ok", "refused", "crash", "hang", "memory"
    message: str
    seconds: float
    peak: int


def structural_offsets(data):
    """Offsets of 4-byte words holding 1..65536 (counts, string lengths) and of 8-byte
    words holding an offset or size inside the file (grid offsets, compressed sizes)."""
    b = np.frombuffer(data, np.uint8)
    if len(b) < 8:
        return np.zeros(0, np.int64)
    idx4 = np.arange(len(b) - 3)
    v4 = (b[idx4].astype(np.int64) | b[idx4 + 1].astype(np.int64) << 8
          | b[idx4 + 2].astype(np.int64) << 16 | b[idx4 + 3].astype(np.int64) << 24)
    idx8 = np.arange(len(b) - 7)
    hi = (b[idx8 + 4].astype(np.int64) | b[idx8 + 5].astype(np.int64) << 8
          | b[idx8 + 6].astype(np.int64) << 16 | b[idx8 + 7].astype(np.int64) << 24)
    v8 = v4[:len(idx8)]
    counts = idx4[(v4 >= 1) & (v4 <= 65536)]
    offsets = idx8[(hi == 0) & (v8 > 16) & (v8 <= len(b))]
    return np.union1d(counts, offsets)


def load_fixtures(tmp, folder=None):
    """The fixtures: the VDB files of ``folder`` (default DATA, a checkout's tests/data; the
    Mantaflow cache from the scenes, scenes/data/fire) and an EXR map written into ``tmp``."""
    from ..film import write_exr
    from ..resources import scenes_dir
    from ..scene.vdb import list_grids
    folder = DATA if folder is None else Path(folder)
    out = []
    for rel in VDB_FIXTURES:
        path = (scenes_dir() / "data" if rel.startswith("fire/cache_fluid/") else folder) / rel
        data = path.read_bytes()
        if rel.endswith(".gz"):   # committed gzipped: an uncompressed NanoVDB file is large
            data = gzip.decompress(data)
            rel = rel[:-3]
            path = Path(tmp) / Path(rel).name
            path.write_bytes(data)
        out.append(Fixture(rel, "vdb", data, [g.name for g in list_grids(path)],
                           structural_offsets(data)))
    exr = Path(tmp) / "map.exr"
    write_exr(exr, np.random.default_rng(0).random((16, 32, 3)).astype(np.float32) + 0.5)
    data = exr.read_bytes()
    out.append(Fixture("map.exr", "exr", data, [], structural_offsets(data)))
    out += _volmc_fixtures(Path(tmp))
    return out


def _volmc_fixtures(tmp):
    """The files volmc writes itself: a grid in each format, and a checkpoint of a 4x4
    render of scenes/tests/absorber.toml (its sums made up: only the reading is tested)."""
    from .. import checkpoint
    from ..film import Film
    from ..params import COUNTER_NAMES
    from ..resources import scenes_dir
    from ..scene import load_scene
    from ..scene.grids import save_grid
    rng = np.random.default_rng(1)
    out = []
    for suffix in (".npy", ".npz", ".vol"):
        path = tmp / f"grid{suffix}"
        save_grid(path, rng.random((5, 6, 7)).astype(np.float32))
        data = path.read_bytes()
        out.append(Fixture(path.name, "grid", data, [], structural_offsets(data)))
    scene = load_scene(scenes_dir() / "tests" / "absorber.toml", ["camera.resolution=[4, 4]"])
    film = Film(4, 4)
    film.sum[...] = rng.random(film.sum.shape)
    film.sum_sq[...] = film.sum ** 2
    film.spp = 3
    path = tmp / "render.ckpt"
    checkpoint.save(path, film, {n: 7 for n in COUNTER_NAMES}, 1.5,
                    checkpoint.identity(scene, "numba"))
    data = path.read_bytes()
    out.append(Fixture(path.name, "checkpoint", data, [], structural_offsets(data), scene))
    return out


def mutate(data, structural, draw):
    """(damaged bytes, description). ``draw(lo, hi)`` returns an int in [lo, hi]: hypothesis
    or an RNG decides every choice."""
    b = bytearray(data)
    kind = KINDS[draw(0, len(KINDS) - 1)]

    def position(width):
        if len(structural) and draw(0, 1):
            return min(int(structural[draw(0, len(structural) - 1)]), len(b) - width)
        return draw(0, max(len(b) - width, 0))

    if kind == "truncate":
        cut = draw(0, len(b) - 1)
        return bytes(b[:cut]), f"truncate at {cut}"
    if kind == "flip":
        bits = [draw(0, 8 * len(b) - 1) for _ in range(draw(1, 8))]
        for bit in bits:
            b[bit // 8] ^= 1 << bit % 8
        return bytes(b), f"flip bits {bits}"
    if kind == "burst":
        at, n = position(1), draw(1, 16)
        burst = bytes(draw(0, 255) for _ in range(n))
        b[at:at + n] = burst
        return bytes(b[:len(data)]), f"burst {burst.hex()} at {at}"
    width = 4 if kind == "word4" else 8
    table = HUGE4 if width == 4 else HUGE8
    pick = draw(0, len(table))
    value = table[pick] if pick < len(table) else \
        int.from_bytes(bytes(draw(0, 255) for _ in range(width)), "little")
    at = position(width)
    b[at:at + width] = value.to_bytes(width, "little")
    return bytes(b), f"{width}-byte word {value:#x} at {at}"


@contextlib.contextmanager
def _memory_limit(nbytes):
    """$VOLMC_MEMORY_LIMIT at ``nbytes`` for the block."""
    old = os.environ.get("VOLMC_MEMORY_LIMIT")
    os.environ["VOLMC_MEMORY_LIMIT"] = str(nbytes)
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("VOLMC_MEMORY_LIMIT", None)
        else:
            os.environ["VOLMC_MEMORY_LIMIT"] = old


def run_case(fixture, damaged, path, choice, seconds=CASE_SECONDS):
    """Write ``damaged`` to ``path`` and read it as ``fixture`` is read: grid ``choice`` of
    its grids (len(grids): list_grids instead), or the EXR map. Returns an Outcome."""
    from .. import checkpoint
    from ..scene import envmap
    from ..scene.errors import SceneError
    from ..scene.grids import load_grid
    from ..scene.vdb import list_grids, read_vdb
    Path(path).write_bytes(damaged)
    key = {"exr": "lights[0].file", "checkpoint": "--resume"}.get(fixture.kind,
                                                                   "medium.density")
    tracemalloc.start()
    t = time.perf_counter()
    status, message = "ok", ""
    try:
        # A warning (numpy's overflow in a cast, ...) would print lines on a user's
        # terminal next to the one-line error: the readers must not emit any.
        with time_limit(seconds), _memory_limit(MEMORY_LIMIT), warnings.catch_warnings():
            warnings.simplefilter("error")
            if fixture.kind == "exr":
                envmap._cache.clear()
                px = envmap.read_env_map(str(path), "scene.toml", key)
                if not (px.ndim == 3 and px.shape[2] == 3 and np.all(np.isfinite(px))
                        and np.all(px >= 0)):
                    status, message = "crash", f"a map of bad texels came back {px.shape}"
            elif fixture.kind == "grid":
                g = load_grid(path, key)
                if not (g.dtype == np.float32 and g.ndim == 3 and np.all(np.isfinite(g))
                        and np.all(g >= 0)):
                    status, message = "crash", f"a bad grid came back {g.shape}"
            elif fixture.kind == "checkpoint":
                film, counters, secs = checkpoint.load(path, fixture.scene, "numba")
                if not (np.all(np.isfinite(film.sum)) and film.spp > 0 and secs >= 0):
                    status, message = "crash", "a damaged film came back"
            elif choice < len(fixture.grids):
                g = read_vdb(path, fixture.grids[choice], key)
                if not (g.values.dtype == np.float32 and g.values.shape[1:] == (8, 8, 8)
                        and len(g.origins) == len(g.values)):
                    status, message = "crash", "a malformed VdbGrid came back"
            else:
                list_grids(path, key)
    except SceneError as e:
        text = str(e)
        status, message = "refused", text
        if "\n" in text or key not in text:
            status = "crash"   # not the one-line error naming the key
    except Hang as e:
        status, message = "hang", str(e)
    except Exception as e:  # noqa: BLE001 -- any other exception is the finding
        status, message = "crash", f"{type(e).__name__}: {e}"[:300]
    seconds_taken = time.perf_counter() - t
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    if status in ("ok", "refused") and peak > MEMORY_LIMIT + 4 * len(damaged) + (4 << 20):
        status, message = "memory", f"peak {peak} bytes; {message}"
    return Outcome(status, message, seconds_taken, peak)


def scratch_dir():
    """A directory for the damaged files: /dev/shm when there is one (no disk writes)."""
    return tempfile.TemporaryDirectory(dir="/dev/shm" if os.path.isdir("/dev/shm") else None)


def fuzz(cases, seed=0, kinds=KINDS_READ, folder=None):
    """Run ``cases`` cases drawn by a seeded RNG over the fixtures of ``folder`` (see
    load_fixtures); returns (counts, failures, seconds)."""
    rng = np.random.default_rng(seed)

    def draw(lo, hi):
        return int(rng.integers(lo, hi, endpoint=True))

    counts, failures = {}, []
    t = time.perf_counter()
    with scratch_dir() as tmp:
        fixtures = [f for f in load_fixtures(tmp, folder) if f.kind in kinds]
        for i in range(cases):
            fx = fixtures[i % len(fixtures)]
            damaged, what = mutate(fx.data, fx.structural, draw)
            path = Path(tmp) / f"case{Path(fx.name).suffix}"
            out = run_case(fx, damaged, path, draw(0, len(fx.grids)))
            counts[out.status] = counts.get(out.status, 0) + 1
            if out.status not in ("ok", "refused"):
                failures.append((fx.name, what, out))
    return counts, failures, time.perf_counter() - t


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m volmc.bench.fuzz", description=__doc__.split(
        "\n\n")[0])
    p.add_argument("--cases", type=int, default=5000, help="cases to run (default 5000)")
    p.add_argument("--seed", type=int, default=0, help="RNG seed (default 0)")
    p.add_argument("--only", choices=KINDS_READ, help="fuzz one reader only")
    p.add_argument("--fixtures", type=Path, default=DATA,
                   help="the folder of the test fixtures (default: tests/data of this checkout)")
    args = p.parse_args(argv)
    if not (args.fixtures / "vdb").is_dir():
        print(f"python -m volmc.bench.fuzz: --fixtures {args.fixtures}: no vdb/ fixture folder "
              "there (the fixtures come with a checkout of volmc, in tests/data)", file=sys.stderr)
        return 2
    counts, failures, seconds = fuzz(args.cases, args.seed,
                                     (args.only,) if args.only else KINDS_READ, args.fixtures)
    print(f"{args.cases} cases in {seconds:.1f} s ({args.cases / seconds:.0f}/s): "
          + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    for name, what, out in failures:
        print(f"FAIL {out.status}: {name}: {what}: {out.message}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
