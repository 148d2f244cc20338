"""The render parameter record: defined once here, used by every backend.

The Numba reference receives a one-element numpy structured array of ``params_dtype(np.float64)``
and reads its fields by name; the OpenCL host derives the C struct of the kernels from the same
field list (with ``np.float32`` reals), so the layout is never written twice by hand.

Units: lengths in world units, extinction in 1/world unit, angles as cosines or tangents,
radiance/irradiance/intensity in the scene's linear RGB units. "World" is the scene frame of
``pack.scene_frame``: the scene re-centred on the medium box and scaled by a power of two, so
the kernels' float32 never sees coordinates far from the origin (robustness case 11, 12).
"""

import numpy as np

#: (name, kind, count, meaning). kind "real" becomes float64 (reference) or float32 (kernels).
PARAM_FIELDS = (
    ("width", "i4", 1, "image width in pixels"),
    ("height", "i4", 1, "image height in pixels"),
    ("cam_type", "i4", 1, "CAMERA_PERSPECTIVE, CAMERA_ORTHOGRAPHIC or CAMERA_PANORAMIC"),
    ("eye", "real", 3, "camera position (perspective: the lens centre; panoramic) or "
                       "image-plane centre (orthographic), moved near along forward"),
    ("forward", "real", 3, "unit viewing direction"),
    ("right", "real", 3, "unit vector along the image's +x (left to right)"),
    ("up", "real", 3, "unit vector along the image's up direction (bottom to top)"),
    ("half_height", "real", 1, "tan(fov / 2) (perspective) or size / 2 (orthographic); "
                               "panoramic: unused"),
    ("aspect", "real", 1, "width / height"),
    ("aperture", "real", 1, "thin-lens radius; 0: a pinhole (draws no lens sample)"),
    ("lens_slope", "real", 1, "aperture / focus_distance: how far a lens point turns its ray"),
    ("near", "real", 1, "distance along forward from the camera to eye, the plane camera rays "
                        "start on (pack.camera_near; 0: they start at the camera)"),
    ("decomposition", "i4", 1, "1: free flight uses each segment's minorant as its control"),
    ("shadow_estimator", "i4", 1, "ESTIMATOR_* id of shadow rays (the kernels build it in)"),
    ("view_estimator", "i4", 1, "ESTIMATOR_* id of camera rays that cannot scatter, whose "
                                "transmittance is the whole estimate (the kernels build it in)"),
    ("signed_samples", "i4", 1, "1 if samples may be negative (a signed shadow estimator)"),
    ("mis", "i4", 1, "MIS_BALANCE or MIS_POWER: how light and phase sampling combine"),
    ("sampler", "i4", 1, "SAMPLER_INDEPENDENT, SAMPLER_STRATIFIED or SAMPLER_SOBOL"),
    ("spp", "u4", 1, "samples per pixel of the render (the strata of SAMPLER_STRATIFIED)"),
    ("light_samples", "i4", 1, "shadow rays per light (environment: directions) per vertex"),
    ("equiangular", "i4", 1, "1: point lights also sampled by equiangular distance sampling"),
    ("rr", "i4", 1, "RR_THROUGHPUT or RR_ALBEDO: the Russian-roulette survival rule"),
    ("transparent", "i4", 1, "1: camera rays do not see the environment (it still lights)"),
    ("has_env", "i4", 1, "1 if an environment light is present"),
    ("env", "real", 3, "environment radiance (sum of all environment lights); with a map, "
                       "the factor of its texels (radiance x strength)"),
    ("env_map", "i4", 1, "1: the environment is a map (kernels/environment.h; env buffer)"),
    ("env_res", "i4", 2, "the map's texels (W, H)"),
    ("env_rot", "real", 9, "scene direction to the map's frame, 3x3 row-major"),
    ("env_sampling", "i4", 1, "ENV_SAMPLING_IMPORTANCE or ENV_SAMPLING_UNIFORM: how "
                              "next-event estimation draws environment directions"),
    ("emission_sampling", "i4", 1, "EMISSION_SAMPLING_*: collision estimator, emitter sampling "
                                   "or both by MIS (collision when no medium emits)"),
    ("n_lights", "i4", 1, "number of lights in the light array (every type but environment)"),
    ("area_lights", "i4", 1, "lights that sample a direction (suns with an angle, spheres): "
                             "with any, every light has its own points of the light pair"),
    ("spheres", "i4", 1, "1 if a sphere light is present: rays test them as occluders"),
    ("max_depth", "i4", 1, "scattering events per path; -1 = unbounded"),
    ("rr_depth", "i4", 1, "Russian roulette applies from this many scattering events on"),
    ("max_steps", "i4", 1, "step cap per free-flight walk and per transmittance estimate"),
    ("seed_lo", "u4", 1, "low 32 bits of the seed"),
    ("seed_hi", "u4", 1, "high 32 bits of the seed"),
)

