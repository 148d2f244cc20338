"""Runs inside the ``bpy`` process of the Cycles peer (volmc/peers/cycles.py): builds the
Blender scene a job describes and renders it with Cycles in passes of independent seeds.

``python -m volmc.peers.cycles_worker JOB.json`` reads the job (written by
``cycles.write_job``), writes ``JOB.npz`` beside it: ``passes`` [K, h, w, 3] float64 (each
pass's image), ``tracing`` [K] and ``sync`` [K] seconds. Kept apart from volmc's own
process: ``import bpy`` brings a whole Blender (its own numpy and OpenVDB), which is better
not mixed with OpenCL and Numba, and a crash in it must not take volmc down. This module
imports nothing of volmc's, so it also runs in a Python that has only bpy.

The conventions, and how each is matched, are in the docstring of volmc/peers/cycles.py.
"""

import json
import math
import os
import sys
import time

# Run as a script, this file's folder heads sys.path; its cycles.py would then shadow
# Blender's own "cycles" add-on, and the engine would be missing.
if sys.path and os.path.abspath(sys.path[0] or ".") == os.path.dirname(os.path.abspath(__file__)):
    del sys.path[0]


def _clear():
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy


def _look_at(eye, target, up):
    """The camera's world matrix: Blender cameras look along their -Z with +Y up."""
    from mathutils import Matrix, Vector
    e, t, u = Vector(eye), Vector(target), Vector(up)
    f = (t - e).normalized()
    r = f.cross(u).normalized()
    v = r.cross(f)
    return Matrix(((r.x, v.x, -f.x, e.x), (r.y, v.y, -f.y, e.y), (r.z, v.z, -f.z, e.z),
                   (0.0, 0.0, 0.0, 1.0)))


def _along(direction):
    """A world matrix whose -Z axis is ``direction`` (a sun shines along its -Z)."""
    from mathutils import Vector
    d = Vector(direction).normalized()
    return (-d).to_track_quat("Z", "Y").to_matrix().to_4x4()


#: Cycles starts a perspective or orthographic camera's rays on the plane ``clip_start`` in
#: front of the camera object, a panorama's on the sphere of that radius about it; volmc's
#: start at the eye. So the object sits CLIP behind the eye, and the rays start on the plane
#: through the eye (a ray moves sideways by CLIP x tan(its angle to the axis), as good as
#: not at all, and loses no medium; at 1e-4 in front of the eye, a camera inside a box of
#: extinction 30 saw 0.3 % too bright). A panorama's sphere cannot be moved onto the eye:
#: it takes Blender's smallest clip, PANORAMA_CLIP.
CLIP = 1e-4
PANORAMA_CLIP = 1e-6


def _camera(bpy, sc, cam):
    """The camera: "fit" is the axis its field ("fov" degrees, or the orthographic "size")
    spans."""
    from mathutils import Vector
    data = bpy.data.cameras.new("camera")
    data.sensor_fit = cam["fit"]
    if cam["type"] == "orthographic":
        data.type = "ORTHO"
        data.ortho_scale = cam["size"]
    elif cam["type"] == "panoramic":
        data.type = "PANO"
        data.panorama_type = "EQUIRECTANGULAR"
        data.longitude_min, data.longitude_max = -math.pi, math.pi
        data.latitude_min, data.latitude_max = -0.5 * math.pi, 0.5 * math.pi
    else:
        data.lens_unit = "FOV"
        data.angle = math.radians(cam["fov"])   # the angle along the fitted axis
    if cam["aperture"] > 0.0:
        # Cycles' lens radius from the f-stop (see cycles.py): solved for volmc's radius.
        dof = data.dof
        dof.use_dof = True
        dof.aperture_blades = 0
        dof.aperture_ratio = 1.0
        length = 1.0 if cam["type"] == "orthographic" else data.lens * 1e-3
        dof.aperture_fstop = length / (2.0 * cam["aperture"])
    back = 0.0 if cam["type"] == "panoramic" else CLIP
    data.clip_start = back or PANORAMA_CLIP
    data.clip_end = 1e6
    if cam["aperture"] > 0.0:
        data.dof.focus_distance = cam["focus_distance"] + back   # from the moved object
    obj = bpy.data.objects.new("camera", data)
    sc.collection.objects.link(obj)
    eye, target = (Vector(cam["eye"]), Vector(cam["target"]))
    behind = back * (target - eye).normalized()
    obj.matrix_world = _look_at(eye - behind, target - behind, cam["up"])
    sc.camera = obj


def _openvdb():
    """bpy's bundled OpenVDB module: it lives in Blender's own site-packages, which
    ``import bpy`` does not put on the path."""
    import glob
    import bpy
    try:
        import openvdb
    except ImportError:
        root = bpy.utils.resource_path("LOCAL")   # .../bpy/<version>
        sys.path += glob.glob(os.path.join(root, "python", "lib", "python3*",
                                           "site-packages"))
        import openvdb
    return openvdb


