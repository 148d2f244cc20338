"""The transmittance-estimator registry, written once and read by everything else.

Each ``Estimator`` record names a technique and the function that implements it. Twins
share their names, so ``function`` is both the Numba function in ``volmc.reference`` and the
OpenCL function in ``kernels/``. The scene schema takes ``render.transmittance`` values from
``ESTIMATORS``, the backends build or dispatch the chosen function, and the benchmarks and
tests iterate over the records. Adding an estimator means one record here and its twins.

The module imports nothing heavy (Numba only when ``Estimator.reference`` is first read), so
the scene layer can read it.
"""

from dataclasses import dataclass

from . import constants as C


@dataclass(frozen=True)
class Estimator:
    """One transmittance estimator.

    name: the value of ``render.transmittance`` and of ``--estimators``;
    id: its ESTIMATOR_* constant, on which the reference dispatches
    (``reference.estimators.transmittance``);
    function: the twins' name, ``transmittance_<...>(med, o, d, t0, t1, rng, counters,
    max_steps)`` in both backends;
    unbiased: E[estimate] = T exactly; signed: single estimates can be negative (a render
    keeps negative samples when it is chosen); homogeneous_only: exact only where the
    extinction is constant, so it is no choice for grids; chromatic: estimates RGB
    transmittance (colour-dependent extinction); build_options: extra kernel build
    options the function needs; summary: one line for help texts and tables;
    shadow_function, shadow_id: the twins a render runs instead on the shadow rays of
    scattering paths, where the transmittance is one factor of a noisy path; view_function,
    view_id: those it runs on the camera rays of a scene that cannot scatter, where the
    transmittance is the sample but a pixel's rays still differ. Only "auto" has them (by
    default both are function and id): ``function`` is then its choice for a transmittance
    on a fixed ray, where the estimate's own variance is all the error.
    """
    name: str
    id: int
    function: str
    unbiased: bool
    signed: bool = False
    homogeneous_only: bool = False
    chromatic: bool = False
    build_options: tuple = ()
    summary: str = ""
    shadow_function: str = ""
    shadow_id: int = -1
    view_function: str = ""
    view_id: int = -1
    #: whether a render's samples can be negative (None: ``signed``; "auto" renders with
    #: tracking estimators, which never are)
    render_signed: bool = None
    #: the TRACK_* technique of ``function`` and of ``shadow_function`` where they are
    #: techniques of the one tracking loop (-1: a per-segment estimator): the render kernel
    #: walks such shadow rays in the same loop as its free flights (SHADOW_TECHNIQUE)
    track: int = -1
    shadow_track: int = -1

    @property
    def shadow_technique(self):
        """The TRACK_* technique of the shadow rays of scattering paths, or -1."""
        return self.shadow_track if self.shadow_function else self.track

    @property
    def signed_in_renders(self):
        """True if a render with this estimator can produce negative samples."""
        return self.signed if self.render_signed is None else self.render_signed

    @property
    def shadow_kernel(self):
        """The OpenCL function of shadow rays in scattering paths."""
        return self.shadow_function or self.function

    @property
    def shadow_estimator_id(self):
        """The ESTIMATOR_* id of shadow rays in scattering paths."""
        return self.shadow_id if self.shadow_id >= 0 else self.id

    @property
    def view_kernel(self):
        """The OpenCL function of camera rays in scenes that cannot scatter."""
        return self.view_function or self.function

    @property
    def view_estimator_id(self):
        """The ESTIMATOR_* id of camera rays in scenes that cannot scatter."""
        return self.view_id if self.view_id >= 0 else self.id

    @property
    def reference(self):
        """The Numba function (imported on first use)."""
        from .reference import estimators
        return getattr(estimators, self.function)

    @property
    def kernel(self):
        """The OpenCL function's name."""
        return self.function


