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
    """Compiler options ``-DFEATURE_X`` for a feature set, in a stable order."""
    return [f"-DFEATURE_{name}" for name in sorted(feature_set)]