def _write_vdb(grids, path):
    """Float grids in one OpenVDB file. grids: {name: {"file": .npy of a [z, y, x] array,
    "first_centre": world position of voxel (0, 0, 0)'s centre, "voxel": sizes}}."""
    import numpy as np
    openvdb = _openvdb()
    out = []
    for name, g in grids.items():
        a = np.load(g["file"]).astype(np.float32)
        vdb = openvdb.FloatGrid()
        # OpenVDB's index (i, j, k) is (x, y, z): the [z, y, x] array transposed.
        vdb.copyFromArray(np.ascontiguousarray(a.transpose(2, 1, 0)))
        vdb.name = name
        v, c = g["voxel"], g["first_centre"]
        vdb.transform = openvdb.createLinearTransform(
            [[v[0], 0.0, 0.0, 0.0], [0.0, v[1], 0.0, 0.0], [0.0, 0.0, v[2], 0.0],
             [c[0], c[1], c[2], 1.0]])
        out.append(vdb)
    openvdb.write(path, grids=out)


def _node(nt, kind, **inputs):
    n = nt.nodes.new(kind)
    for key, value in inputs.items():
        n.inputs[key].default_value = value
    return n


def _math(nt, op, a, b):
    """A Math node computing ``op(a, b)``; a and b are sockets or numbers."""
    n = nt.nodes.new("ShaderNodeMath")
    n.operation = op
    for i, x in enumerate((a, b)):
        if isinstance(x, (int, float)):
            n.inputs[i].default_value = float(x)
        else:
            nt.links.new(x, n.inputs[i])
    return n.outputs[0]


def _inside_box(nt, bounds):
    """A socket: 1 inside the box ``bounds`` (object coordinates = world), 0 outside."""
    coord = nt.nodes.new("ShaderNodeTexCoord")
    xyz = nt.nodes.new("ShaderNodeSeparateXYZ")
    nt.links.new(coord.outputs["Object"], xyz.inputs[0])
    inside = None
    for axis in range(3):
        c = xyz.outputs[axis]
        both = _math(nt, "MULTIPLY", _math(nt, "GREATER_THAN", c, bounds[0][axis]),
                     _math(nt, "LESS_THAN", c, bounds[1][axis]))
        inside = both if inside is None else _math(nt, "MULTIPLY", inside, both)
    return inside


