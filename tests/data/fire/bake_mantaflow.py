"""Bake the Mantaflow fire of scenes/data/fire with Blender as a Python module, and record
OpenVDB's own reading of its grids for tests/test_fire_fixture.py.

Run it in a virtual environment with bpy (Python 3.11). The committed files are bpy 4.5.15
LTS's; bpy 5.0.1 bakes too, with the repair below, a slightly different simulation:

    python3.11 -m venv /tmp/bpy45 && /tmp/bpy45/bin/pip install bpy==4.5.15
    /tmp/bpy45/bin/python tests/data/fire/bake_mantaflow.py

The simulation: a gas domain of 1.6 x 1.6 x 2.4 m with vorticity 0.3 over a fire-and-smoke
inflow sphere of radius 0.22 m with an orange smoke colour (which makes Mantaflow keep its
colour grids), baked with cache type "All" to OpenVDB with blosc and half floats (Blender's
defaults), frames 1 to 16. Twice (BAKES):

- the gallery fire, scenes/data/fire/cache_fluid/data/fluid_data_0013.vdb ... _0016.vdb
  (about 1.5 MB): resolution 48 (32 x 32 x 48 voxels of 5 cm), not resumable, Blender's
  default, so the files hold what a render needs: velocity, density, shadow, heat (saved as
  "temperature"), flame and the colours;
- tests/data/fire/resumable/cache_fluid/data/fluid_data_0016.vdb (about 0.4 MB): resolution
  24, resumable, so the file holds every grid Mantaflow saves: the level sets, the int32
  flags, fuel, react, emission and the inflows besides.

The bake needs one repair. In the bpy wheels (4.5.15 and 5.0.1 at least) Mantaflow's Python
classes lose their base classes: ``manta.LevelsetGrid.__mro__`` is (LevelsetGrid, object),
where Mantaflow declares LevelsetGrid a Grid<Real>, so the bake script Blender runs stops at
``phi.setConst(9999)`` with "'LevelsetGrid' object has no attribute 'setConst'" and the
process aborts; no cache file is written. Blender's own executable registers the classes
correctly. ``restore_inherited_methods`` gives each class the methods of its Mantaflow
ancestors (PARENTS): Mantaflow's method wrappers take any Mantaflow object and cast it in
C++, so a wrapper is bound to the derived object directly (PyCFunction_NewEx on the
method's PyMethodDef), past the type check of the base class's method descriptor. The
process still aborts at exit (Mantaflow finds grids in use when Python's objects are torn
down), after the files are written and closed, so the script ends with os._exit.
"""

import ctypes
import gc
import os
import shutil
import sys
import tempfile


HERE = os.path.dirname(os.path.abspath(__file__))
#: (folder the cache goes to, its name in truth.npz, resolution, resumable, frames kept)
BAKES = [
    (os.path.join(HERE, "..", "..", "..", "scenes", "data", "fire"), "cache_fluid/", 48, False,
     range(13, 17)),
    (os.path.join(HERE, "resumable"), "resumable/cache_fluid/", 24, True, [16]),
]
LAST_FRAME = max(max(frames) for *_, frames in BAKES)

#: Mantaflow's class hierarchy (extern/mantaflow/preprocessed: grid.h, levelset.h,
#: shapes.h, particle.h, mesh.h), by the names the manta module gives the classes.
PARENTS = {
    "GridBase": "PbClass", "Grid_Real": "GridBase", "Grid_Vec3": "GridBase",
    "Grid_int": "GridBase", "LevelsetGrid": "Grid_Real", "MACGrid": "Grid_Vec3",
    "FlagGrid": "Grid_int", "Grid4dBase": "PbClass", "Grid4d_Real": "Grid4dBase",
    "Grid4d_Vec3": "Grid4dBase", "Grid4d_Vec4": "Grid4dBase", "Grid4d_int": "Grid4dBase",
    "Shape": "PbClass", "Sphere": "Shape", "Box": "Shape", "Cylinder": "Shape",
    "NullShape": "Shape", "Slope": "Shape",
    "ParticleBase": "PbClass", "ParticleDataBase": "PbClass", "MeshDataBase": "PbClass",
    "ParticleSystem_BasicParticleData": "ParticleBase",
    "ParticleSystem_ParticleIndexData": "ParticleBase",
    "ParticleSystem_TurbulenceParticleData": "ParticleBase",
    "ParticleSystem_VortexParticleData": "ParticleBase",
    "BasicParticleSystem": "ParticleSystem_BasicParticleData",
    "ParticleIndexSystem": "ParticleSystem_ParticleIndexData",
    "TurbulenceParticleSystem": "ParticleSystem_TurbulenceParticleData",
    "VortexParticleSystem": "ParticleSystem_VortexParticleData",
    "ParticleDataImpl_Real": "ParticleDataBase", "ParticleDataImpl_Vec3": "ParticleDataBase",
    "ParticleDataImpl_int": "ParticleDataBase", "MeshDataImpl_Real": "MeshDataBase",
    "MeshDataImpl_Vec3": "MeshDataBase", "MeshDataImpl_int": "MeshDataBase",
    "FluidSolver": "PbClass", "Mesh": "PbClass", "VortexSheetMesh": "Mesh",
    "WaveletNoiseField": "PbClass", "MovingObstacle": "PbClass", "Timings": "PbClass",
}

