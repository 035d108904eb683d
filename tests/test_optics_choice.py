"""Physical optics chosen by what an object is, not by a PEC flag (issue 27, items 1 and 6).

The rule (docs/po.md, "Choosing GO, PO or both, per object"): without its own ``optics``
key an object gets the mode's optics when its material reflects at least 0.4 of the power
at normal incidence, |Gamma(0)|^2 = |(1 - sqrt(eps_r)) / (1 + sqrt(eps_r))|^2 >= 0.4
(PEC: 1). Checked against that closed form with the permittivities written out here
(ITU-R P.2040-3 Table 3: eps' = a, sigma = c f_GHz^d); then on an imported (Sionna-style
XML) street whose car is ``itu_metal`` or a poor conductor: its PO facet and SBR returns
are there under the ``paper`` preset and equal the same car as PEC times |Gamma(0)|^2
within 0.2 dB (a facet at normal incidence radiates -Gamma(0) times the PEC facet's field,
docs/po.md; the SBR return's last bounce is on the car's front face within 4 degrees of
normal). The trace tool prints the choice once, takes ``--optics NAME=...``, and labels
the radar's mounting return only where a path from its mounting exists.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_scene_import import SQUARE, WALL_XML, feature, geojson_scene, write_scene
from tool_helpers import load_tool

from clradcom.errors import ArgumentError, SceneError
from clradcom.mechanisms.optics import (
    TARGET_REFLECTANCE,
    normal_reflectance,
    object_optics,
    optics_summary,
)
from clradcom.paths import InteractionType
from clradcom.scene import load_scene
from clradcom.scene.materials import EPS0
from clradcom.scene.reader import scene_from_dict
from clradcom.scene.records import with_object_optics
from clradcom.trace import TraceSettings, trace_scene

F_C = 24e9
#: ITU-R P.2040-3 Table 3 rows used here: (a, c, d), eps' = a, sigma = c f_GHz^d
ITU = {"metal": (1.0, 1.0e7, 0.0), "concrete": (5.24, 0.0462, 0.7822),
       "glass": (6.31, 0.0036, 1.3394), "marble": (7.074, 0.0055, 0.9262),
       "brick": (3.91, 0.0238, 0.16), "wood": (1.99, 0.0047, 1.0718)}
#: a conductor as poor as a metal can be and still count: 20 S/m (|Gamma(0)|^2 = -3.2 dB)
POOR_METAL_S_M = 20.0
SKIN = 16.0 - 16.0j  # skin-like at 24 GHz (tests/test_po_dielectric.py)


def conductor_eps(eps_real, sigma_s_m, f_hz=F_C):
    return complex(eps_real, -sigma_s_m / (2 * math.pi * f_hz * EPS0))


def itu_eps(name):
    a, c, d = ITU[name]
    return conductor_eps(a, c * (F_C / 1e9) ** d)


def reflectance0(eps):
    """|Gamma(0)|^2 of a half-space (principal square root: Re > 0, Im <= 0)."""
    root = np.sqrt(complex(eps))
    return abs((1 - root) / (1 + root)) ** 2


def db(x):
    return 10 * np.log10(x)


#: material -> (its permittivity, None for PEC; whether it is a target by the rule)
RULE_CASES = {
    "metal": (None, True),  # the paper's PEC
    "itu_metal": (itu_eps("metal"), True),
    "poor_metal": (conductor_eps(1.0, POOR_METAL_S_M), True),
    "skin": (SKIN, True),
    "itu_concrete": (itu_eps("concrete"), False),
    "itu_glass": (itu_eps("glass"), False),
    "itu_marble": (itu_eps("marble"), False),
    "itu_brick": (itu_eps("brick"), False),
    "itu_wood": (itu_eps("wood"), False),
    "trees": (10.0 - 6.0j, False),  # the paper's Table II
    "concrete_building": (5.0 - 0.1j, False),
}


def rule_scene(**own_keys):
    """One small box per material of RULE_CASES, named after it; ``own_keys``: optics keys."""
    objects = [{"name": m, "material": m, "shape": "box", "extents": [0.5, 0.5, 0.5],
                "position": [3.0 * i, 5.0, 0.25], **({"optics": own_keys[m]}
                                                    if m in own_keys else {})}
               for i, m in enumerate(RULE_CASES)]
    return scene_from_dict({
        "scene": {"name": "rule", "carrier_hz": F_C},
        "materials": [{"name": "poor_metal", "eps_r": 1.0,
                       "conductivity_s_m": POOR_METAL_S_M},
                      {"name": "skin", "eps_r": [SKIN.real, SKIN.imag]}],
        "objects": objects,
        "radars": [{"name": "A", "position": [0.0, 0.0, 1.0]}]})


def test_the_rule_follows_the_materials_reflection_not_a_pec_flag():
    scene = rule_scene()
    refl = normal_reflectance(scene)
    for o in scene.objects:
        eps, target = RULE_CASES[o.name]
        want = 1.0 if eps is None else reflectance0(eps)
        print(f"{o.name:18s} |Gamma(0)|^2 = {want:.4f} ({db(want):+.3f} dB)")
        assert refl[o.material] == pytest.approx(want, rel=1e-12, abs=1e-15), o.name
        assert (want >= TARGET_REFLECTANCE) == target, o.name  # the cases span the bound
    targets = [RULE_CASES[o.name][1] for o in scene.objects]
    for mode, default in (("none", "go"), ("pec", "both"), ("sbr", "po")):
        assert object_optics(scene, mode) == [default if t else "go" for t in targets], mode
    # an object's own key wins either way
    own = rule_scene(itu_metal="go", itu_concrete="po", skin="both")
    got = dict(zip([o.name for o in own.objects], object_optics(own, "sbr"), strict=True))
    assert (got["itu_metal"], got["itu_concrete"], got["skin"], got["metal"]) == (
        "go", "po", "both", "po")


def test_the_summary_names_each_object_its_optics_and_why():
    lines = optics_summary(rule_scene(itu_concrete="both"), "sbr", most=20)
    po = next(ln for ln in lines if ln.strip().startswith("po "))
    go = next(ln for ln in lines if ln.strip().startswith("go "))
    both = next(ln for ln in lines if ln.strip().startswith("both "))
    assert "4 object(s)" in po and "itu_metal (itu_metal -0.0 dB)" in po
    assert "poor_metal (poor_metal -3.2 dB)" in po and "skin (skin -3.4 dB)" in po
    assert "itu_concrete (own key)" in both
    assert "trees (trees -5.0 dB)" in go and "metal (" not in go
    assert "-4.0 dB" in lines[0]
    assert "and 3 more" in next(ln for ln in optics_summary(rule_scene(), "sbr", most=4)
                                if ln.strip().startswith("go "))


def test_optics_set_by_name_or_pattern_as_the_scene_key_would():
    scene = rule_scene()
    changed = with_object_optics(scene, [("itu_*", "go"), ("itu_glass", "po")],
                                 argument="--optics")
    got = dict(zip([o.name for o in changed.objects], object_optics(changed, "sbr"),
                   strict=True))
    assert (got["itu_metal"], got["itu_glass"], got["itu_wood"], got["metal"]) == (
        "go", "po", "go", "po")
    assert all(o.optics is None for o in scene.objects)  # the scene given is left as it was
    assert changed.content_hash() != scene.content_hash()
    with pytest.raises(ArgumentError, match=r"--optics = 'car\*=po': no object of scene "
                                            r"'rule' is named so \(its objects: metal, "):
        with_object_optics(scene, {"car*": "po"}, argument="--optics")
    with pytest.raises(ArgumentError, match=r"--optics = 'metal=mirror': the optics must"):
        with_object_optics(scene, {"metal": "mirror"}, argument="--optics")


# ---------------------------------------------------------------------------
# the keys of imported shapes


def test_xml_shape_and_geojson_feature_carry_an_optics_key(tmp_path):
    marker = '<ref id="$wall_material" name="bsdf"/>'
    xml = WALL_XML.replace(marker, marker + '\n    <string name="optics" value="both"/>')
    scene = load_scene(write_scene(tmp_path, xml))
    assert [o.optics for o in scene.objects] == [None, "both", None, None]
    bad = WALL_XML.replace(marker, marker + '\n    <string name="optics" value="mirror"/>')
    with pytest.raises(SceneError, match=r"shape\[mesh-wall\]\.optics = 'mirror': must be "
                                         r"one of go, po, both") as info:
        load_scene(write_scene(tmp_path, bad))
    assert str(info.value.file) == str(tmp_path / "canyon.xml") and info.value.line > 0

    features = [feature("a", [SQUARE], height=5, optics="po"),
                feature("b", [[[x + 20, y] for x, y in SQUARE]], height=5)]
    city = load_scene(geojson_scene(tmp_path, features))
    assert [o.optics for o in city.objects] == ["po", None]
    city = load_scene(geojson_scene(tmp_path, features, 'optics = "go"\n'))
    assert [o.optics for o in city.objects] == ["po", "go"]  # the feature's own wins
    with pytest.raises(SceneError, match=r"feature 0 of .*property optics = 'fast' must be "
                                         "one of go, po, both"):
        load_scene(geojson_scene(tmp_path, [feature("a", [SQUARE], height=5,
                                                    optics="fast")]))
    with pytest.raises(SceneError, match=r"objects\[0\]\.optics"):
        load_scene(geojson_scene(tmp_path, features, 'optics = "fast"\n'))


# ---------------------------------------------------------------------------
# an imported street whose car is a finite conductor, under the paper preset

CAR_XML = """\
<scene version="3.0.0">
  <bsdf type="itu-radio-material" id="mat-itu_concrete">
    <string name="type" value="concrete"/>
  </bsdf>
  <bsdf type="twosided" id="mat-{car}"><bsdf type="diffuse"/></bsdf>
  <shape type="rectangle" id="mesh-road">
    <ref id="mat-itu_concrete"/>
    <transform name="to_world"><scale value="30 6 1"/><translate value="15 0 0"/></transform>
  </shape>
  <shape type="cube" id="mesh-carA">
    <ref id="mat-{car}"/>
    <transform name="to_world">
      <scale value="2 0.9 0.675"/><translate value="22 0 0.825"/>
    </transform>
  </shape>
