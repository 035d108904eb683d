"""The tracer's nested settings: one frozen dataclass per mechanism, each refusing a bad
value by its own name, TraceSettings.replace and the snapshot metadata they give."""

import dataclasses
import re

import pytest

from clradcom.trace import (
    DiffractionSettings,
    OpticsSettings,
    ScatteringSettings,
    SpecularSettings,
    TraceSettings,
)

BASE = TraceSettings(specular=SpecularSettings(max_reflections=2, rays=10_000),
                     diffraction=DiffractionSettings(max_diffractions=2, max_reflections=1),
                     optics=OpticsSettings(mode="pec"),
                     scattering=ScatteringSettings(enabled=True, tile_size_m=0.5))


def test_replace_changes_one_field_and_keeps_the_rest():
    new = BASE.replace(specular__rays=20_000)
    assert new.specular == SpecularSettings(max_reflections=2, rays=20_000)
    assert (new.diffraction, new.optics, new.scattering) == (
        BASE.diffraction, BASE.optics, BASE.scattering)
    assert BASE.specular.rays == 10_000  # frozen: the base is untouched
    both = BASE.replace(scattering__enabled=False, optics__mode="sbr",
                        scattering__threshold_db=-80.0)
    assert both.scattering == ScatteringSettings(enabled=False, tile_size_m=0.5,
                                                 threshold_db=-80.0)
    assert both.optics.mode == "sbr" and both.specular == BASE.specular
    assert BASE.replace() == BASE
    with pytest.raises(dataclasses.FrozenInstanceError):
        BASE.specular.rays = 1  # type: ignore[misc]


@pytest.mark.parametrize("key", ["rays", "physics__rays", "specular_rays", "__rays"])
def test_replace_refuses_an_unknown_mechanism_naming_the_key(key):
    with pytest.raises(TypeError,
                       match=rf"^{key}: TraceSettings.replace takes mechanism__field names"):
        BASE.replace(**{key: 1})


def test_replace_refuses_an_unknown_field_naming_it():
    with pytest.raises(TypeError, match="'max_rays'"):
        BASE.replace(specular__max_rays=1)
    with pytest.raises(TypeError, match="'diffraction_hop_m'"):  # an old flat name
        BASE.replace(diffraction__diffraction_hop_m=5.0)


def test_replace_checks_the_new_value():
    with pytest.raises(ValueError, match=r"DiffractionSettings\.max_hop_m = -1\.0: must be"):
        BASE.replace(diffraction__max_hop_m=-1.0)


def test_trace_settings_takes_only_the_settings_classes():
    with pytest.raises(TypeError, match=r"TraceSettings\.optics = 'sbr': must be a OpticsSettings"):
        TraceSettings(optics="sbr")
    with pytest.raises(TypeError,
                       match=r"TraceSettings\.specular = .*: must be a SpecularSettings"):
        TraceSettings(specular=DiffractionSettings())
    with pytest.raises(TypeError, match="max_reflections"):  # no flat names
        TraceSettings(max_reflections=1)


@pytest.mark.parametrize("cls, field, value", [
    (SpecularSettings, "max_reflections", -1),
    (SpecularSettings, "max_reflections", 17),
    (SpecularSettings, "max_reflections", 1.0),
    (SpecularSettings, "rays", 0),
    (SpecularSettings, "rays", True),
    (SpecularSettings, "line_of_sight", 1),
    (DiffractionSettings, "max_diffractions", 4),
    (DiffractionSettings, "wedge_angle_deg", 0.0),
    (DiffractionSettings, "wedge_angle_deg", 180.0),
    (DiffractionSettings, "wedge_angle_deg", float("nan")),
    (DiffractionSettings, "max_reflections", 17),
    (DiffractionSettings, "max_hop_m", 0.0),
    (DiffractionSettings, "max_hop_m", float("inf")),
    (DiffractionSettings, "max_chains", 0),
    (OpticsSettings, "mode", "po"),
    (OpticsSettings, "sbr_spacing_wavelengths", 0.001),
    (OpticsSettings, "sbr_spacing_wavelengths", "0.5"),
    (OpticsSettings, "max_bounces", 17),
    (OpticsSettings, "max_bounces", 2.0),
    (ScatteringSettings, "enabled", "yes"),
    (ScatteringSettings, "max_reflections", 3),
    (ScatteringSettings, "threshold_db", 1.0),
    (ScatteringSettings, "tile_size_m", -0.5),
    (ScatteringSettings, "min_face_area_m2", float("inf")),
    (ScatteringSettings, "floor", -1e-12),
])
def test_each_settings_class_refuses_a_bad_value_naming_the_field(cls, field, value):
    with pytest.raises(ValueError,
                       match=rf"^{cls.__name__}\.{field} = {re.escape(repr(value))}: must "):
        cls(**{field: value})
    cls(**{field: getattr(cls(), field)})  # the default is fine


def test_diffraction_search_never_exceeds_the_specular_reflections():
    s = TraceSettings(specular=SpecularSettings(max_reflections=1),
                      diffraction=DiffractionSettings(max_reflections=3))
    assert s.diffraction_search.max_reflections == 1
    assert s.diffraction.max_reflections == 3  # as given
    assert BASE.diffraction_search == BASE.diffraction


def test_metadata_names_every_setting_by_mechanism():
    meta = BASE.metadata()
    expected = {f"settings.{m}.{f.name}"
                for m, cls in (("specular", SpecularSettings),
                               ("diffraction", DiffractionSettings),
                               ("optics", OpticsSettings), ("scattering", ScatteringSettings))
                for f in dataclasses.fields(cls)}
    # None means "follow another setting" (or, for expand_rounds and from_receiver, "off": a
    # snapshot traced without it keeps its bytes) and is left out
    assert set(meta) == (expected - {"settings.optics.max_bounces",
                                     "settings.optics.sbr_spacing_wavelengths",
                                     "settings.specular.expand_rounds",
                                     "settings.specular.from_receiver"}
                         ) | {"settings.engine"}
    assert BASE.replace(specular__expand_rounds=3).metadata()[
        "settings.specular.expand_rounds"] == 3
    assert meta["settings.engine"] == "device"
    assert meta["settings.specular.rays"] == 10_000
    assert meta["settings.diffraction.max_reflections"] == 1
    assert meta["settings.optics.mode"] == "pec"
    assert meta["settings.scattering.enabled"] is True
    assert meta["settings.scattering.tile_size_m"] == 0.5
    assert BASE.replace(optics__max_bounces=3).metadata()["settings.optics.max_bounces"] == 3


def test_optics_search_follows_the_specular_depth_unless_set():
    base = TraceSettings(specular=SpecularSettings(max_reflections=4))
    assert base.optics_search.max_bounces == 4
    own = base.replace(optics__max_bounces=2)
    assert own.optics_search.max_bounces == 2
    assert own.optics_search is own.optics


def test_engine_is_checked_and_replaceable():
    assert BASE.replace(engine="host").engine == "host"
    assert BASE.replace(engine="host").specular == BASE.specular
    with pytest.raises(ValueError, match="TraceSettings.engine.*'gpu'"):
        TraceSettings(engine="gpu")