#: The medium record (volmc/reference/medium.py, kernels/medium.h): what is where, and what
#: bounds it. Arrays travel beside it: the density grid and the per-cell majorant grid.
MEDIUM_FIELDS = (
    ("density_kind", "i4", 1, "DENSITY_CONSTANT, DENSITY_GRID, DENSITY_BRICKS or a profile"),
    ("majorant_kind", "i4", 1, "MAJORANT_GLOBAL (one segment), MAJORANT_GRID (DDA cells) or "
                               "MAJORANT_OCTREE (octree leaves)"),
    ("transformed", "i4", 1, "1: a transform places the medium (xform), 0: its box is as given"),
    ("xform", "real", 12, "transformed: scene frame to the medium's space, 3x4 row-major"),
    ("bmin", "real", 3, "medium box minimum corner"),
    ("bmax", "real", 3, "medium box maximum corner"),
    ("near_min", "real", 3, "several media: a box of the scene frame around the placed box, "
                            "a little larger (pack.py): a ray that misses it misses the medium"),
    ("near_max", "real", 3, "several media: that box's maximum corner"),
    ("inv_extent", "real", 3, "1 / (bmax - bmin) per axis"),
    ("dims", "i4", 3, "DENSITY_GRID, DENSITY_BRICKS: voxels (nx, ny, nz)"),
    ("density", "real", 1, "DENSITY_CONSTANT: the density"),
    ("profile", "real", 5, "1-D profiles: a, b, c, s, L (density as a function of x)"),
    ("scale", "real", 1, "extinction = scale * density, 1/world unit"),
    ("sigma_maj", "real", 1, "MAJORANT_GLOBAL: extinction majorant of the whole medium"),
    ("sigma_min", "real", 1, "MAJORANT_GLOBAL: extinction minorant (the control)"),
    ("maj_res", "i4", 3, "MAJORANT_GRID: cells (cz, cy, cx)"),
    ("octree_depth", "i4", 1, "MAJORANT_OCTREE: depth D; leaves are whole cells of 2^D per axis"),
    ("spectral", "i4", 1, "SPECTRAL_GREY, SPECTRAL_TRACKING or SPECTRAL_CHANNEL"),
    ("chroma", "real", 3, "extinction per channel / the largest one (1, 1, 1 when grey)"),
    ("emission_kind", "i4", 1, "EMISSION_NONE, EMISSION_RADIANCE or EMISSION_TEMPERATURE"),
    ("emission_rgb", "real", 3, "radiance (EMISSION_RADIANCE) or scale (TEMPERATURE), RGB"),
    ("emission_dims", "i4", 3, "voxels (nx, ny, nz) of the emission field grid"),
    ("table_scale", "real", 1, "EMISSION_TEMPERATURE: blackbody table entries per kelvin"),
    ("emitter_row", "u4", 1, "emission sampling: the first row of its distribution's cells in "
                             "the table (after the blackbody rows; volmc/emitters.py)"),
    ("emitter_res", "i4", 3, "emission sampling: cells (cx, cy, cz) over the box; 0: none"),
    ("emitter_prob", "real", 1, "emission sampling: probability of picking this medium"),
    ("emitter_density", "real", 1, "emission sampling: a cell's density per scene volume over "
                                   "its probability (this medium's, times the cell's)"),
    ("emitter_to_scene", "real", 12, "emission sampling: medium space to the scene frame, 3x4"),
    ("albedo", "real", 3, "single-scattering albedo per channel"),
    ("phase_kind", "i4", 1, "PHASE_ISOTROPIC or PHASE_HG"),
    ("g", "real", 1, "Henyey-Greenstein asymmetry"),
    # Several media (kernels/medium.h): the kernels hold every medium's arrays one after the
    # other in shared buffers, and each record says where its own begin (elements). The
    # reference keeps an array per medium and ignores them; one medium has them all 0.
    ("grid_off", "u4", 1, "first element of this medium's density grid in the grid buffer"),
    ("maj_off", "u4", 1, "first element of its majorant maxima and minima (maj, mnr)"),
    ("emis_off", "u4", 1, "first element of its emission field grid"),
    ("table_off", "u4", 1, "first element of its blackbody table"),
    ("bricks_off", "u4", 1, "first element of its brick index table"),
    ("pool_off", "u4", 1, "first element of its brick pool"),
    ("nodes_off", "u4", 1, "first element of its octree's first-child indices"),
)