</scene>
"""

CAR_TOML = """\
[scene]
name = "imported_street"
carrier_hz = {carrier}
import = "street.xml"

[[materials]]
name = "pec"
pec = true

[[materials]]
name = "poor_metal"
eps_r = 1.0
conductivity_s_m = {poor}

[[radars]]
name = "A"
position = [0.0, 0.0, {height}]
pattern = "isotropic"
tx_power_w = 0.01
noise_figure_db = 10.0
"""


def car_scene_file(folder, car_material, height=0.825):
    """A road (itu_concrete) and car A (a 4 x 1.8 x 1.35 m box, 15 cm over the road, its
    front face 20 m ahead of radar A, which looks at the face's centre when ``height`` is
    0.825 m) as a Sionna-style XML scene imported by a TOML file."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "street.xml").write_text(CAR_XML.format(car=car_material))
    path = folder / "street.toml"
    path.write_text(CAR_TOML.format(carrier=F_C, poor=POOR_METAL_S_M, height=height))
    return path


def car_returns(paths, car):
    """(PO facet paths, SBR paths) ending on the car."""
    nk = paths.n_interactions.astype(int)
    last = paths.object_id[np.arange(len(paths)), np.maximum(nk - 1, 0)]
    on_car = (nk > 0) & (last == car)
    po = on_car & (paths.interaction[:, 0] == InteractionType.PHYSICAL_OPTICS)
    sbr = on_car & np.any(paths.interaction == InteractionType.SBR, axis=1)
    return po, sbr


