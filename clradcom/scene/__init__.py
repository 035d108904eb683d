"""Scenes: the records (:mod:`~clradcom.scene.records`), the TOML reader
(:mod:`~clradcom.scene.reader`), the Python edits (:mod:`~clradcom.scene.edit`),
materials, antennas and procedural models."""

from clradcom.scene.edit import (
    add_material,
    add_object,
    add_radar,
    move,
    new_scene,
    remove,
    save_scene,
    set_waveform,
)
from clradcom.scene.reader import load_scene, scene_from_dict
from clradcom.scene.records import Radar, Scene, SceneObject

__all__ = ["Radar", "Scene", "SceneObject", "add_material", "add_object", "add_radar",
           "load_scene", "move", "new_scene", "remove", "save_scene", "scene_from_dict",
           "set_waveform"]
