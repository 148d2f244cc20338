"""Slow, self-contained checks started in the background when the session begins.

Most of the suite runs on one core (Numba compiling the reference, Python, the CLI's
subprocesses), so on CI's two cores the other one is often idle. A job started here runs
in a subprocess at a low CPU priority (nice 15 to 19), so it takes little more than the
time the tests leave, and writes its result as JSON; the test that needs it collects it
with ``result``, waiting if it is not done. A job that is not started (its test is not
selected), fails or writes nothing gives ``None``, and the test then does the work itself:
the background changes when the work is done, never what is checked.

Jobs are scripts beside this file, run as ``python SCRIPT OUT.json [ARGS...]``.
"""

import json
import os
import shutil
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

_JOBS = {}
_DONE = {}


def start(name, script, nice=19, args=()):
    """Run ``python SCRIPT OUT.json ARGS...`` in the background as job ``name`` (once per session),
    at CPU priority ``nice`` (19 the lowest; a lower one is served first among the jobs);
    a relative SCRIPT is beside this file."""
    if name in _JOBS:
        return
    script = Path(__file__).parent / script
    folder = Path(tempfile.mkdtemp(prefix=f"volmc_background_{name}_"))
    out = folder / "result.json"
    log = open(folder / "log.txt", "w")
    proc = subprocess.Popen([sys.executable, str(script), str(out), *args],
                            stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                            preexec_fn=lambda: os.nice(nice))
    log.close()
    _JOBS[name] = (proc, out)


def result(name, timeout=3600.0):
    """The JSON result of job ``name`` (waiting for it), or None when it was not started,
    failed or did not finish in ``timeout`` seconds (then it is stopped)."""
    if name not in _DONE:
        _DONE[name] = _collect(name, timeout)
    return _DONE[name]


def _collect(name, timeout):
    job = _JOBS.pop(name, None)
    if job is None:
        return None
    proc, out = job
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        shutil.rmtree(out.parent, ignore_errors=True)
        return None
    if proc.returncode != 0 or not out.exists():
        warnings.warn(f"background job {name} failed (exit {proc.returncode}; its log: "
                      f"{out.with_name('log.txt')}); the test does the work itself")
        return None
    text = out.read_text()
    shutil.rmtree(out.parent, ignore_errors=True)
    return json.loads(text)


def stop_all():
    """Stop the jobs nobody collected (a session that ends early)."""
    for proc, out in _JOBS.values():
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        shutil.rmtree(out.parent, ignore_errors=True)
    _JOBS.clear()