#: Offset of PyMethodDescrObject.d_method: the object header, d_type, d_name, d_qualname
#: (CPython 3.11, 64-bit).
METHOD_DEF_OFFSET = 16 + 3 * 8


class BoundToAny:
    """A descriptor that binds a builtin method's C function to any instance."""

    _new = ctypes.pythonapi.PyCFunction_NewEx
    _new.restype = ctypes.py_object
    _new.argtypes = [ctypes.c_void_p, ctypes.py_object, ctypes.c_void_p]

    def __init__(self, descriptor):
        self.method_def = ctypes.c_void_p.from_address(id(descriptor) + METHOD_DEF_OFFSET).value

    def __get__(self, obj, owner=None):
        return self if obj is None else self._new(self.method_def, obj, None)


def restore_inherited_methods(manta):
    """Add to every class in PARENTS the methods of its ancestors it lacks; returns how
    many."""
    modified = ctypes.pythonapi.PyType_Modified
    modified.argtypes = [ctypes.py_object]
    added = 0
    for name in PARENTS:
        cls = getattr(manta, name, None)
        if cls is None:
            continue
        own = gc.get_referents(cls.__dict__)[0]   # the dict behind the read-only proxy
        ancestor = name
        while ancestor in PARENTS:
            ancestor = PARENTS[ancestor]
            for key, value in vars(getattr(manta, ancestor)).items():
                if key.startswith("__") or key in own or \
                        type(value).__name__ != "method_descriptor":
                    continue
                own[key] = BoundToAny(value)
                added += 1
        modified(cls)
    return added


def bake(out, resolution, resumable):
    """Bake frames 1 to LAST_FRAME into the cache folder ``out``."""
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, LAST_FRAME
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.0, 0.0, 1.2))
    domain = bpy.context.active_object
    domain.scale = (1.6, 1.6, 2.4)
    bpy.ops.object.transform_apply(location=False, rotation=False, scale=True)
    settings = domain.modifiers.new("Fluid", "FLUID")
    settings.fluid_type = "DOMAIN"
    ds = settings.domain_settings
    ds.domain_type = "GAS"
    ds.resolution_max = resolution
    ds.vorticity = 0.3
    ds.cache_directory = out
    ds.cache_type = "ALL"
    ds.cache_resumable = resumable
    ds.cache_data_format = "OPENVDB"
    ds.cache_frame_start, ds.cache_frame_end = 1, LAST_FRAME
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.22, location=(0.0, 0.0, 0.35))
    flow = bpy.context.active_object
    settings = flow.modifiers.new("Fluid", "FLUID")
    settings.fluid_type = "FLOW"
    fs = settings.flow_settings
    fs.flow_type = "BOTH"
    fs.flow_behavior = "INFLOW"
    fs.smoke_color = (1.0, 0.45, 0.15)
    bpy.context.view_layer.objects.active = domain
    with bpy.context.temp_override(object=domain, active_object=domain, scene=scene):
        assert bpy.ops.fluid.bake_all() == {"FINISHED"}


def main():
    import bpy  # (creates the manta module)
    import manta
    print(f"restored {restore_inherited_methods(manta)} inherited Mantaflow methods")
    sys.path.insert(0, HERE)
    from make_fixtures import openvdb_module, record_truth, update_truth
    vdb = openvdb_module()
    for folder, name, resolution, resumable, frames in BAKES:
        work = tempfile.mkdtemp(prefix="volmc_bake_")
        bake(work, resolution, resumable)
        data = os.path.join(folder, "cache_fluid", "data")
        shutil.rmtree(data, ignore_errors=True)
        os.makedirs(data)
        truth = {}
        for frame in frames:
            file = f"fluid_data_{frame:04d}.vdb"
            shutil.copyfile(os.path.join(work, "data", file), os.path.join(data, file))
            record_truth(vdb, os.path.join(data, file), f"{name}data/{file}", truth)
        update_truth(truth, name)
        size = sum(os.path.getsize(os.path.join(data, f)) for f in os.listdir(data))
        print(f"wrote {data}: {len(frames)} frames, {size} bytes (Blender "
              f"{bpy.app.version_string}, OpenVDB {vdb.LIBRARY_VERSION})", flush=True)
        shutil.rmtree(work, ignore_errors=True)
    os._exit(0)


if __name__ == "__main__":
    main()
