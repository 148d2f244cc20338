"""Feature switches: what a scene needs compiled into the render kernel ("model only what a
scene needs"). The reference decides the same things at run time from the records.

A switch stays only while `volmc bench specialise` shows it pays at least 3 % on some
shipped scene (docs/performance.md, "Specialisation"): of the nine switches and six baked
constants measured for issue 10, only MAJORANT_GRID did. MAJORANT_OCTREE (issue 13) pays 1.15x on the
homogeneous scene and 1.12x on the roulette scene, whose loops would otherwise carry the
octree walk (docs/bench_specialise.json). CHROMATIC and EMISSION measured neutral
(0.98-1.015 on the cloud, homogeneous, sunset and plume scenes; issue 11,
docs/bench_specialise_issue11.json in git history, commit 351519c) but stay for what they
guarantee rather than for speed: a grey scene runs exactly the scalar arithmetic it ran
before colour existed (the same image bit for bit), and a scene without emission compiles
none of it. TRANSFORM (issue 22)
stays for the same guarantee: a medium that is not turned, mirrored or sheared runs exactly
the code it ran before placement existed. A BRICKS switch
measured neutral too and was not kept: brick lookups are one more density kind. PROFILES is not a
scene's: render builds always compile the 1-D test profiles out (3.5 % on the cloud with a
global majorant), and the test and benchmark kernels keep them.
"""

from .schema import ConstantDensity

#: Every feature switch, with the condition that turns it on.
FEATURES = {
    "MAJORANT_GRID": "per-cell majorants along a 3-D DDA walk (a grid with "
                     "render.majorant = \"grid\")",
    "MAJORANT_OCTREE": "per-leaf majorants along an octree walk (a grid with "
                       "render.majorant = \"octree\")",
    "CHROMATIC": "extinction per colour channel (medium.scale = [r, g, b] with unequal "
                 "channels): RGB transmittance and spectral tracking",
    "EMISSION": "an emitting medium (medium.emission): its source term at every tentative "
                "collision",
    "TRANSFORM": "a medium placed by a transform that turns, mirrors or shears it "
                 "(medium.transform): points and rays enter its space",
    "ENV_MAP": "an environment map (lights.environment.file): radiance looked up and "
               "directions sampled per texel",
}


#: Code paths no scene takes: off in every render build, on in the test and benchmark kernels
#: (which build with the defaults of features.h).
TEST_FEATURES = {
    "PROFILES": "1-D test profiles as density sources (tests and the estimator benchmark)",
}


#: Instrumentation no scene needs: off in every render build unless a tool asks for it
#: (``OpenCLBackend(record=K)``), so a normal render compiles none of it.
TOOL_FEATURES = {
    "ALBEDO_AOV": "the albedo AOV a denoiser reads (volmc render --denoise; film.py): each "
                  "sample's albedo at its camera ray's first scattering",
    "RECORD": "recording of the transmittance segments a render queries (med.rec; "
              "volmc/bench/segments.py)",
}


def features(scene) -> frozenset:
    """The set of feature names (keys of FEATURES) a loaded Scene needs: what any of its
    media needs."""
    from .transform import placement
    r = scene.render
    out = set()
    for m in scene.spec.media:
        if not isinstance(m.density, ConstantDensity) and r.majorant == "grid":
            out.add("MAJORANT_GRID")
        if not isinstance(m.density, ConstantDensity) and r.majorant == "octree":
            out.add("MAJORANT_OCTREE")
        if m.chromatic:
            out.add("CHROMATIC")
        if m.emission is not None:
            out.add("EMISSION")
        if m.bounds is not None and placement(m)[2] is not None:
            out.add("TRANSFORM")
    if any(getattr(lt, "file", None) is not None for lt in scene.spec.lights):
        out.add("ENV_MAP")
    return frozenset(out)


def define_flags(feature_set) -> list:
    """Compiler options ``-DFEATURE_X=1`` for the features in the set and ``=0`` for the
    others, in a stable order (a kernel built without options has every feature on)."""
    return [f"-DFEATURE_{name}={int(name in feature_set)}"
            for name in sorted(FEATURES) + sorted(TEST_FEATURES) + sorted(TOOL_FEATURES)]


def features_header() -> str:
    """Text of the generated ``features.h``: every FEATURE_X defaults to 1 (compiled in)
    unless the build defines it, so kernels test plain constants and need no #ifdef."""
    out = ["/* Generated from volmc/scene/features.py: do not edit. */",
           "#ifndef VOLMC_FEATURES_H", "#define VOLMC_FEATURES_H"]
    for name, meaning in {**FEATURES, **TEST_FEATURES, **TOOL_FEATURES}.items():
        out += [f"/* {meaning} */", f"#ifndef FEATURE_{name}", f"#define FEATURE_{name} 1",
                "#endif"]
    return "\n".join(out + ["#endif", ""])
