"""Scenes: the records (:mod:`~clradcom.scene.records`), the TOML reader
(:mod:`~clradcom.scene.reader`), materials, antennas and procedural models."""

from clradcom.scene.reader import load_scene, scene_from_dict
from clradcom.scene.records import Radar, Scene, SceneObject

__all__ = ["Radar", "Scene", "SceneObject", "load_scene", "scene_from_dict"]
