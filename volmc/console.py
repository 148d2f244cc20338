"""The ``volmc`` console script: the command line (volmc/cli) behind a guard for the moment
before it is imported."""

import os
import sys

#: 128 + SIGPIPE, the status of a program the signal ended
EXIT_BROKEN_PIPE = 141


def main():
    """Entry point of the ``volmc`` console script; returns the exit status. A Ctrl-C while
    Python still imports the command line (about 0.4 s: numpy, Numba) ends with the line of
    any other interrupt and its exit status, not a traceback. Output cut short by a closed
    pipe ends quietly with status 141."""
    try:
        from .cli import main as cli_main
        from .cli.common import EXIT_INTERRUPTED
    except KeyboardInterrupt:
        print("volmc: interrupted", file=sys.stderr)
        return 130   # cli.common.EXIT_INTERRUPTED, not importable yet: 128 + SIGINT
    try:
        status = cli_main()
        sys.stdout.flush()   # a closed pipe shows here, not in the interpreter's last flush
        return status
    except KeyboardInterrupt:   # between cli.main's own handler and the exit
        print("volmc: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:   # `volmc info | head`: the reader left; end as a C tool would
        # (the interpreter's last flush of stdout must not raise again)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
