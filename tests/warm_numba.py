"""Background job (tests/background.py): compile the Numba reference's render path into
Numba's on-disk cache, for one medium or for several.

The reference compiles its render path once for one medium and once for two to four media
(volmc.reference.medium.media_data pads several media to four slots), 3 to 5 minutes each
on CI's two cores, single-threaded. These jobs compile them from the session's start on the
core the tests leave idle, by rendering a shipped scene at 2x2 pixels and 1 spp: the default
cloud for one medium, the placed media of gallery/islands.toml for several. The test process
then loads the code from the cache: Numba keys a cache entry by the function's source and
argument types, and the render path's argument types depend only on the count of media
slots (every array is float64 or int32 of a fixed rank), so what is loaded is what the test
would have compiled. Writes {"scene": ..., "media": ...}.

Run as ``python tests/warm_numba.py OUT.json one|several``.
"""

import json
import os
import sys

from volmc.render import render
from volmc.resources import scenes_dir
from volmc.scene import load_scene

SCENES = {"one": "cloud.toml", "several": "gallery/islands.toml"}


def main(out, which):
    name = SCENES[which]
    scene = load_scene(scenes_dir() / name, ["camera.resolution=[2, 2]", "render.spp=1"])
    assert (len(scene.media) > 1) == (which == "several"), name
    render(scene, backend="numba", progress=False)
    with open(out + ".part", "w") as f:
        json.dump({"scene": name, "media": len(scene.media)}, f)
    os.replace(out + ".part", out)


if __name__ == "__main__":
    main(*sys.argv[1:3])