@pytest.mark.parametrize("material, eps", [("itu_metal", itu_eps("metal")),
                                           ("poor_metal", conductor_eps(1.0, POOR_METAL_S_M))])
def test_an_imported_metal_car_gets_po_and_sbr_with_its_own_reflection(tmp_path, runtime,
                                                                       material, eps):
    settings = TraceSettings.preset("paper", specular__rays=20_000,
                                    specular__max_reflections=2,
                                    diffraction__max_diffractions=0,
                                    scattering__enabled=False)
    got = {}
    for mat in ("pec", material):
        scene = load_scene(car_scene_file(tmp_path / mat, mat))
        car = scene.object_index("carA")
        assert object_optics(scene, settings.optics.mode)[car] == "po"
        paths = trace_scene(scene, settings, runtime=runtime).links[0].paths
        po, sbr = car_returns(paths, car)
        assert po.any() and sbr.any(), mat  # the returns are there
        got[mat] = paths, po, sbr
    want = reflectance0(eps)
    (p_pec, po_pec, sbr_pec), (p_met, po_met, sbr_met) = got["pec"], got[material]
    # the same facets lit, the same face sequences bounced
    np.testing.assert_array_equal(p_pec.face_id[po_pec], p_met.face_id[po_met])
    assert sbr_pec.sum() == sbr_met.sum()
    for what, a, b in (("PO facets", p_met.gain[po_met], p_pec.gain[po_pec]),
                       ("SBR", p_met.gain[sbr_met], p_pec.gain[sbr_pec])):
        ratio = abs(a.sum()) ** 2 / abs(b.sum()) ** 2
        print(f"{material} {what}: {db(ratio):+.4f} dB against PEC, |Gamma(0)|^2 "
              f"{db(want):+.4f} dB")
        assert abs(db(ratio) - db(want)) < 0.2, (what, db(ratio), db(want))
    # nothing else changes: the same paths in all
    assert p_met.n_paths == p_pec.n_paths


