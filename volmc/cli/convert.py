"""``volmc convert``: a density grid from one of .npy, .npz and .vol to another."""

import sys

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
    grid = load_grid(args.input, "input")
    bounds = ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    if args.bounds is not None:
        b = args.bounds
        bounds = (tuple(b[:3]), tuple(b[3:]))
    elif args.input.lower().endswith(".vol"):
        bb = read_vol(args.input)[1]
        bounds = (tuple(bb[:3]), tuple(bb[3:]))
    check_writable(args.output, "output")
    save_grid(args.output, grid, bounds)
    nz, ny, nx = grid.shape
    print(f"volmc: wrote {args.output} ({nx}x{ny}x{nz} [x, y, z])", file=sys.stderr)
    return 0
