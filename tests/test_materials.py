"""Materials: the paper's Table II, ITU-R P.2040-3 Table 3, user-defined materials."""

import math

import pytest

from clradcom.errors import SceneError, SceneWarning
from clradcom.scene.materials import (
    EPS0,
    ITU_P2040_TABLE3,
    PAPER_MATERIALS,
    builtin_material,
    builtin_material_names,
    conductivity_to_eps_imag,
    itu_conductivity,
    itu_permittivity,
    xpd_db_to_cross_pol_share,
)
from clradcom.scene.reader import load_scene

F = 24e9


# -- the paper's Table II ------------------------------------------------------------


def test_paper_table2_builtins():
    b = PAPER_MATERIALS["concrete_building"]
    assert b.eps_r == complex(5.0, -0.1) and b.roughness_m == pytest.approx(1e-3)
    assert not b.pec
    r = PAPER_MATERIALS["concrete_road"]
    assert r.eps_r == complex(5.0, -0.1) and r.roughness_m == pytest.approx(0.4e-3)
    m = PAPER_MATERIALS["metal"]
    assert m.pec and math.isinf(m.eps_r.real) and m.roughness_m == 0.0
    t = PAPER_MATERIALS["trees"]
    assert t.eps_r == complex(10.0, -6.0)
    assert t.scattering_coefficient == pytest.approx(0.5)  # project default for trees
    for mat in PAPER_MATERIALS.values():
        assert mat.roughness_model == "ament"


def test_builtin_names_cover_paper_and_itu():
    names = builtin_material_names()
    for n in ("concrete_building", "concrete_road", "metal", "trees"):
        assert n in names
    for n in ("vacuum", "concrete", "brick", "plasterboard", "wood", "glass", "ceiling_board",
              "chipboard", "plywood", "marble", "floorboard", "metal", "very_dry_ground",
              "medium_dry_ground", "wet_ground"):
        assert n in ITU_P2040_TABLE3
        assert "itu_" + n in names


# -- ITU-R P.2040-3 ------------------------------------------------------------------


def test_itu_concrete_at_24ghz_from_power_law():
    a, b, c, d = 5.24, 0.0, 0.0462, 0.7822
    sigma = c * 24.0**d
    eps = itu_permittivity("concrete", F)
    assert eps.real == pytest.approx(a * 24.0**b)
    assert -eps.imag == pytest.approx(sigma / (2 * math.pi * F * EPS0))
    # the reference's numbers (physics reference §7): 5.24 - j0.416, sigma = 0.555 S/m
    assert eps.imag == pytest.approx(-0.416, abs=5e-4)
    assert itu_conductivity("concrete", F) == pytest.approx(0.555, abs=5e-4)


@pytest.mark.parametrize(
    "name, expected",
    [
        ("brick", complex(3.91, -0.030)),
        ("plasterboard", complex(2.73, -0.126)),
        ("wood", complex(1.99, -0.106)),
        ("glass", complex(6.31, -0.190)),
        ("chipboard", complex(2.58, -0.194)),
        ("plywood", complex(2.71, -0.247)),
        ("marble", complex(7.074, -0.078)),
        ("ceiling_board", complex(1.48, -0.025)),
        ("vacuum", complex(1.0, 0.0)),
    ],
)
def test_itu_materials_match_reference_table(name, expected):
    eps = itu_permittivity(name, F)
    assert eps.real == pytest.approx(expected.real, abs=1e-3)
    assert eps.imag == pytest.approx(expected.imag, abs=6e-4)


def test_itu_metal_is_effectively_pec():
    eps = itu_permittivity("metal", F)
    assert eps.imag == pytest.approx(-1e7 * 17.975 / 24.0, rel=1e-3)  # -7.5e6


def test_eps_imag_shortcut():
    # eps'' = 17.98 sigma / f_GHz
    assert conductivity_to_eps_imag(1.0, 1e9) == pytest.approx(17.975, rel=1e-4)


@pytest.mark.parametrize("name", ["very_dry_ground", "medium_dry_ground", "wet_ground",
                                  "floorboard"])
def test_itu_out_of_range_refused(name):
    with pytest.raises(SceneError) as ei:
        itu_permittivity(name, F)
    assert name in str(ei.value) and "GHz" in str(ei.value)


def test_itu_out_of_range_extrapolates_with_warning():
    with pytest.warns(SceneWarning, match="wet_ground"):
        eps = itu_permittivity("wet_ground", F, extrapolate=True)
    assert eps.real == pytest.approx(30.0 * 24.0**-0.4)
    assert -eps.imag == pytest.approx(0.15 * 24.0**1.3 * 17.975 / 24.0, rel=1e-3)


