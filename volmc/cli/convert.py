"""``volmc convert``: a density grid from one of .npy, .npz and .vol to another."""

import sys

import numpy as np

from ..scene.errors import SceneError
from ..scene.schema import FLOAT32_MAX
from .common import check_writable, finite_float


def add_convert_parser(sub):
    c = sub.add_parser("convert", help="convert a density grid between .npy, .npz and .vol")
    c.add_argument("input")
    c.add_argument("output")
    c.add_argument("--bounds", type=finite_float, nargs=6,
                   metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
                   help="bounding box written into .vol headers (default: the input .vol's "
                        "box, else the unit cube)")
    return c


def cmd_convert(args):
    from ..scene.grids import load_grid, read_vol, save_grid
    if args.input.lower().endswith((".vdb", ".nvdb")):
        raise SceneError(args.input, "input", "convert reads .npy, .npz and .vol grids; a "
                         "VDB grid renders as it is (medium.density = { file = ..., grid = "
                         "... })")
    bounds = ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    if args.bounds is not None:
        b = args.bounds
        bounds = (tuple(b[:3]), tuple(b[3:]))
        # A .vol header holds float32: the box must be one there, and not empty there (a
        # box of width 1e-8 at 1, or 1e-46, was empty once rounded).
        if not all(abs(v) <= FLOAT32_MAX for v in b) or not all(
                np.float32(lo) < np.float32(hi) for lo, hi in zip(b[:3], b[3:])):
            raise SceneError("command line", "--bounds", f"expected XMIN YMIN ZMIN < XMAX "
                             f"YMAX ZMAX within float32's range, got {' '.join(map(str, b))}")
    check_writable(args.output, "output")
    grid = load_grid(args.input, "input")
    if args.bounds is None and args.input.lower().endswith(".vol"):
        bb = read_vol(args.input)[1]
        bounds = (tuple(bb[:3]), tuple(bb[3:]))
    save_grid(args.output, grid, bounds)
    nz, ny, nx = grid.shape
    print(f"volmc: wrote {args.output} ({nx}x{ny}x{nz} [x, y, z])", file=sys.stderr)
    return 0
