"""The scene schema's key lists come from its dataclasses: a field added to a section is a key
that validate reads and serialize writes back, and the explicit exceptions name real fields."""

from dataclasses import fields

import pytest

from volmc.scene import schema
from volmc.scene.schema import Camera, Render, validate
from volmc.scene.serialize import to_dict

MEDIUM = {"bounds": [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]], "density": 1.0}

#: A valid value, other than the default, of every key of [render] and [camera]. A new field
#: fails test_every_key_has_a_value until it has one here.
VALUES = {
    "render": {
        "spp": 3, "max_depth": 7, "rr_depth": 2, "seed": 11, "max_steps": 999,
        "transmittance": next(e for e in schema.TRANSMITTANCE_ESTIMATORS
                              if e != Render().transmittance),
        "majorant": "global", "majorant_resolution": [2, 3, 4], "free_flight": "decomposition",
        "spectral": "channel", "grid_storage": "dense", "mis": "power", "sampler": "sobol",
        "light_samples": 2, "equiangular": True, "rr": "albedo",
        "transparent_background": True, "env_sampling": "uniform", "env_compensation": True,
        "emission_sampling": "mis",
    },
    "camera": {
        "type": "orthographic", "eye": [1.0, 2.0, 5.0], "target": [0.0, 0.5, 0.0],
        "up": [0.0, 0.0, 1.0], "fov": 30.0, "size": 3.0, "resolution": [16, 8],
        "aperture": 0.1, "focus_distance": 2.5,
    },
}
SECTIONS = {"render": (Render, schema.RENDER_KEYS), "camera": (Camera, schema.CAMERA_KEYS)}


def _as_field(v):
    return tuple(v) if isinstance(v, list) else v


@pytest.mark.parametrize("section", sorted(SECTIONS))
def test_every_key_has_a_value(section):
    cls, keys = SECTIONS[section]
    assert keys == tuple(f.name for f in fields(cls))
    assert set(VALUES[section]) == set(keys), "give the new key a value in VALUES"


@pytest.mark.parametrize("section", sorted(SECTIONS))
def test_validate_reads_and_serialize_writes_every_key(section):
    """A key accepted but not read (or not written back) would silently keep its default."""
    cls, keys = SECTIONS[section]
    raw = {"camera": {}, "medium": MEDIUM, section: VALUES[section]}
    spec = validate(raw, "scene.toml", "/")
    got = getattr(spec, section)
    default = cls()
    for k in keys:
        assert getattr(got, k) == _as_field(VALUES[section][k]) != getattr(default, k), k
    written = to_dict(spec)
    assert set(written[section]) == set(keys)
    assert validate(written, "scene.toml", "/") == spec


def test_unknown_key_names_the_derived_keys():
    raw = {"camera": {}, "medium": MEDIUM, "render": {"zzz": 1}}
    with pytest.raises(schema.SceneError) as e:
        validate(raw, "scene.toml", "/")
    assert f"(allowed: {', '.join(schema.RENDER_KEYS)})" in str(e.value)


def test_exceptions_name_real_fields():
    """Every field of the table of keys that differ from fields exists (a renamed or removed
    field must leave no stale entry), and each key list is the fields with those changes."""
    for cls, renamed in schema._KEYS_OF_FIELD.items():
        names = [f.name for f in fields(cls)]
        assert set(renamed) <= set(names), (cls.__name__, set(renamed) - set(names))
    assert schema.TOP_KEYS == ("camera", "medium", "media", "lights", "render")
    assert schema.FILE_DENSITY_KEYS == ("file", "grid")
    assert "power" in schema.LIGHT_KEYS["sphere"]
    assert "texels" not in schema.LIGHT_KEYS["environment"]


def test_every_light_class_has_a_type():
    assert schema.LIGHT_TYPES == tuple(schema.LIGHT_KEYS)
    for t, cls in schema.LIGHT_CLASSES.items():
        assert cls.__dataclass_fields__["type"].default == t
        assert schema.LIGHT_KEYS[t][0] == "type"
        assert set(schema.LIGHT_KEYS[t]) <= {f.name for f in fields(cls)} | {"power"}