def test_itu_medium_dry_ground_in_range():
    eps = itu_permittivity("medium_dry_ground", 5e9)
    assert eps.real == pytest.approx(15.0 * 5.0**-0.1)
    assert -eps.imag == pytest.approx(0.035 * 5.0**1.63 * 17.975 / 5.0, rel=1e-3)


def test_builtin_itu_material_object():
    m = builtin_material("itu_glass", F)
    assert m.eps_r == itu_permittivity("glass", F)
    assert m.conductivity_s_m == pytest.approx(0.0036 * 24**1.3394)
    with pytest.raises(KeyError):
        builtin_material("unobtainium", F)


def test_xpd_conversion():
    assert xpd_db_to_cross_pol_share(0.0) == pytest.approx(0.5)
    k = xpd_db_to_cross_pol_share(20.0)
    assert 10 * math.log10((1 - k) / k) == pytest.approx(20.0)


# -- materials in scene files ----------------------------------------------------------

HEAD = '[scene]\ncarrier_hz = 24e9\n'


def obj(material):
    return (f'[[objects]]\nname = "o"\nmaterial = "{material}"\nshape = "plane"\n'
            'size = [1.0, 1.0]\n')


def load(tmp_path, text, name="mat.toml"):
    p = tmp_path / name
    p.write_text(text)
    return load_scene(p)


def test_user_material_eps_pair(tmp_path):
    s = load(tmp_path, HEAD + '[[materials]]\nname = "asphalt"\neps_r = [3.2, -0.05]\n'
             'roughness_m = 0.002\nscattering_coefficient = 0.3\ncross_pol_share = 0.1\n'
             'roughness_model = "boithias"\n' + obj("asphalt"))
    m = s.materials[s.objects[0].material]
    assert m.eps_r == complex(3.2, -0.05)
    assert (m.roughness_m, m.scattering_coefficient, m.cross_pol_share) == (0.002, 0.3, 0.1)
    assert m.roughness_model == "boithias"
    assert s.material_roughness_model.tolist() == [1]


def test_user_material_real_eps_plus_conductivity(tmp_path):
    s = load(tmp_path, HEAD + '[[materials]]\nname = "m"\neps_r = 4\nconductivity_s_m = 0.5\n'
             + obj("m"))
    assert s.materials[0].eps_r == pytest.approx(complex(4.0, -0.5 * 17.975 / 24), rel=1e-4)


def test_user_material_from_base_with_overrides(tmp_path):
    s = load(tmp_path, HEAD + '[[materials]]\nname = "wet_wall"\nbase = "concrete_building"\n'
             'roughness_m = 0.003\n' + obj("wet_wall"))
    m = s.materials[0]
    assert m.eps_r == complex(5.0, -0.1) and m.roughness_m == 0.003


def test_user_material_itu_extrapolated_warns(tmp_path):
    with pytest.warns(SceneWarning, match="wet_ground"):
        s = load(tmp_path, HEAD + '[[materials]]\nname = "verge"\nitu = "wet_ground"\n'
                 'allow_extrapolation = true\n' + obj("verge"))
    assert s.materials[0].eps_r.real == pytest.approx(30.0 * 24.0**-0.4)
    assert s.materials[0].conductivity_s_m == pytest.approx(0.15 * 24.0**1.3)


def test_user_material_pec_and_xpd(tmp_path):
    s = load(tmp_path, HEAD + '[[materials]]\nname = "tin"\npec = true\nxpd_db = 10.0\n'
             + obj("tin"))
    assert s.materials[0].pec and s.material_pec.tolist() == [True]
    assert s.materials[0].cross_pol_share == pytest.approx(1 / 11)


def test_builtin_itu_material_by_name_in_scene(tmp_path):
    s = load(tmp_path, HEAD + obj("itu_concrete"))
    assert s.material_eps_r[0] == pytest.approx(complex(5.24, -0.4163), abs=1e-3)


def _err(tmp_path, text):
    with pytest.raises(SceneError) as ei:
        load(tmp_path, text)
    e = ei.value
    assert "mat.toml" in str(e)
    return e


def test_error_positive_imaginary_eps(tmp_path):
    e = _err(tmp_path, HEAD + '[[materials]]\nname = "m"\neps_r = [5.0, 0.1]\n' + obj("m"))
    assert e.key == "materials[0].eps_r" and e.value == [5.0, 0.1]
    assert "materials[0].eps_r = [5.0, 0.1]" in str(e)
    assert "e^{+j omega t}" in str(e) and "[5, -0.1]" in str(e)


