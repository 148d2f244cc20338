"""The ``volmc`` console script: the command line (volmc/cli) behind a guard for the moment
before it is imported."""

import sys


def main():
    """Entry point of the ``volmc`` console script; returns the exit status. A Ctrl-C while
    Python still imports the command line (about 0.4 s: numpy, Numba) ends with the line of
    any other interrupt and its exit status, not a traceback."""
    try:
        from .cli import main as cli_main
        from .cli.common import EXIT_INTERRUPTED
    except KeyboardInterrupt:
        print("volmc: interrupted", file=sys.stderr)
        return 130   # cli.common.EXIT_INTERRUPTED, not importable yet: 128 + SIGINT
    try:
        return cli_main()
    except KeyboardInterrupt:   # between cli.main's own handler and the exit
        print("volmc: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
