"""Benchmarks: named configurations that print their cost (and, later, error) side by side."""


def report_main(make_report, print_report, json_path=None):
    """The end of a benchmark's command line: build the report (``make_report()``), print it
    with the wall time, and write it as JSON to ``json_path`` if given."""
    import json
    import time
    t = time.perf_counter()
    report = make_report()
    print_report(report)
    print(f"\n{time.perf_counter() - t:.0f} s")
    if json_path:
        with open(json_path, "w") as f:
            json.dump(report, f, indent=1)
