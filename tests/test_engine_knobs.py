"""The device engine's knobs: the per-object scene key ``sbr_spacing_wavelengths`` and
tools/trace.py's ``--engine`` and ``--sbr-spacing``."""

import pytest
from tool_helpers import load_tool

from clradcom.errors import SceneError
from clradcom.scene.reader import load_scene, scene_from_dict
from clradcom.scene.records import SBR_SPACING_WAVELENGTHS
from clradcom.trace import OpticsSettings


def plate_scene(**extra):
    return {"scene": {"name": "p", "carrier_hz": 24e9},
            "objects": [{"name": "road", "material": "concrete_road", "shape": "plane",
                         "size": [10.0, 10.0]},
                        {"name": "plate", "material": "metal", "shape": "plane",
                         "size": [1.0, 1.0], **extra}]}


def test_sbr_spacing_key_reaches_the_object_record_and_is_none_when_absent():
    scene = scene_from_dict(plate_scene(sbr_spacing_wavelengths=2))
    assert [o.sbr_spacing_wavelengths for o in scene.objects] == [None, 2.0]
    assert isinstance(scene.objects[1].sbr_spacing_wavelengths, float)
    low, high = SBR_SPACING_WAVELENGTHS
    for v in (low, high, 0.5):
        assert scene_from_dict(plate_scene(sbr_spacing_wavelengths=v)).objects[
            1].sbr_spacing_wavelengths == v


def test_sbr_spacing_key_is_in_the_content_hash_only_when_set():
    plain = scene_from_dict(plate_scene()).content_hash()
    a = scene_from_dict(plate_scene(sbr_spacing_wavelengths=0.5)).content_hash()
    b = scene_from_dict(plate_scene(sbr_spacing_wavelengths=1.0)).content_hash()
    assert len({plain, a, b}) == 3
    assert scene_from_dict(plate_scene()).content_hash() == plain


@pytest.mark.parametrize(("value", "reason"), [
    (0, "between 0.01 and 100 wavelengths"), (-1.0, "between 0.01 and 100 wavelengths"),
    (0.001, "between 0.01 and 100 wavelengths"), (101, "between 0.01 and 100 wavelengths"),
    ("fine", "expected a number (wavelengths)"), (True, "expected a number"),
    (float("nan"), "NaN or inf"), (float("inf"), "NaN or inf"),
    ([0.5], "expected a number")])
def test_bad_sbr_spacing_is_refused_naming_file_key_and_value(tmp_path, value, reason):
    with pytest.raises(SceneError) as info:
        scene_from_dict(plate_scene(sbr_spacing_wavelengths=value))
    err = info.value
    assert err.key == "objects[1].sbr_spacing_wavelengths"
    assert reason in str(err) and repr(value)[:4] in str(err)


def test_sbr_spacing_key_in_a_scene_file(tmp_path):
    path = tmp_path / "rail.toml"
    path.write_text('[scene]\ncarrier_hz = 24e9\n[[objects]]\nname = "rail"\n'
                    'material = "metal"\nshape = "box"\nextents = [60.0, 0.01, 0.3]\n'
                    'sbr_spacing_wavelengths = 2.0\n')
    assert load_scene(path).objects[0].sbr_spacing_wavelengths == 2.0
    path.write_text(path.read_text().replace("2.0\n", "1e3\n"))
    with pytest.raises(SceneError, match=r"rail\.toml.*objects\[0\]\.sbr_spacing_wavelengths"
                                         r" = 1000\.0.*between"):
        load_scene(path)


def test_trace_tool_engine_and_sbr_spacing_flags():
    tool = load_tool("trace")
    parse = tool.build_parser().parse_args
    default = tool.settings_from_args(parse(["s.toml"]))
    assert default.engine == "device"
    assert default.optics.sbr_spacing_wavelengths == OpticsSettings().sbr_spacing_wavelengths
    s = tool.settings_from_args(parse(["s.toml", "--engine", "host", "--sbr-spacing", "2"]))
    assert s.engine == "host" and s.optics.sbr_spacing_wavelengths == 2.0
    assert s.optics.mode == default.optics.mode == "sbr"
    assert s.replace(engine="device", optics__sbr_spacing_wavelengths=None) == default
    acc = tool.settings_from_args(parse(["s.toml", "--sbr-accuracy", "1.5",
                                         "--no-sbr-mirrors"]))
    assert acc.optics.sbr_accuracy_db == 1.5 and acc.optics.sbr_mirrors is False
    assert default.optics.sbr_mirrors is True


@pytest.mark.parametrize(("argv", "message"), [
    (["--sbr-spacing", "0"], "argument --sbr-spacing: must be a number in [0.01, 100], "
                             "got '0'"),
    (["--sbr-spacing", "-2"], "argument --sbr-spacing: must be a number in [0.01, 100]"),
    (["--sbr-spacing", "nan"], "argument --sbr-spacing: must be a finite number, got 'nan'"),
    (["--sbr-spacing", "fine"], "argument --sbr-spacing: must be a number, got 'fine'"),
    (["--engine", "gpu"], "argument --engine: invalid choice: 'gpu'"),
])
def test_trace_tool_refuses_bad_knobs_naming_the_flag(capsys, argv, message):
    with pytest.raises(SystemExit):
        load_tool("trace").build_parser().parse_args(["s.toml", *argv])
    assert message in capsys.readouterr().err
