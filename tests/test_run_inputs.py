"""A run never writes over a file it read (issue #28): every file reading a scene opens
is in ``Scene.input_files``, and the commands refuse outputs over any of them, or a
snapshot traced from another scene than the one given beside it."""

from __future__ import annotations

from pathlib import Path

import pytest
import trimesh

from clradcom.cli import main as clradcom_main
from clradcom.scene import load_scene
from clradcom.snapshot import Snapshot, save_snapshot

ROOT = Path(__file__).resolve().parents[1]
CANONICAL = ROOT / "scenes" / "canonical"


def _export_main(argv):
    import importlib.util
    spec = importlib.util.spec_from_file_location("export_tool", ROOT / "tools" / "export.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.main(argv)


def _glb_scene(folder: Path, mesh_name: str) -> Path:
    """The canonical trihedral, its mesh as ``mesh_name`` (a GLB) in ``folder``."""
    mesh = trimesh.load(CANONICAL / "meshes" / "trihedral.obj", force="mesh")
    mesh.export(folder / mesh_name)
    text = (CANONICAL / "corner_mesh.toml").read_text()
    assert "meshes/trihedral.obj" in text
    scene = folder / "scene.toml"
    scene.write_text(text.replace("meshes/trihedral.obj", mesh_name))
    return scene


def _empty_snapshot(path: Path, scene) -> Path:
    save_snapshot(path, Snapshot(scene_name=scene.name, carrier_hz=float(scene.carrier_hz),
                                 scene_hash=scene.content_hash(), links=(), metadata={}))
    return path


def test_input_files_name_the_scene_file_and_its_meshes(tmp_path):
    scene_file = _glb_scene(tmp_path, "corner.glb")
    scene = load_scene(scene_file)
    assert [Path(p).resolve() for p in scene.input_files] == [
        scene_file.resolve(), (tmp_path / "corner.glb").resolve()]
    # a shape scene reads its file alone
    plate = load_scene(CANONICAL / "plate.toml")
    assert [Path(p).resolve() for p in plate.input_files] == [
        (CANONICAL / "plate.toml").resolve()]


def test_export_refuses_to_write_its_view_over_the_scene_mesh(tmp_path, capsys):
    scene_file = _glb_scene(tmp_path, "snap.glb")
    scene = load_scene(scene_file)
    snap = _empty_snapshot(tmp_path / "snap.npz", scene)
    before = (tmp_path / "snap.glb").read_bytes()
    rc = _export_main([str(snap), "--scene", str(scene_file), "--glb", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert rc == 2
    assert "refusing to overwrite an input file" in err and "snap.glb" in err
    assert len(err.strip().splitlines()) == 1
    assert (tmp_path / "snap.glb").read_bytes() == before
    # the scene still loads the mesh it had
    assert load_scene(scene_file).content_hash() == scene.content_hash()


def test_a_trace_into_the_folder_of_its_mesh_keeps_the_mesh(tmp_path):
    """The trace replaces only the outputs it owns in its folder: a mesh the scene reads
    from there is carried into the new folder, byte for byte."""
    scene_file = _glb_scene(tmp_path, "corner.glb")
    before = (tmp_path / "corner.glb").read_bytes()
    rc = clradcom_main(["trace", str(scene_file), "--out", str(tmp_path), "--rays", "2000"])
    assert rc == 0
    assert (tmp_path / "snapshot.npz").is_file()
    assert (tmp_path / "corner.glb").read_bytes() == before
    assert len(load_scene(scene_file).triangles) > 0


@pytest.mark.parametrize("tool", ["view", "export"])
def test_a_snapshot_of_another_scene_is_refused(tmp_path, capsys, tool):
    plate = load_scene(CANONICAL / "plate.toml")
    snap = _empty_snapshot(tmp_path / "plate.npz", plate)
    other = CANONICAL / "corner.toml"
    if tool == "view":
        rc = clradcom_main(["view", str(other), "--snapshot", str(snap),
                            "--out", str(tmp_path / "v.png")])
    else:
        rc = _export_main([str(snap), "--scene", str(other), "--top-view",
                           "--out", str(tmp_path / "ex")])
    err = capsys.readouterr().err
    assert rc == 2
    assert "scene_hash" in err and "another scene" in err
    assert not (tmp_path / "v.png").exists() and not (tmp_path / "ex").exists()
    # the same snapshot beside its own scene is drawn
    if tool == "view":
        assert clradcom_main(["view", str(CANONICAL / "plate.toml"), "--snapshot", str(snap),
                              "--out", str(tmp_path / "v.png")]) == 0
        assert (tmp_path / "v.png").stat().st_size > 0


def test_a_snapshot_without_a_hash_must_name_the_scenes_radars(tmp_path, capsys):
    """A snapshot with no scene hash (written by another tool) is checked by its radars'
    names and indices: against a scene without them it is refused in one line (it was an
    IndexError in `clradcom radar`, and drawn silently by `view`)."""
    import dataclasses

    from clradcom.snapshot import load_snapshot
    from clradcom.trace import TraceSettings, trace_scene
    car = load_scene(CANONICAL / "moving_car.toml")
    snap = trace_scene(car, TraceSettings.preset("go", specular__rays=2000))
    assert len(snap.links) > 0
    path = tmp_path / "nohash.npz"
    save_snapshot(path, dataclasses.replace(snap, scene_hash=""))
    assert load_snapshot(path).scene_hash == ""
    for argv in (["radar", str(path), "--scene", str(CANONICAL / "plate.toml"),
                  "--out", str(tmp_path / "r")],
                 ["view", str(CANONICAL / "plate.toml"), "--snapshot", str(path),
                  "--out", str(tmp_path / "v.png")]):
        assert clradcom_main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "has no scene hash" in err[0] and "'radarA'" in err[0]
    assert not (tmp_path / "r").exists() and not (tmp_path / "v.png").exists()
    assert clradcom_main(["view", str(CANONICAL / "moving_car.toml"), "--snapshot",
                          str(path), "--out", str(tmp_path / "v.png")]) == 0


def test_export_checks_the_link_before_it_writes_anything(tmp_path, capsys):
    plate = load_scene(CANONICAL / "plate.toml")
    snap = _empty_snapshot(tmp_path / "plate.npz", plate)
    out = tmp_path / "ex"
    rc = _export_main([str(snap), "--scene", str(CANONICAL / "plate.toml"), "--mat",
                       "--top-view", "--link", "X->Y", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--link = 'X->Y'" in err[0]
    assert not out.exists()   # no .mat written before the refusal, no folder either
