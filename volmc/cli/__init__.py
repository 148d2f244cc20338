"""Command line: ``volmc render``, ``check``, ``peer``, ``bench``, ``convert``, ``info``.

Bad input (scene files, grids, flag values) prints one line
``volmc: error: <file>: <key>: <what is wrong>`` and exits with status 2, no traceback.
Ctrl-C during a render writes what was accumulated (marked partial) and exits 130.

Each command's module holds its parser builder ``add_<command>_parser(subparsers)`` beside
its handler ``cmd_<command>(args)``; ``COMMANDS`` (and ``bench.BENCHES`` for the benchmarks)
maps the names to them.
"""

import sys

from ..scene.errors import SceneError
from .bench import add_bench_parser, cmd_bench
from .check import add_check_parser, cmd_check
from .common import EXIT_BAD_INPUT, EXIT_INTERRUPTED, Parser
from .convert import add_convert_parser, cmd_convert
from .info import add_info_parser, cmd_info
from .peer import add_peer_parser, cmd_peer
from .render import add_render_parser, cmd_render

#: ``volmc`` COMMAND -> (parser builder, handler), in the order ``--help`` lists them.
COMMANDS = {
    "render": (add_render_parser, cmd_render),
    "check": (add_check_parser, cmd_check),
    "info": (add_info_parser, cmd_info),
    "peer": (add_peer_parser, cmd_peer),
    "bench": (add_bench_parser, cmd_bench),
    "convert": (add_convert_parser, cmd_convert),
}


def build_parser():
    p = Parser(prog="volmc", description="Monte Carlo volume path tracer")
    sub = p.add_subparsers(dest="command", required=True, parser_class=Parser)
    for add, _ in COMMANDS.values():
        add(sub)
    return p


def main(argv=None):
    """Entry point of the ``volmc`` console script; returns the exit status."""
    try:
        args = build_parser().parse_args(argv)
        return COMMANDS[args.command][1](args)
    except SceneError as e:
        print(f"volmc: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("volmc: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
