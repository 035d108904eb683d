"""trace_scene keeps what a trace builds from the geometry alone (faces, BVH, device
buffers, face tables, wedges: clradcom.mechanisms.common.kept_geometry) for the next
trace of the same triangles: the next trace gives the same snapshot bit for bit as one
that builds everything anew, and a changed geometry is never traced with a kept one."""

from __future__ import annotations

import dataclasses
import threading
from pathlib import Path

import numpy as np
import pytest

from clradcom.mechanisms import diffraction
from clradcom.mechanisms.common import (
    build_geometry,
    forget_geometries,
    geometry_key,
    kept_geometry,
)
from clradcom.scene.reader import load_scene
from clradcom.snapshot import save_snapshot
from clradcom.trace import TraceSettings, trace_scene

STREET = Path(__file__).resolve().parents[1] / "scenes" / "street" / "street.toml"
# GO with one diffraction, so that the kept wedges are used too
SETTINGS = TraceSettings.preset("go", specular__rays=20_000, specular__max_reflections=3,
                                diffraction__max_diffractions=1)


@pytest.fixture(scope="module")
def street():
    return load_scene(STREET)


def snapshot_bytes(snap, folder: Path, name: str) -> bytes:
    return save_snapshot(folder / name, snap).read_bytes()


def test_second_trace_reuses_the_geometry_and_is_bit_identical(street, runtime, tmp_path):
    forget_geometries()
    first = trace_scene(street, SETTINGS, runtime=runtime)
    kept = kept_geometry(street, runtime)
    again = trace_scene(street, SETTINGS, runtime=runtime)
    assert kept_geometry(street, runtime).caster is kept.caster  # nothing rebuilt
    fresh = trace_scene(street, SETTINGS, runtime=runtime,
                        geometry=build_geometry(street, runtime))
    a, b, c = (snapshot_bytes(s, tmp_path, n) for s, n in (
        (first, "first.npz"), (again, "again.npz"), (fresh, "fresh.npz")))
    assert a == b == c
    assert sum(len(link.paths.delay_s) for link in first.links) > 20


def test_a_changed_geometry_is_built_anew(street, runtime, tmp_path):
    forget_geometries()
    before = trace_scene(street, SETTINGS, runtime=runtime)
    old = kept_geometry(street, runtime)
    car = street.objects[street.object_index("carB")]
    triangles = street.triangles.copy()
    triangles[car.tri_slice] += np.array([0.5, 0.0, 0.0])  # car B half a metre on
    moved = dataclasses.replace(street, triangles=triangles)
    assert geometry_key(moved) != geometry_key(street)
    new = kept_geometry(moved, runtime)
    assert new.caster is not old.caster
    np.testing.assert_array_equal(new.caster.triangles, triangles)
    after = trace_scene(moved, SETTINGS, runtime=runtime)
    fresh = trace_scene(moved, SETTINGS, runtime=runtime,
                        geometry=build_geometry(moved, runtime))
    assert snapshot_bytes(after, tmp_path, "a.npz") == snapshot_bytes(fresh, tmp_path, "f.npz")
    assert snapshot_bytes(after, tmp_path, "a.npz") != snapshot_bytes(before, tmp_path,
                                                                      "b.npz")
    # the first geometry is still kept (two per thread) and still the street's
    assert kept_geometry(street, runtime).caster is old.caster


def test_changing_a_scenes_arrays_in_place_leaves_the_kept_geometry_alone(street, runtime):
    forget_geometries()
    scene = dataclasses.replace(street, triangles=street.triangles.copy())
    kept = kept_geometry(scene, runtime)
    original = scene.triangles.copy()
    car = scene.objects[scene.object_index("carC")]
    scene.triangles[car.tri_slice] += np.array([0.0, 0.0, 0.25])
    np.testing.assert_array_equal(kept.caster.triangles, original)
    assert not kept.caster.triangles.flags.writeable
    assert kept_geometry(scene, runtime).caster is not kept.caster


def test_wedges_are_kept_per_setting_and_equal_a_fresh_extraction(street, runtime):
    forget_geometries()
    geom = kept_geometry(street, runtime)
    coarse = dataclasses.replace(SETTINGS.diffraction, wedge_angle_deg=40.0)
    w20 = diffraction.prepare(geom, SETTINGS.diffraction)
    w40 = diffraction.prepare(geom, coarse)
    assert diffraction.prepare(kept_geometry(street, runtime), SETTINGS.diffraction) is w20
    assert len(w40.start) < len(w20.start)
    fresh = diffraction.prepare(build_geometry(street, runtime), SETTINGS.diffraction)
    for name, value in vars(fresh).items():
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(getattr(w20, name), value, err_msg=name)


def test_each_thread_keeps_its_own(street, runtime):
    forget_geometries()
    mine = kept_geometry(street, runtime)
    theirs = []
    worker = threading.Thread(target=lambda: theirs.append(kept_geometry(street, runtime)))
    worker.start()
    worker.join()
    assert theirs[0].caster is not mine.caster
    assert kept_geometry(street, runtime).caster is mine.caster