_RECORDS = (
    Estimator("analytic", C.ESTIMATOR_ANALYTIC, "transmittance_analytic", True,
              homogeneous_only=True, chromatic=True,
              summary="exp(-sigma L) per majorant segment: exact on homogeneous segments only"),
    Estimator("track_length", C.ESTIMATOR_TRACK_LENGTH, "transmittance_track_length", True,
              chromatic=True, track=C.TRACK_LENGTH,
              summary="delta tracking: 1 if the walk escapes, 0 at the first real collision"),
    Estimator("ratio", C.ESTIMATOR_RATIO, "transmittance_ratio_tracking", True,
              chromatic=True, track=C.TRACK_RATIO,
              summary="ratio tracking: product of (1 - mu / sigma_maj) over tentative collisions"),
    Estimator("residual_ratio", C.ESTIMATOR_RESIDUAL_RATIO, "transmittance_residual_ratio", True,
              chromatic=True, track=C.TRACK_RESIDUAL_RATIO,
              summary="residual ratio tracking with each segment's minorant as control"),
    Estimator("next_flight", C.ESTIMATOR_NEXT_FLIGHT, "transmittance_next_flight", True,
              chromatic=True, track=C.TRACK_NEXT_FLIGHT,
              summary="next-flight ratio tracking: every vertex adds the chance to escape"),
    Estimator("biased_raymarch", C.ESTIMATOR_BIASED_RAYMARCH, "transmittance_biased_raymarch",
              False, chromatic=True,
              summary="jittered ray marching, exp(-tau estimate): biased (Jensen)"),
    Estimator("power_series", C.ESTIMATOR_POWER_SERIES, "transmittance_power_series", True,
              build_options=("-DVOLMC_POWER_SERIES",),
              summary="p-series CMF power series (Georgiev et al. 2019)"),
    Estimator("unbiased_raymarch", C.ESTIMATOR_UNBIASED_RAYMARCH,
              "transmittance_unbiased_raymarch", True, signed=True,
              build_options=("-DVOLMC_POWER_SERIES",),
              summary="unbiased ray marching (Kettunen et al. 2021)"),
    Estimator("telescoping", C.ESTIMATOR_TELESCOPING, "transmittance_telescoping", True,
              signed=True, chromatic=True, build_options=("-DVOLMC_DEBIASING",),
              summary="telescoping sum over nested jittered ray marching (Misso et al. 2022)"),
    Estimator("jackknife", C.ESTIMATOR_JACKKNIFE, "transmittance_jackknife", False,
              signed=True, chromatic=True, build_options=("-DVOLMC_DEBIASING",),
              summary="jackknife-corrected ray marching over two combs: biased, second order"),
    Estimator("auto", C.ESTIMATOR_AUTO, "transmittance_auto", True, signed=True,
              chromatic=True, build_options=("-DVOLMC_POWER_SERIES", "-DVOLMC_DEBIASING"),
              summary="chosen from measurements: on shadow rays residual ratio tracking per "
                      "thin segment and track length per thick one; on camera rays that "
                      "cannot scatter residual ratio tracking; on a fixed ray unbiased ray "
                      "marching (grey) or telescoping (colour)",
              shadow_function="transmittance_auto_shadow", shadow_id=C.ESTIMATOR_AUTO_SHADOW,
              shadow_track=C.TRACK_AUTO,
              view_function="transmittance_residual_ratio",
              view_id=C.ESTIMATOR_RESIDUAL_RATIO, render_signed=False),
)

#: name -> Estimator, in registry order.
ESTIMATORS = {e.name: e for e in _RECORDS}
assert len({e.id for e in _RECORDS}) == len(_RECORDS), "estimator ids are unique"


def chromatic_estimators():
    """Names usable for shadow rays in colour-dependent media."""
    return tuple(n for n, e in ESTIMATORS.items() if e.chromatic and not e.homogeneous_only)


def grid_estimators():
    """Names usable for shadow rays in grids (``render.transmittance``)."""
    return tuple(n for n, e in ESTIMATORS.items() if not e.homogeneous_only)
