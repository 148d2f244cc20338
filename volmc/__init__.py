"""volmc: Monte Carlo volume path tracing (OpenCL kernels, Numba float64 reference).

The Python API (volmc/api.py; docs/python_api.md and docs/api/volmc.md)::

    import volmc
    scene = volmc.load_scene("scene.toml", overrides={"render.spp": 16})
    img = volmc.render(scene, seed=1)          # img.image: float32 [h, w, 3]
    img.save("out.exr")

* ``load_scene(path=None, overrides=None, frame=None)``: a scene file (None: the bundled
  cloud), with overrides as a dict of dotted keys or ``-D`` strings.
* ``scene_from_dict(scene, base_dir=".", overrides=None, name="<dict>", frame=None)``: a
  scene from a dict shaped like the TOML (numpy arrays allowed as density grids) or from the
  schema dataclasses.
* ``render(scene, spp=None, seed=None, backend="opencl", device=None, progress=True,
  client=None, checkpoint=None, checkpoint_every=60.0, resume=None, lanes=None,
  albedo=False)``: a ``RenderedImage``
  with ``image``, ``variance``, ``counters``, ``seconds``, ``save(path)``; ``client`` renders
  on a Dask cluster, ``checkpoint``/``resume`` as on the command line.
* ``render_frames(scene, frames, output=None, ...)``: a scene whose grid files name the frame
  (``{frame:04d}``), rendered once per frame; with ``output`` written as
  ``<stem>.0001.exr``, ... and complete frames skipped.
* ``estimate_transmittance(scene_or_medium, origins, directions, t_max, estimator="auto",
  n=64, backend="opencl", seed=0, device=None, lanes=None)``: a ``TransmittanceResult``
  per ray.
* ``VolmcError``: raised for any bad input, with the CLI's one-line message.
* ``VolmcWarning``: issued by ``render`` when a guard fired (the image may be biased).

Importing volmc imports nothing heavy: the functions import Numba, pyopencl and the
renderer when first called.

``volmc.render`` is the function above, although ``volmc/render.py`` (the render driver) is
also a module of this package: import from the module with ``from volmc.render import ...``.
"""

import sys
import types

from .api import (RenderedImage, TransmittanceResult, estimate_transmittance, load_scene,
                  render, render_frames, scene_from_dict)

__all__ = ["load_scene", "scene_from_dict", "render", "render_frames", "estimate_transmittance",
           "VolmcError", "VolmcWarning", "RenderedImage", "TransmittanceResult"]


def __getattr__(name):
    if name in ("VolmcError", "VolmcWarning"):   # volmc/scene/errors.py, imported on use
        from .scene import errors
        return getattr(errors, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class _Package(types.ModuleType):
    """The volmc package, which keeps ``volmc.render`` the API function: importing the
    submodule volmc.render (the render driver) would otherwise rebind the package attribute
    to the module. The module stays reachable as ``sys.modules["volmc.render"]``."""

    def __setattr__(self, name, value):
        if name in __all__ and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
