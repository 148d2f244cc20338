"""Whether the camera sees the medium at all: a scene whose camera rays all miss the medium
box renders only the background, which is rarely what its author meant, so ``volmc render``
warns (not an error: a background plate is a legitimate render)."""

import numpy as np
from numba import njit

from .reference.camera import camera_ray
from .reference.integrator import enter_medium

#: Film positions per axis at which camera rays are traced (corners and edges included),
#: each through five lens points (the centre and four on the rim) when there is a lens.
FILM_SAMPLES = 65
_LENS = ((0.5, 0.5), (0.0, 0.5), (1.0, 0.5), (0.5, 0.0), (0.5, 1.0))


@njit(cache=True)
def _any_ray_enters(prm, m, n):
    for j in range(n):
        fy = prm.height * j / (n - 1)
        for i in range(n):
            fx = prm.width * i / (n - 1)
            for v1, v2 in _LENS:
                o, d = camera_ray(prm, fx, fy, 0.0, 0.0, v1, v2)
                _, t0, t1, _ = enter_medium(m, o, d)
                if t1 > t0:
                    return True
    return False


def medium_in_view(scene):
    """False when no camera ray of a FILM_SAMPLES^2 grid over the film (corners and edges
    included; through the lens's centre and rim) enters a (placed) medium box. A box
    smaller than the grid's spacing can slip between the rays: the answer is then False
    although a few pixels may see it."""
    from .pack import pack_scene
    pk = pack_scene(_boxes(scene), np.float64)
    return any(_any_ray_enters(pk.params[0], m, FILM_SAMPLES) for m in pk.medium)


def _boxes(scene):
    """``scene`` with its camera and its media's boxes and no more: constant media, no
    emission, no lights. Packing the scene itself copied every grid to float64 and built
    its majorants, the peak of a render's memory (128 MiB at 256^3), for the boxes alone."""
    from dataclasses import replace

    from .scene.loading import Scene
    from .scene.schema import ConstantDensity

    def bare(spec):
        def one(m):
            return replace(m, density=ConstantDensity(1.0), emission=None)
        return replace(spec, medium=one(spec.medium), others=tuple(map(one, spec.others)),
                       lights=())
    parts = tuple(Scene(bare(p.spec)) for p in scene.parts)
    return Scene(bare(scene.spec), parts=parts)
