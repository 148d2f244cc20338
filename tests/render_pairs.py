"""Renders of the default cloud with two shadow-ray estimators, compared statistically."""

from volmc.resources import default_scene
from volmc.scene import load_scene

#: A small, quick version of the cloud: 32^3 grid, 8x8 pixels, 64 spp, 4 bounces.
SMALL_CLOUD = ["medium.density.resolution=32", "camera.resolution=[8, 8]", "render.spp=64",
               "render.max_depth=4"]


def assert_estimators_render_alike(backend, name, other="ratio", extra=()):
    """Renders the small cloud with render.transmittance = ``name`` and, with another seed,
    ``other``; asserts the per-pixel and image-mean two-sample z-tests pass (family level
    ALPHA, volmc.check.compare_images) and that no walk was capped."""
    from volmc.check import compare_images
    from volmc.render import render
    keys = SMALL_CLOUD + list(extra)
    a = render(load_scene(default_scene(), keys + [f"render.transmittance={name}"]),
               progress=False, backend=backend)
    b = render(load_scene(default_scene(), keys + [f"render.transmittance={other}",
                                                   "render.seed=11"]),
               progress=False, backend=backend)
    c = compare_images(a.image, a.film.variance_of_mean(), b.image, b.film.variance_of_mean())
    assert c.passed, c.summary()
    assert a.counters["capped"] == 0
