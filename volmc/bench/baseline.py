"""An earlier volmc as a configuration of ``volmc bench render`` (``--baseline DIR``).

DIR is a checkout of volmc (for example a git worktree of an earlier commit). A worker process
imports the volmc found there, builds its OpenCL backend for the same scene file and ``-D``
overrides, and renders on request, so a change can be measured as speed against error in
the same run, alternating with the current code on the same machine. The worker uses only the
interface every volmc version has had: ``volmc.scene.load_scene``, ``volmc.render``'s
``make_backend`` and ``batch_schedule``, ``volmc.film.Film`` and ``backend.render(start, n,
film)``.
"""

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from ..scene.errors import SceneError

_WORKER = r"""
import json, sys, time
sys.path.insert(0, sys.argv[1])
import numpy as np
from volmc.film import Film
from volmc.render import batch_schedule, make_backend
from volmc.scene import load_scene
scene = load_scene(sys.argv[2], json.loads(sys.argv[3]))
be = make_backend("opencl", scene, None)
be.warm_up()
w, h = scene.camera.resolution
state = {"next": 0}
def render(spp):
    film = Film(w, h)
    t = time.perf_counter()
    for n in batch_schedule(w * h, spp):
        be.render(state["next"] + film.spp, n, film)
        film.spp += n
    sec = time.perf_counter() - t
    state["next"] += spp
    return film.mean(), sec
render(1)
import volmc
print("ready " + volmc.__file__, flush=True)
for line in sys.stdin:
    spp, out = line.split()
    mean, sec = render(int(spp))
    np.save(out, mean)
    print(sec, flush=True)
"""


def check_checkout(path):
    """``path`` resolved, or the one-line SceneError when it holds no volmc checkout (checked
    before a benchmark starts, not when its first baseline render is due)."""
    path = Path(path).resolve()
    if not (path / "volmc" / "__init__.py").is_file():
        raise SceneError("command line", "--baseline", f"{path} is not a volmc checkout "
                         "(no volmc/__init__.py)")
    # Where the checkout's volmc looks for its kernels (resources._package_dir).
    if not ((path / "volmc" / "kernels").is_dir() or
            ((path / "kernels").is_dir() and (path / "pyproject.toml").is_file())):
        raise SceneError("command line", "--baseline", f"{path} is not a volmc checkout "
                         "(no kernels/ beside a pyproject.toml, nor volmc/kernels/)")
    return path


class BaselineRunner:
    """Renders with the volmc checkout at ``path`` in a worker process (OpenCL backend)."""

    def __init__(self, path, scene_file, defines=()):
        path = check_checkout(path)
        self.tmp = tempfile.TemporaryDirectory(prefix="volmc-baseline-")
        # The worker runs in the temporary directory, so it gets the scene's absolute path;
        # its stderr goes to a file, whose last line says why it could not start.
        log = Path(self.tmp.name) / "worker.log"
        with open(log, "w") as err:
            self.proc = subprocess.Popen(
                [sys.executable, "-c", _WORKER, str(path), str(Path(scene_file).resolve()),
                 json.dumps(list(defines))],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=err, text=True,
                cwd=self.tmp.name)
        line = self.proc.stdout.readline()
        if not line.startswith("ready"):
            try:
                self.proc.wait(timeout=60)
            except subprocess.TimeoutExpired:   # it printed something else and goes on
                self.proc.kill()
                self.proc.wait()
            lines = log.read_text(errors="replace").strip().splitlines()
            self.tmp.cleanup()
            why = f" ({lines[-1].strip()})" if lines else ""
            raise SceneError("command line", "--baseline",
                             f"the volmc at {path} could not render the scene{why}")
        self.module = line.split(maxsplit=1)[1].strip()
        self.n = 0

    def render(self, spp):
        """(mean image, seconds, None) of ``spp`` fresh samples per pixel."""
        self.n += 1
        out = Path(self.tmp.name) / f"img{self.n}.npy"
        self.proc.stdin.write(f"{int(spp)} {out}\n")
        self.proc.stdin.flush()
        sec = float(self.proc.stdout.readline())
        return np.load(out), sec, None

    def close(self):
        if self.proc.poll() is None:
            self.proc.stdin.close()
            self.proc.wait(timeout=60)
        self.tmp.cleanup()
