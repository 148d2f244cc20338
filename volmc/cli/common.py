"""What the commands share: the one-line-error parser, the flag value types, the options
several commands take and the checks of output paths."""

import argparse
import contextlib
import math
import os

from ..outputs import check_output as check_writable
from ..scene.errors import SceneError

EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130
SCENE_HELP = "scene .toml (default: the bundled cloud scene)"


class Parser(argparse.ArgumentParser):
    """argparse with a one-line error (no usage dump) and exit status 2. An option given an
    empty value (``-o ""``, ``--json ""``) is an error too: otherwise it reads as "not
    given", and a JSON report or checkpoint the user asked for would silently not be
    written."""

    def error(self, message):
        raise SceneError("command line", "", message)

    def parse_known_args(self, args=None, namespace=None):
        ns, rest = super().parse_known_args(args, namespace)
        for a in self._actions:
            v = getattr(ns, a.dest, None) if a.option_strings else None
            if v == "" or (isinstance(v, list) and "" in v):
                self.error(f"argument {a.option_strings[-1]}: expected a value, got ''")
        return ns, rest


def _convert(text, kind, expected):
    """``kind(text)``, or the argparse error "expected <expected>, got '<text>'"."""
    try:
        return kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None


def positive_int(text):
    v = _convert(text, int, "a positive integer")
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {v}")
    return v


def nonnegative_seconds(text):
    v = _convert(text, float, "a number of seconds")
    if not (v >= 0.0 and math.isfinite(v)):
        raise argparse.ArgumentTypeError(f"must be a finite number of seconds >= 0, got {v}")
    return v


def spp_count(text):
    """Samples per pixel: a positive integer of at most MAX_SPP (as render.spp)."""
    from ..scene.schema import MAX_SPP
    v = positive_int(text)
    if v > MAX_SPP:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_SPP} samples per pixel, "
                                         f"got {v}")
    return v


def reference_spp_count(text):
    """The samples per pixel of a reference whose own noise is subtracted: an spp_count of
    at least 2, since its variance is estimated from its samples (one sample has none, and
    every error would come out NaN)."""
    v = spp_count(text)
    if v < 2:
        raise argparse.ArgumentTypeError(f"must be at least 2 (the reference's own noise is "
                                         f"estimated from its samples), got {v}")
    return v


WORKERS_PER_CPU = 4


def local_workers(text):
    """--workers: a positive integer of at most WORKERS_PER_CPU per CPU of this machine.
    Each worker is a process holding the scene and its own compiled kernels, and more of
    them than the CPUs only share those CPUs, so a larger count is a typing error (an
    unbounded one would start processes until memory ran out)."""
    v = positive_int(text)
    cpus = os.cpu_count() or 1
    if v > WORKERS_PER_CPU * cpus:
        raise argparse.ArgumentTypeError(
            f"{v} worker processes on a machine with {cpus} CPUs: at most "
            f"{WORKERS_PER_CPU * cpus} ({WORKERS_PER_CPU} per CPU); for more, start a "
            "cluster and pass --scheduler")
    return v


def seed(text):
    v = _convert(text, int, "an integer in [0, 2^64)")
    if not 0 <= v < 2**64:
        raise argparse.ArgumentTypeError(f"must be in [0, 2^64), got {v}")
    return v


def finite_float(text):
    v = _convert(text, float, "a number")
    if v != v or v in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return v


def exposure(text):
    from ..film import MAX_EXPOSURE
    v = finite_float(text)
    if abs(v) > MAX_EXPOSURE:
        raise argparse.ArgumentTypeError(f"must be in [-{MAX_EXPOSURE:g}, {MAX_EXPOSURE:g}] "
                                         f"stops, got {text!r}")
    return v


def lanes(text):
    from ..cl.lanes import check_lanes
    return check_lanes(text)


def add_scene_argument(parser):
    """The optional scene positional of render, check, peer and bench render."""
    parser.add_argument("scene", nargs="?", help=SCENE_HELP)


def add_device_option(parser, help="OpenCL device (as for render)"):
    parser.add_argument("--device", help=help)


def add_defines_option(parser, help="override a scene key (repeatable)"):
    parser.add_argument("-D", dest="defines", action="append", default=[],
                        metavar="SECTION.KEY=VALUE", help=help)


def scheduler_address(text):
    """A --scheduler address that may name a scheduler (volmc.distributed.address_problem):
    a bad port or host is the one-line error before anything runs."""
    from ..distributed import address_problem
    why = address_problem(text)
    if why:
        raise argparse.ArgumentTypeError(why)
    return text


def add_cluster_options(parser, what):
    """--workers N | --scheduler ADDRESS (rendering on Dask; see dask_session)."""
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=local_workers, metavar="N",
                       help=f"{what} on a new local Dask cluster of N worker processes "
                            "(needs volmc[dask])")
    where.add_argument("--scheduler", metavar="ADDRESS", type=scheduler_address,
                       help=f"{what} on the running Dask scheduler at ADDRESS, e.g. "
                            "tcp://10.0.0.1:8786 (its workers need volmc installed)")