def _material(bpy, med, name="volmc_medium"):
    """Volume Scatter + Volume Absorption (+ Emission) with volmc's coefficients
    (volmc/peers/cycles.py explains each)."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    mat.cycles.volume_interpolation = "LINEAR"   # trilinear, as volmc
    nt = mat.node_tree
    for n in list(nt.nodes):
        if n.type != "OUTPUT_MATERIAL":
            nt.nodes.remove(n)
    out = next(n for n in nt.nodes if n.type == "OUTPUT_MATERIAL")
    scale, albedo = med["scale"], med["albedo"]
    s = max(scale)
    k = [c / s for c in scale]
    if med["grid"] is None:
        density = float(s * med["density"])
    else:
        attr = nt.nodes.new("ShaderNodeAttribute")
        attr.attribute_name = "density"
        density = _math(nt, "MULTIPLY", attr.outputs["Fac"], s)
        if med["clip_to_bounds"]:
            density = _math(nt, "MULTIPLY", density, _inside_box(nt, med["bounds"]))

    def put(node, key, value):
        if isinstance(value, float):
            node.inputs[key].default_value = value
        else:
            nt.links.new(value, node.inputs[key])

    scatter = _node(nt, "ShaderNodeVolumeScatter",
                    Color=[k[c] * albedo[c] for c in range(3)] + [1.0],
                    Anisotropy=float(med["g"]))
    if hasattr(scatter, "phase"):   # Blender 4.3 and later offer several phase functions
        scatter.phase = "HENYEY_GREENSTEIN"
    put(scatter, "Density", density)
    absorb = _node(nt, "ShaderNodeVolumeAbsorption",
                   Color=[1.0 - k[c] * (1.0 - albedo[c]) for c in range(3)] + [1.0])
    put(absorb, "Density", density)
    add = nt.nodes.new("ShaderNodeAddShader")
    nt.links.new(scatter.outputs[0], add.inputs[0])
    nt.links.new(absorb.outputs[0], add.inputs[1])
    volume = add.outputs[0]
    em = med["emission"]
    if em is not None:
        top = max(em["colour"])
        if top > 0:
            emit = _node(nt, "ShaderNodeEmission",
                         Color=[c / top for c in em["colour"]] + [1.0])
            if med["grid"] is None:
                strength = float(med["density"] * top * em["constant"])
            else:
                strength = _math(nt, "MULTIPLY", attr.outputs["Fac"], top)
                if em["constant"] is not None:
                    strength = _math(nt, "MULTIPLY", strength, em["constant"])
                else:
                    field = nt.nodes.new("ShaderNodeAttribute")
                    field.attribute_name = "emission"
                    strength = _math(nt, "MULTIPLY", strength, field.outputs["Fac"])
                if med["clip_to_bounds"]:
                    strength = _math(nt, "MULTIPLY", strength, _inside_box(nt, med["bounds"]))
            put(emit, "Strength", strength)
            both = nt.nodes.new("ShaderNodeAddShader")
            nt.links.new(volume, both.inputs[0])
            nt.links.new(emit.outputs[0], both.inputs[1])
            volume = both.outputs[0]
    nt.links.new(volume, out.inputs["Volume"])
    return mat


def _place(bpy, sc, obj, m):
    """Give ``obj`` the world matrix ``m`` (4 x 4). Blender keeps an object's matrix as a
    location, a rotation and a scale, which lose a shear (a matrix whose columns are not
    orthogonal). A sheared m = T U S V^T (its linear part's singular values S, with U and V
    rotations after moving any mirroring into S) becomes an empty at T U S with ``obj`` as
    its child, turned by V^T."""
    import numpy as np
    from mathutils import Matrix
    m = np.asarray(m, float)
    g = m[:3, :3].T @ m[:3, :3]
    if np.abs(g - np.diag(np.diag(g))).max() <= 1e-12 * np.abs(g).max():
        obj.matrix_world = Matrix(m.tolist())
        return
    u, s, vt = np.linalg.svd(m[:3, :3])
    if np.linalg.det(u) < 0.0:
        u[:, 2], s[2] = -u[:, 2], -s[2]
    if np.linalg.det(vt) < 0.0:
        vt[2], s[2] = -vt[2], -s[2]
    outer = np.eye(4)
    outer[:3, :3], outer[:3, 3] = u * s, m[:3, 3]
    inner = np.eye(4)
    inner[:3, :3] = vt
    empty = bpy.data.objects.new(obj.name + "_shear", None)
    sc.collection.objects.link(empty)
    empty.matrix_world = Matrix(outer.tolist())
    obj.parent = empty
    obj.matrix_parent_inverse = Matrix.Identity(4)
    obj.matrix_basis = Matrix(inner.tolist())


def _medium(bpy, sc, med, folder, name="volmc_medium"):
    """The object of one medium, named ``name`` (its material and VDB file too)."""
    from mathutils import Matrix
    lo, hi = med["bounds"]
    place = Matrix(med["transform"]) if med.get("transform") else Matrix.Identity(4)
    if med["grid"] is None:
        bpy.ops.mesh.primitive_cube_add(size=2.0)
        obj = bpy.context.active_object
        box = Matrix.Diagonal([(hi[i] - lo[i]) / 2 for i in range(3)] + [1.0])
        box.translation = [(lo[i] + hi[i]) / 2 for i in range(3)]
        obj.name = name
        _place(bpy, sc, obj, place @ box)
        obj.data.materials.append(_material(bpy, med, name))
        return
    path = os.path.join(folder, f"{name}.vdb")
    _write_vdb(med["grid"], path)
    vol = bpy.data.volumes.new(name)
    vol.filepath = path
    vol.render.precision = "FULL"   # not half floats
    vol.render.clipping = 0.0       # no small value dropped as empty space
    # Densities per world unit, as volmc's (pbrt-v4's rule); Blender's default, "OBJECT",
    # scales them with the object, so a stretched grid had other optical depths.
    vol.render.space = "WORLD"
    obj = bpy.data.objects.new(name, vol)
    sc.collection.objects.link(obj)
    _place(bpy, sc, obj, place)
    vol.grids.load()
    vol.materials.append(_material(bpy, med, name))


def _lights(bpy, sc, lights):
    world = bpy.data.worlds.new("world")
    sc.world = world
    world.use_nodes = True
    bg = next(n for n in world.node_tree.nodes if n.type == "BACKGROUND")
    env = [0.0, 0.0, 0.0]
    for i, lt in enumerate(lights):
        if lt["type"] == "environment":
            env = [env[c] + lt["radiance"][c] for c in range(3)]
            continue
        rgb = lt["irradiance"] if lt["type"] == "directional" else lt["power"]
        top = max(rgb)
        if not top > 0:
            continue
        data = bpy.data.lights.new(f"light{i}", "SUN" if lt["type"] == "directional"
                                   else "POINT")
        data.energy = top
        data.color = [c / top for c in rgb]
        if lt["type"] == "directional":
            data.angle = 0.0
        else:
            data.shadow_soft_size = 0.0
            if hasattr(data, "use_soft_falloff"):
                data.use_soft_falloff = False
        obj = bpy.data.objects.new(f"light{i}", data)
        sc.collection.objects.link(obj)
        if lt["type"] == "directional":
            obj.matrix_world = _along(lt["direction"])
        else:
            obj.location = lt["position"]
    bg.inputs["Color"].default_value = env + [1.0]
    bg.inputs["Strength"].default_value = 1.0


def build(job):
    """The Blender scene of a job; returns the scene."""
    bpy = _clear()
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    cy = sc.cycles
    cy.device = "CPU"
    cy.use_adaptive_sampling = False
    cy.use_denoising = False
    cy.pixel_filter_type = "BOX"   # a sample anywhere in its pixel, weighted 1: volmc's
    cy.filter_width = 1.0
    cy.max_bounces = cy.volume_bounces = job["volume_bounces"]
    cy.diffuse_bounces = cy.glossy_bounces = cy.transmission_bounces = 0
    cy.transparent_max_bounces = 1024   # the medium box's faces are transparent crossings
    cy.sample_clamp_direct = cy.sample_clamp_indirect = 0.0
    cy.volume_biased = False   # null scattering (unbiased), not ray marching
    cy.caustics_reflective = cy.caustics_refractive = True
    cy.blur_glossy = 0.0
    cy.light_sampling_threshold = 0.0   # the light tree culls no light
    if job["threads"] > 0:
        sc.render.threads_mode = "FIXED"
        sc.render.threads = job["threads"]
    else:
        sc.render.threads_mode = "AUTO"
    w, h = job["resolution"]
    sc.render.resolution_x, sc.render.resolution_y = w, h
    sc.render.resolution_percentage = 100
    sc.render.film_transparent = bool(job.get("transparent", False))
    sc.render.use_persistent_data = True
    sc.view_settings.view_transform = "Standard"
    sc.view_settings.look = "None"
    sc.view_settings.exposure = 0.0
    sc.view_settings.gamma = 1.0
    sc.render.image_settings.file_format = "OPEN_EXR"
    sc.render.image_settings.color_depth = "32"
    sc.render.image_settings.color_mode = "RGB"
    _camera(bpy, sc, job["camera"])
    # Several media: one object each; where they overlap Cycles adds their closures.
    for i, med in enumerate([job["medium"]] + list(job.get("others", []))):
        _medium(bpy, sc, med, job["folder"], "volmc_medium" if i == 0 else f"volmc_medium{i}")
    _lights(bpy, sc, job["lights"])
    return bpy, sc


def render_passes(bpy, sc, job):
    """Each pass rendered and read back: ([K] images, [K] tracing s, [K] sync s)."""
    import numpy as np
    import OpenEXR
    stamps = []
    bpy.app.handlers.render_stats.append(lambda text: stamps.append((time.perf_counter(),
                                                                      text)))
    images, tracing, sync = [], [], []
    out = os.path.join(job["folder"], "pass.exr")
    sc.render.filepath = out
    for i, (spp, seed) in enumerate(zip(job["pass_spp"], job["pass_seeds"])):
        sc.cycles.samples = int(spp)
        sc.cycles.seed = int(seed)
        # Persistent data keeps Blender's side of the scene between passes, but Cycles
        # would then not see the new seed: the tag makes it sync the scene again.
        sc.update_tag()
        bpy.context.view_layer.update()
        stamps.clear()
        t0 = time.perf_counter()
        bpy.ops.render.render(write_still=True)
        t1 = time.perf_counter()
        # Cycles reports its phases: scene sync ("Synchronizing ...", "Updating ..."),
        # then "Sample 0/N" when tracing starts, "Sample i/N" as it goes, "Finished".
        # Tracing is from "Sample 0/N" to "Finished"; the rest of the call is sync and
        # output.
        first = next((t for t, s in stamps if "Sample 0/" in s), t0)
        done = next((t for t, s in stamps if "Finished" in s), t1)
        trace = done - first
        tracing.append(trace)
        sync.append((t1 - t0) - trace)
        with OpenEXR.File(out, separate_channels=True) as f:
            ch = f.channels()
            images.append(np.stack([np.asarray(ch[c].pixels, np.float64) for c in "RGB"],
                                   axis=-1))
    return images, tracing, sync


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    job_path = argv[0]
    with open(job_path) as f:
        job = json.load(f)
    import numpy as np
    bpy, sc = build(job)
    images, tracing, sync = render_passes(bpy, sc, job)
    np.savez(os.path.splitext(job_path)[0] + ".npz", passes=np.stack(images),
             tracing=np.array(tracing), sync=np.array(sync),
             version=np.array(bpy.app.version_string))
    return 0


if __name__ == "__main__":
    sys.exit(main())