LIGHT_FIELDS = (
    ("type", "i4", 1, "LIGHT_DIRECTIONAL, LIGHT_POINT, LIGHT_SPOT or LIGHT_SPHERE"),
    ("vec", "real", 3, "directional: unit propagation direction; others: position"),
    ("color", "real", 3, "directional: irradiance; point, spot: intensity per steradian (a "
                         "spot's on its axis); sphere: radiance"),
    ("axis", "real", 3, "spot: unit direction of the cone's axis"),
    ("size", "real", 1, "directional: 1 - cos of the sun's half-angle (0: parallel light); "
                        "spot: cos of the cone's half-angle; sphere: radius"),
    ("inner", "real", 1, "spot: cos of the angle where the blend reaches full intensity"),
)

#: Samples (pixels x samples per pixel) per batch once the render's schedule has ramped up
#: (volmc/render.py, batch_schedule): about half a second of work at the default scene's
#: speed at W = 8. A launch renders at most one batch. Against 1 << 16 (one sample per pixel
#: of the default 256x256 cloud), alternating on a 2-core Zen 3: 1.13x the samples/s at W = 8
#: and 1.07x at W = 1; 1 << 20 was slower than 1 << 18 at both.
BATCH_SAMPLES = 1 << 18


def launch_spp(n_pixels):
    """The most samples per pixel one batch (and so one launch) of an n-pixel image holds."""
    return max(1, BATCH_SAMPLES // max(n_pixels, 1))


#: One launch of the OpenCL render kernel (kernels/integrator.cl, render_batch): which pixels
#: and samples it renders and how they are cut among work-items.
LAUNCH_FIELDS = (
    ("pix_start", "u4", 1, "first pixel of the launch (row-major index)"),
    ("n_pix", "u4", 1, "pixels of the launch"),
    ("sample_start", "u4", 1, "first sample index of every pixel"),
    ("n_samples", "u4", 1, "samples per pixel of the launch"),
    ("jobs_per_item", "u4", 1, "samples (pixel, sample) each work-item renders"),
    ("item_stride", "u4", 1, "stride of the deal of runs of blocks to work-items "
                             "(volmc.backends.opencl.item_deal)"),
    ("item_group", "u4", 1, "blocks of jobs_per_item jobs in a run of the deal"),
    ("rec_capacity", "i4", 1, "segments recorded per pixel (0: not recording)"),
)

#: Counter slots accumulated by every backend (the lane counters by the OpenCL kernels only:
#: the reference is one path at a time).
COUNTER_NAMES = (
    "lookups",          # density lookups
    "scatter_events",   # real scattering events (sum of path lengths)
    "capped",           # walks cut by the step cap (max_steps)
    "dropped",          # NaN/Inf/negative sample contributions caught and dropped
    "over_majorant",    # lookups whose extinction exceeded the majorant
    "shadow_rays",      # transmittance estimates for next-event estimation
    "lane_rounds",      # iterations of the lane-generic kernels' tracking loop (per work-item)
    "lane_active",      # lanes active in those iterations, summed (occupancy: / (rounds x W))
)
(C_LOOKUPS, C_SCATTER, C_CAPPED, C_DROPPED, C_OVER_MAJORANT, C_SHADOW, C_LANE_ROUNDS,
 C_LANE_ACTIVE) = range(len(COUNTER_NAMES))
N_COUNTERS = len(COUNTER_NAMES)
#: The counters of the lanes' work rather than of the samples: they depend on how a render's
#: samples are grouped into launches (its batches), which a resumed render may change.
LANE_COUNTERS = ("lane_rounds", "lane_active")


def sample_counts(counters):
    """A {counter: count} dict without LANE_COUNTERS: the counts the samples decide."""
    return {k: v for k, v in counters.items() if k not in LANE_COUNTERS}


def _dtype(fields, real):
    spec = []
    for name, kind, count, _ in fields:
        base = np.dtype(real) if kind == "real" else np.dtype(kind)
        spec.append((name, base, (count,)) if count > 1 else (name, base))
    return np.dtype(spec, align=True)


def params_dtype(real=np.float64):
    """Structured dtype of the parameter record with reals of type ``real``."""
    return _dtype(PARAM_FIELDS, real)


def medium_dtype(real=np.float64):
    """Structured dtype of the medium record with reals of type ``real``."""
    return _dtype(MEDIUM_FIELDS, real)


def launch_dtype():
    """Structured dtype of the launch record (no reals)."""
    return _dtype(LAUNCH_FIELDS, np.float32)


def light_dtype(real=np.float64):
    """Structured dtype of one directional/point light with reals of type ``real``."""
    return _dtype(LIGHT_FIELDS, real)