def add_lanes_option(parser):
    parser.add_argument("--lanes", type=lanes, metavar="W",
                        help="OpenCL paths per work-item, 1, 4, 8 or 16 (default: $VOLMC_LANES, "
                             "else the device's preferred float vector width)")


def add_ladder_arguments(p, repeats, levels="4,16,64", reference_spp=1024):
    """--spp-levels, --reference-spp and --repeats of the speed-against-error benchmarks."""
    p.add_argument("--spp-levels", default=levels,
                   help=f"comma-separated samples per pixel of the timed renders (default "
                        f"{levels})")
    p.add_argument("--reference-spp", type=reference_spp_count, default=reference_spp,
                   help=f"samples per pixel of the reference, at least 2 (default "
                        f"{reference_spp})")
    p.add_argument("--repeats", type=positive_int, default=repeats,
                   help=f"passes over the spp ladder (default {repeats})")


def scene_path(args):
    """The scene positional's path, the bundled cloud scene when none is given."""
    from ..resources import default_scene
    return str(default_scene()) if args.scene is None else args.scene


def check_outputs(outputs, inputs=()):
    """Raise SceneError unless every output is writable (check_writable), none is one of the
    ``inputs`` (the scene files: the output would overwrite it) and no two outputs are one
    file (the later would overwrite the earlier). outputs: flag -> a path, a list of paths
    (a folder's files) or None (not written)."""
    ins = {os.path.realpath(p): p for p in inputs}
    seen = {}
    for flag, paths in outputs.items():
        for path in [] if paths is None else [paths] if isinstance(paths, str) else paths:
            check_writable(path, flag)
            real = os.path.realpath(path)
            if real in ins:
                raise SceneError("command line", flag, f"{path} is the scene file "
                                                       f"{ins[real]}: name another file")
            if real in seen:
                raise SceneError("command line", flag, f"{path} is also the file of "
                                                       f"{seen[real]}: name another file")
            seen[real] = flag


def check_figure_path(path, flag):
    """Raise SceneError unless ``path`` is writable and names a format matplotlib writes
    (by its suffix), so that a figure cannot fail after the benchmark has run."""
    check_writable(path, flag)
    from matplotlib.backend_bases import FigureCanvasBase
    formats = FigureCanvasBase.get_supported_filetypes()
    suffix = os.path.splitext(path)[1].lstrip(".").lower()
    if suffix not in formats:
        raise SceneError("command line", flag, f"expected a figure path ending in one of "
                         f"{', '.join('.' + f for f in sorted(formats))}, got {path!r}")


def check_opencl_choices(device, lanes=None):
    """A bad --device, lane width, $VOLMC_LANES or $VOLMC_GATHERS is the one-line error now,
    before a command prints anything."""
    from ..cl.device import select_device
    from ..cl.lanes import resolve_gathers, resolve_lanes
    dev = select_device(device)
    resolve_lanes(lanes, dev)
    resolve_gathers(dev)


def check_directory(path, flag):
    """Raise SceneError unless ``path`` is an existing directory where files can be
    written (the output folders of benchmarks and peers)."""
    from ..outputs import check_directory_writable
    if not os.path.isdir(path):
        raise SceneError("command line", flag, f"not a directory: {path}")
    check_directory_writable(path, flag)


def comma_list(text, flag, allowed):
    """The items of a comma-separated flag value, each one of ``allowed``, none twice (a
    configuration named twice would be measured twice, as two rows of one name)."""
    items = [x.strip() for x in text.split(",") if x.strip()]
    bad = [x for x in items if x not in allowed]
    if not items or bad:
        raise SceneError("command line", flag, f"expected a comma-separated list of "
                                               f"{', '.join(allowed)}, got {text!r}")
    twice = [x for i, x in enumerate(items) if x in items[:i]]
    if twice:
        raise SceneError("command line", flag, f"{twice[0]!r} is named twice in {text!r}")
    return items


def spp_levels(text):
    """The ``--spp-levels`` list: positive integers separated by commas."""
    from ..scene.schema import MAX_SPP
    levels = []
    for x in text.split(","):
        if not (x.strip().isascii() and x.strip().isdigit()) or not 1 <= int(x) <= MAX_SPP:
            raise SceneError("command line", "--spp-levels",
                             f"expected integers from 1 to {MAX_SPP} separated by commas, "
                             f"got {text!r}")
        levels.append(int(x))
    return levels


@contextlib.contextmanager
def dask_session(args):
    """The Dask client of --workers or --scheduler (None without either), closed with the
    local cluster it started on leaving; a one-line error without Dask or when the scheduler
    cannot be reached (distributed.connect)."""
    if not (args.workers or args.scheduler):
        yield None
        return
    from ..distributed import close, connect, quiet_logs
    client, cluster = connect(args.workers, args.scheduler, "command line",
                              "--workers" if args.workers else "--scheduler")
    # Dask's own logs in this process (the client's lost connection, the local nannies'
    # restarted workers) are tracebacks on the user's terminal; a cluster that fails is the
    # one-line error (distributed.ClusterError), a worker that dies is retried quietly.
    try:
        with quiet_logs():
            yield client
    finally:
        close(client, cluster)
