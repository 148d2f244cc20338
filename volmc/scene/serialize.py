"""Write a validated scene back as a dictionary or TOML text (the inverse of ``validate``).

``validate(to_dict(spec), ...) == spec`` for every valid scene: tests check the round trip,
and renders store the fully resolved scene in their EXR metadata for reproducibility.
"""

from .transform import axis_angle
from .schema import (ArrayDensity, ConstantDensity, DirectionalLight, EnvironmentLight,
                     FileDensity, GeneratedDensity, PointLight, SceneSpec, SphereLight,
                     SpotLight)


def to_dict(spec: SceneSpec, array_as=None) -> dict:
    """Plain dictionary in the TOML layout of docs/scene_format.md, every key explicit. A grid
    given as a numpy array stays the array, or is ``array_as(array)`` when given (a TOML
    file cannot hold the array: ``to_toml`` needs a stand-in)."""
    c, r = spec.camera, spec.render
    lights = []
    for lt in spec.lights:
        if isinstance(lt, EnvironmentLight):
            env = {"type": "environment", "radiance": list(lt.radiance)}
            if lt.file is not None:
                env.update(file=lt.resolved, strength=lt.strength)
                if lt.rotation is not None:
                    env["rotation"] = axis_angle(lt.rotation)
            lights.append(env)
        elif isinstance(lt, DirectionalLight):
            lights.append({"type": "directional", "direction": list(lt.direction),
                           "irradiance": list(lt.irradiance), "angle": lt.angle})
        elif isinstance(lt, SpotLight):
            lights.append({"type": "spot", "position": list(lt.position),
                           "direction": list(lt.direction), "intensity": list(lt.intensity),
                           "angle": lt.angle, "blend": lt.blend})
        elif isinstance(lt, SphereLight):
            lights.append({"type": "sphere", "position": list(lt.position),
                           "radius": lt.radius, "radiance": list(lt.radiance)})
        elif isinstance(lt, PointLight):
            lights.append({"type": "point", "position": list(lt.position),
                           "intensity": list(lt.intensity)})
    media = [_medium(m, array_as) for m in spec.media]
    camera = {"type": c.type, "eye": list(c.eye), "target": list(c.target), "up": list(c.up),
              "fov": c.fov, "size": c.size, "resolution": list(c.resolution),
              "aperture": c.aperture}
    if c.focus_distance is not None:   # None (a Camera not validated yet): eye to target
        camera["focus_distance"] = c.focus_distance
    return {
        "camera": camera,
        **({"medium": media[0]} if len(media) == 1 else {"media": media}),
        "lights": lights,
        "render": {"spp": r.spp, "max_depth": r.max_depth, "rr_depth": r.rr_depth,
                   "seed": r.seed, "max_steps": r.max_steps, "transmittance": r.transmittance,
                   "majorant": r.majorant, "majorant_resolution": list(r.majorant_resolution),
                   "free_flight": r.free_flight, "spectral": r.spectral,
                   "grid_storage": r.grid_storage, "mis": r.mis,
                   "sampler": r.sampler, "light_samples": r.light_samples,
                   "equiangular": r.equiangular, "rr": r.rr,
                   "transparent_background": r.transparent_background,
                   "env_sampling": r.env_sampling, "env_compensation": r.env_compensation,
                   "emission_sampling": r.emission_sampling},
    }


def _medium(m, array_as=None):
    """One medium's table."""
    def _source(d):
        return _grid_source(d, array_as)
    phase = {"type": m.phase.type}
    if m.phase.type == "hg":
        phase["g"] = m.phase.g
    medium = {"density": _source(m.density),
              "scale": m.scale[0] if not m.chromatic else list(m.scale),
              "albedo": list(m.albedo), "phase": phase}
    if m.bounds is not None:
        medium = {"bounds": [list(m.bounds[0]), list(m.bounds[1])], **medium}
    if m.transform is not None:
        medium["transform"] = {"matrix": [list(row) for row in m.transform]}
    if m.emission is not None:
        e = m.emission
        if e.radiance is not None:
            medium["emission"] = {"radiance": list(e.radiance), "field": _source(e.field)}
        else:
            medium["emission"] = {"temperature": _source(e.temperature), "scale": e.scale}
            if e.remap is not None:
                medium["emission"]["remap"] = list(e.remap)
    return medium


def _grid_source(d, array_as=None):
    """A grid source as the scene writes it."""
    if isinstance(d, ConstantDensity):
        return d.value
    if isinstance(d, FileDensity):
        return {"file": d.resolved, "grid": d.grid} if d.grid != "density" or \
            d.resolved.lower().endswith((".npz", ".vdb", ".nvdb")) else {"file": d.resolved}
    if isinstance(d, GeneratedDensity):
        return {"generator": d.generator, "resolution": d.resolution, "seed": d.seed,
                "channel": d.channel}
    if isinstance(d, ArrayDensity):   # the array itself: validate() takes it back
        return d.array if array_as is None else array_as(d.array)
    raise TypeError(d)


def _value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)  # shortest repr that round-trips exactly
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(type(v))


def dict_to_toml(d: dict) -> str:
    """TOML text of a scene-shaped dictionary: top-level tables become sections, lists of
    tables become arrays of tables ([[lights]]); values are written inline."""
    out = []
    for key, val in d.items():
        if isinstance(val, dict):
            out.append(f"[{key}]")
            out += [f"{k} = {_value(v)}" for k, v in val.items()]
            out.append("")
        elif isinstance(val, list) and val and all(isinstance(x, dict) for x in val):
            for item in val:
                out.append(f"[[{key}]]")
                out += [f"{k} = {_value(v)}" for k, v in item.items()]
                out.append("")
        else:
            out.insert(0, f"{key} = {_value(val)}")
    return "\n".join(out) + "\n"


def to_toml(spec: SceneSpec, array_as=None) -> str:
    """TOML text of a scene (tables for sections, [[lights]] for lights). A numpy-array grid
    raises TypeError unless ``array_as`` maps it to a TOML value (see ``to_dict``)."""
    return dict_to_toml(to_dict(spec, array_as))
