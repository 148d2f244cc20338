"""Benchmarks: named configurations that print their cost (and, later, error) side by side."""


def report_main(make_report, print_report, json_path=None):
    """The end of a benchmark's command line: build the report (``make_report()``), print it
    with the wall time, and write it as JSON to ``json_path`` if given. Bad input (a
    VolmcError: a scene, a grid, a map) is the one-line error with exit status 2."""
    import sys
    import time
    from ..scene.errors import VolmcError
    t = time.perf_counter()
    try:
        report = make_report()
    except VolmcError as e:   # bad input: the one-line error and status 2, as the CLI's
        print(f"volmc: error: {e}", file=sys.stderr)
        raise SystemExit(2)
    print_report(report)
    print(f"\n{time.perf_counter() - t:.0f} s")
    if json_path:
        from ..outputs import write_json
        write_json(json_path, report, indent=1)