# ---------------------------------------------------------------------------
# the trace tool: the choice printed once, --optics, the mounting-return label


def test_trace_prints_the_optics_takes_overrides_and_labels_only_a_real_mounting(
        tmp_path, capsys):
    tool = load_tool("trace")
    common = ["--rays", "20000", "--reflections", "1", "--diffractions", "0",
              "--no-scattering"]
    # a radar 1.5 m over the road: no echo from within 1 m of it, so no mounting return
    high = car_scene_file(tmp_path / "high", "itu_metal", height=1.5)
    assert tool.main([str(high), "--out", str(tmp_path / "o1"), *common]) == 0
    out = capsys.readouterr().out
    assert out.count("optics (OpticsSettings.mode 'sbr'") == 1
    assert "po (PO facets + SBR-PO): 1 object(s): carA (itu_metal -0.0 dB)" in out
    assert "go (GO image paths): 1 object(s): road (itu_concrete -8.1 dB)" in out
    assert 'id="mounting_return"' not in (tmp_path / "o1" / "A_image.svg").read_text()
    # 0.5 m over the road: the road right under it is its mounting return; --optics wins
    low = car_scene_file(tmp_path / "low", "itu_metal", height=0.5)
    assert tool.main([str(low), "--out", str(tmp_path / "o2"), *common,
                      "--optics", "carA=go"]) == 0
    out = capsys.readouterr().out
    assert "go (GO image paths): 2 object(s): road (itu_concrete -8.1 dB), carA (own key)" \
        in out
    assert 'id="mounting_return"' in (tmp_path / "o2" / "A_image.svg").read_text()
    # an object the scene lacks is refused before anything is traced
    assert tool.main([str(low), "--out", str(tmp_path / "o3"), "--optics", "carZ=po"]) == 2
    err = capsys.readouterr().err
    assert "--optics = 'carZ=po': no object of scene 'imported_street'" in err
    assert not (tmp_path / "o3").exists()