def test_error_eps_real_not_positive(tmp_path):
    e = _err(tmp_path, HEAD + '[[materials]]\nname = "m"\neps_r = [-2.0, -1.0]\n' + obj("m"))
    assert e.key == "materials[0].eps_r" and "pec = true" in str(e)


def test_error_negative_roughness(tmp_path):
    e = _err(tmp_path, HEAD + '[[materials]]\nname = "m"\neps_r = 3.0\nroughness_m = -0.001\n'
             + obj("m"))
    assert e.key == "materials[0].roughness_m" and e.value == -0.001
    assert "roughness_m = -0.001" in str(e) and ">= 0" in str(e)


@pytest.mark.parametrize("s_value", ["1.5", "-0.1"])
def test_error_scattering_coefficient_outside_unit_interval(tmp_path, s_value):
    e = _err(tmp_path, HEAD + f'[[materials]]\nname = "m"\neps_r = 3.0\n'
             f'scattering_coefficient = {s_value}\n' + obj("m"))
    assert e.key == "materials[0].scattering_coefficient" and e.value == float(s_value)
    assert s_value in str(e)


def test_error_material_needs_exactly_one_source(tmp_path):
    e = _err(tmp_path, HEAD + '[[materials]]\nname = "m"\neps_r = 3.0\nitu = "glass"\n'
             + obj("m"))
    assert e.key == "materials[0]" and "exactly one of" in str(e) and "'glass'" in str(e)


def test_error_material_without_source(tmp_path):
    e = _err(tmp_path, HEAD + '[[materials]]\nname = "m"\nroughness_m = 0.1\n' + obj("m"))
    assert e.key == "materials[0]" and "exactly one of" in str(e)


def test_error_itu_material_out_of_range_in_scene(tmp_path):
    e = _err(tmp_path, HEAD + obj("itu_wet_ground"))
    assert e.key == "objects[0].material" and e.value == "itu_wet_ground"
    assert "objects[0].material = 'itu_wet_ground'" in str(e)
    assert "1-10 GHz" in str(e) and "allow_extrapolation" in str(e)


def test_error_unknown_itu_name(tmp_path):
    e = _err(tmp_path, HEAD + '[[materials]]\nname = "m"\nitu = "granite"\n' + obj("m"))
    assert e.key == "materials[0].itu" and e.value == "granite" and "'granite'" in str(e)


def test_error_user_material_shadows_builtin(tmp_path):
    e = _err(tmp_path, HEAD + '[[materials]]\nname = "metal"\neps_r = 3.0\n' + obj("metal"))
    assert e.key == "materials[0].name" and e.value == "metal" and "base = 'metal'" in str(e)


def test_error_duplicate_material_name(tmp_path):
    e = _err(tmp_path, HEAD + '[[materials]]\nname = "m"\neps_r = 3.0\n'
             '[[materials]]\nname = "m"\neps_r = 4.0\n' + obj("m"))
    assert e.key == "materials[1].name" and "duplicate material" in str(e)
    assert "materials[0]" in str(e)


def test_error_unknown_material_name(tmp_path):
    e = _err(tmp_path, HEAD + obj("concrete_bulding"))
    assert e.key == "objects[0].material" and e.value == "concrete_bulding"
    assert "did you mean 'concrete_building'" in str(e)


def test_error_cross_pol_and_xpd_both(tmp_path):
    e = _err(tmp_path, HEAD + '[[materials]]\nname = "m"\neps_r = 3.0\ncross_pol_share = 0.1\n'
             'xpd_db = 3.0\n' + obj("m"))
    assert e.key == "materials[0].xpd_db" and "not both" in str(e)


def test_error_bad_roughness_model(tmp_path):
    e = _err(tmp_path, HEAD + '[[materials]]\nname = "m"\neps_r = 3.0\n'
             'roughness_model = "kirchhoff"\n' + obj("m"))
    assert e.key == "materials[0].roughness_model" and "'kirchhoff'" in str(e)
    assert "ament" in str(e)


def test_docs_materials_example_loads(tmp_path):
    import re
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[1] / "docs" / "materials.md").read_text()
    block = re.findall(r"```toml\n(.*?)```", doc, re.S)[0]
    s = load(tmp_path, HEAD + block)
    by = {m.name: m for m in s.materials}
    assert by["asphalt"].eps_r == complex(3.2, -0.05)
    assert by["lossy_panel"].eps_r.imag == pytest.approx(-0.5 * 17.975 / 24, rel=1e-4)
    assert by["rough_glass"].eps_r == itu_permittivity("glass", F)
    assert by["hedge"].eps_r == complex(10, -6) and by["hedge"].scattering_coefficient == 0.7
    assert by["sheet_metal"].pec
