"""Scenes: the TOML format of docs/scene_format.md, validation, grids and procedural generators."""

from .errors import SceneError, VolmcError
from .loading import Scene, apply_overrides, load_scene, scene_from_dict
from .schema import (ArrayDensity, Camera, ConstantDensity, DirectionalLight, EnvironmentLight,
                     FileDensity, GeneratedDensity, Medium, Phase, PointLight, Render, SceneSpec, SphereLight,
                     SpotLight, validate)

__all__ = [
    "SceneError", "VolmcError", "Scene", "load_scene", "scene_from_dict", "apply_overrides",
    "validate",
    "Camera", "Medium", "Phase", "Render", "SceneSpec", "ConstantDensity", "FileDensity",
    "GeneratedDensity", "ArrayDensity", "EnvironmentLight", "DirectionalLight", "PointLight",
    "SpotLight", "SphereLight",
]
