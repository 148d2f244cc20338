"""How tests run the command line in a subprocess: with the volmc this test process imported
(in CI the installed package, not the source tree beside the tests), so that the subprocess
shares its Numba cache. A second copy of the sources is a second Numba cache (keyed on the
files' paths), and compiling the reference integrator again cost CI about three minutes per
test that renders with it. ``-P`` keeps Python from putting the working directory, which may
be the source tree, ahead of that package on sys.path."""

import os
import sys

import volmc


def volmc_cli(*args):
    """The argument list that runs ``volmc ARGS...``."""
    return [sys.executable, "-P", "-m", "volmc.cli", *args]


def volmc_env():
    """The environment for it: os.environ with the imported package's directory first on
    PYTHONPATH."""
    env = dict(os.environ)
    root = os.path.dirname(os.path.dirname(os.path.abspath(volmc.__file__)))
    env["PYTHONPATH"] = os.pathsep.join([root, env.get("PYTHONPATH", "")])
    return env
