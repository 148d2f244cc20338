"""Feature detection: what a scene needs compiled into the kernels ("model only what a
scene needs"). The reference decides the same things at run time from the parameters."""

from .schema import ConstantDensity, DirectionalLight, EnvironmentLight, PointLight

#: Every feature flag, with the condition that turns it on.
FEATURES = {
    "GRID": "density comes from a grid (else homogeneous: analytic tracking)",
    "MAJORANT_GRID": "per-cell majorants with a 3-D DDA walk (render.majorant = \"grid\")",
    "PHASE_HG": "Henyey-Greenstein phase function (else isotropic)",
    "ENV": "an environment light",
    "DELTA_LIGHTS": "at least one directional or point light",
    "POINT": "at least one point light",
    "RR": "Russian roulette can trigger (max_depth = -1 or rr_depth <= max_depth)",
    "ORTHO": "orthographic camera (else perspective)",
    "SCATTER": "scattering can reach the image (some albedo > 0 and max_depth != 0)",
}
#: Code paths no scene takes, off in every render build and on in the test and benchmark
#: kernels (which build with the defaults of features.h).
TEST_FEATURES = {
    "PROFILES": "1-D test profiles as density sources (tests and the estimator benchmark)",
}


#: Per-scene constants a build can compile in instead of reading them from the records at run
#: time ("baking"): the kernels read each through the macro BAKE_X(run-time value), which a
#: baked build defines as the scene's constant (volmc/cl/specialise.py).
BAKES = {
    "GRID_DIMS": "voxels of the density grid (nx, ny, nz)",
    "MAJ_RES": "cells of the majorant grid (cz, cy, cx)",
    "N_LIGHTS": "number of directional and point lights",
    "PHASE_KIND": "phase function (isotropic or Henyey-Greenstein)",
    "PHASE_G": "Henyey-Greenstein asymmetry g",
    "ALBEDO": "single-scattering albedo",
}


def features(scene) -> frozenset:
    """The set of feature names (keys of FEATURES) a loaded Scene needs."""
    m, r = scene.medium, scene.render
    out = set()
    if not isinstance(m.density, ConstantDensity):
        out.add("GRID")
        if r.majorant == "grid":
            out.add("MAJORANT_GRID")
    if m.phase.type == "hg":
        out.add("PHASE_HG")
    if any(isinstance(lt, EnvironmentLight) for lt in scene.lights):
        out.add("ENV")
    if any(isinstance(lt, (DirectionalLight, PointLight)) for lt in scene.lights):
        out.add("DELTA_LIGHTS")
    if any(isinstance(lt, PointLight) for lt in scene.lights):
        out.add("POINT")
    if r.max_depth < 0 or r.rr_depth <= r.max_depth:
        out.add("RR")
    if scene.camera.type == "orthographic":
        out.add("ORTHO")
    if max(m.albedo) > 0.0 and r.max_depth != 0:
        out.add("SCATTER")
    return frozenset(out)


def define_flags(feature_set) -> list:
    """Compiler options ``-DFEATURE_X=1`` for the features in the set and ``=0`` for the
    others, in a stable order (a kernel built without options has every feature on)."""
    return [f"-DFEATURE_{name}={int(name in feature_set)}"
            for name in sorted(FEATURES) + sorted(TEST_FEATURES)]


def features_header() -> str:
    """Text of the generated ``features.h``: every FEATURE_X defaults to 1 (compiled in)
    unless the build defines it, so kernels test plain constants and need no #ifdef; every
    BAKE_X(v) defaults to the run-time value v."""
    out = ["/* Generated from volmc/scene/features.py: do not edit. */",
           "#ifndef VOLMC_FEATURES_H", "#define VOLMC_FEATURES_H"]
    for name, meaning in {**FEATURES, **TEST_FEATURES}.items():
        out += [f"/* {meaning} */", f"#ifndef FEATURE_{name}", f"#define FEATURE_{name} 1",
                "#endif"]
    for name, meaning in BAKES.items():
        out += [f"/* {meaning}: read at run time unless the build bakes it in */",
                f"#ifndef BAKE_{name}", f"#define BAKE_{name}(runtime) (runtime)", "#endif"]
    return "\n".join(out + ["#endif", ""])
