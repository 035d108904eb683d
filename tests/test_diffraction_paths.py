"""First-order UTD diffraction through the whole tracer, against closed forms."""

import numpy as np
import pytest

from clradcom.geometry.wedges import extract_wedges
from clradcom.mechanisms import diffraction
from clradcom.mechanisms.common import build_geometry
from clradcom.mechanisms.diffraction import wedges_seeing
from clradcom.paths import InteractionType
from clradcom.physics.em import C0
from clradcom.scene.reader import scene_from_dict
from clradcom.trace import (
    DiffractionSettings,
    OpticsSettings,
    SpecularSettings,
    TraceSettings,
    trace_scene,
)


def knife_edge_scene(h, pol, d1=10.0, d2=10.0):
    """A 100 m x 100 m PEC screen in the plane x = 0 whose top edge is at height h."""
    return scene_from_dict({
        "scene": {"name": "knife", "carrier_hz": 24e9},
        "objects": [{"name": "screen", "material": "metal", "shape": "plane",
                     "size": [100.0, 100.0], "position": [0.0, 0.0, h - 50.0],
                     "rotation_deg": [0.0, -90.0, 0.0]}],
        "radars": [{"name": "tx", "role": "tx", "position": [-d1, 0.0, 0.0],
                    "polarization": pol},
                   {"name": "rx", "role": "rx", "position": [d2, 0.0, 0.0],
                    "orientation_deg": [0.0, 0.0, 180.0], "polarization": pol}]})


def knife_edge_loss_db(nu):
    """ITU-R P.526 J(nu) from the Fresnel integrals (scipy's C, S)."""
    from scipy.special import fresnel

    s, c = fresnel(nu)
    return -20 * np.log10(np.sqrt((1 - c - s) ** 2 + (c - s) ** 2) / 2)


@pytest.mark.parametrize("nu", [0.5, 1.0, 1.5])
@pytest.mark.parametrize("pol", ["V", "H"])
def test_knife_edge_loss_through_the_tracer(runtime, nu, pol):
    d1 = d2 = 10.0
    lam = C0 / 24e9
    h = nu / np.sqrt(2 * (d1 + d2) / (lam * d1 * d2))
    settings = TraceSettings(specular=SpecularSettings(max_reflections=1, rays=20000),
                             diffraction=DiffractionSettings(max_diffractions=1))
    paths = trace_scene(knife_edge_scene(h, pol), settings, runtime=runtime).links[0].paths
    assert not np.any(paths.n_interactions == 0), "the screen must block the line of sight"
    diffracted = paths.interaction[:, 0] == InteractionType.DIFFRACTION
    assert diffracted.any()
    top = np.argmin(np.where(diffracted, paths.delay_s, np.inf))
    # the top edge's Keller point is straight above the line, at the edge
    np.testing.assert_allclose(paths.points[top, 1], [0.0, 0.0, h], atol=1e-9)
    np.testing.assert_allclose(paths.delay_s[top] * C0, 2 * np.hypot(10.0, h), rtol=1e-12)
    free = lam / (4 * np.pi * (d1 + d2))
    loss = -20 * np.log10(abs(paths.gain[top]) / free)
    # a PEC screen's soft and hard cases bracket the absorbing knife edge by ~0.1 dB
    assert loss == pytest.approx(knife_edge_loss_db(nu), abs=0.35)


def test_diffraction_order_zero_turns_it_off(runtime):
    settings = TraceSettings(specular=SpecularSettings(max_reflections=1, rays=20000),
                             diffraction=DiffractionSettings(max_diffractions=0))
    paths = trace_scene(knife_edge_scene(0.2, "V"), settings, runtime=runtime).links[0].paths
    assert paths.n_paths == 0
    with pytest.raises(ValueError, match=r"DiffractionSettings\.max_diffractions = 4: must be "
                       r"an integer in \[0, 3\]"):
        DiffractionSettings(max_diffractions=4)


def test_moving_edge_doppler_and_shadow_continuity(runtime):
    """Doppler of a diffracted path follows -(1/lambda) dL/dt with the edge moving."""
    lam = C0 / 24e9
    scene = scene_from_dict({
        "scene": {"name": "edge", "carrier_hz": 24e9},
        "objects": [{"name": "screen", "material": "metal", "shape": "plane",
                     "size": [100.0, 100.0], "position": [0.0, 0.0, 0.3 - 50.0],
                     "rotation_deg": [0.0, -90.0, 0.0], "velocity": [0.0, 0.0, 2.0]}],
        "radars": [{"name": "tx", "role": "tx", "position": [-10.0, 0.0, 0.0]},
                   {"name": "rx", "role": "rx", "position": [10.0, 0.0, 0.0],
                    "orientation_deg": [0.0, 0.0, 180.0]}]})
    settings = TraceSettings(specular=SpecularSettings(max_reflections=0, rays=1000))
    paths = trace_scene(scene, settings, runtime=runtime).links[0].paths
    top = np.argmin(paths.delay_s)
    # L(t) = 2 sqrt(10^2 + z(t)^2), dz/dt = 2 m/s
    z = 0.3
    expected = -(1 / lam) * 2 * z / np.hypot(10.0, z) * 2.0
    assert paths.doppler_hz[top] == pytest.approx(expected, rel=1e-9)


def test_physical_optics_replaces_the_go_mirror_return_of_a_pec_plate(runtime):
    """With optics mode 'pec' a small far plate returns 4 pi A^2 / lambda^2, not pi R^2."""
    lam = C0 / 24e9
    side, R = 0.2, 40.0  # 6x the far-field distance 2 D^2 / lambda of the plate's side
    scene = scene_from_dict({
        "scene": {"name": "far_plate", "carrier_hz": 24e9},
        "objects": [{"name": "plate", "material": "metal", "shape": "plane",
                     "size": [side, side], "position": [R, 0.0, 0.0],
                     "rotation_deg": [0.0, -90.0, 0.0]}],
        "radars": [{"name": "r", "position": [0.0, 0.0, 0.0],
                    "pattern": {"type": "sector", "azimuth_width_deg": 10.0,
                                "elevation_width_deg": 10.0}}]})

    def rcs(paths):
        total = paths.gain.sum()
        gain = scene.radars[0].pattern.gain(np.array([[1.0, 0.0, 0.0]]))[0]
        return abs(total) ** 2 * (4 * np.pi) ** 3 * R**4 / (lam**2 * gain**2)

    base = TraceSettings(specular=SpecularSettings(max_reflections=1, rays=100_000),
                         diffraction=DiffractionSettings(max_diffractions=0))
    go = trace_scene(scene, base, runtime=runtime).links[0].paths
    po = trace_scene(scene, base.replace(optics__mode="pec"), runtime=runtime).links[0].paths
    assert go.n_paths == 1 and rcs(go) == pytest.approx(np.pi * R**2, rel=1e-6)
    assert po.n_paths == 2  # one PO term per triangle, the GO mirror path gone
    assert np.all(po.interaction[:, 0] == InteractionType.PHYSICAL_OPTICS)
    # residual: the facets' own Fresnel phase k rho^2 / 2R at this finite range
    assert rcs(po) == pytest.approx(4 * np.pi * side**4 / lam**2, rel=1e-2)
    with pytest.raises(ValueError, match=r"OpticsSettings\.mode = 'sometimes': must be one of"):
        OpticsSettings(mode="sometimes")


def _segment_hits_rectangle_x(a, b, x0, y_range, z_range):
    """Independent float64 check: the segment a -> b crosses the rectangle x = x0,
    y in y_range, z in z_range."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if (a[0] - x0) * (b[0] - x0) >= 0:
        return False
    p = a + (x0 - a[0]) / (b[0] - a[0]) * (b - a)
    return y_range[0] <= p[1] <= y_range[1] and z_range[0] <= p[2] <= z_range[1]


def test_edges_hidden_at_their_sample_points_still_diffract(runtime):
    """A metal box x 10-14, y 0-2, z 0-12 and tx (0, -2.2, 0.75), rx (0, -1.8, 0.75): its
    vertical corner edge at (10, 0) diffracts at (10, 0, 0.75), 68.047 ns, -118.33 dB.  A
    plate at x = 5 (y -2.5 ... 0.5, z 1.5 ... 11.5) hides that edge's points at 1/4, 1/2
    and 3/4 of its height (the candidate filter's old samples) from both antennas, but
    not the Keller point: both legs pass under the plate.  Expected, independently of the
    filter: every diffraction path of the box alone whose two legs miss the plate (a
    float64 segment-rectangle test) is found again with the plate, with the same delay
    and gain.  (diffraction.wedges_seeing sampled three points per edge and dropped it.)"""
    def paths(with_plate):
        objects = [{"name": "box", "material": "metal", "shape": "box",
                    "extents": [4.0, 2.0, 12.0], "position": [12.0, 1.0, 6.0]}]
        if with_plate:
            objects.append({"name": "plate", "material": "metal", "shape": "plane",
                            "size": [10.0, 3.0], "position": [5.0, -1.0, 6.5],
                            "rotation_deg": [0.0, -90.0, 0.0]})
        scene = scene_from_dict({
            "scene": {"name": "hidden", "carrier_hz": 24e9}, "objects": objects,
            "radars": [{"name": "tx", "role": "tx", "position": [0.0, -2.2, 0.75]},
                       {"name": "rx", "role": "rx", "position": [0.0, -1.8, 0.75]}]})
        settings = TraceSettings(specular=SpecularSettings(max_reflections=1),
                                 diffraction=DiffractionSettings(max_diffractions=1))
        p = trace_scene(scene, settings, runtime=runtime).links[0].paths
        return p, np.flatnonzero(p.interaction[:, 0] == InteractionType.DIFFRACTION)

    alone, d_alone = paths(False)
    plated, d_plated = paths(True)
    corner = [i for i in d_alone if np.allclose(alone.points[i, 1], [10.0, 0.0, 0.75])]
    assert len(corner) == 1
    i = corner[0]
    assert alone.delay_s[i] * 1e9 == pytest.approx(68.047, abs=1e-3)
    assert 20 * np.log10(abs(alone.gain[i])) == pytest.approx(-118.33, abs=0.01)
    expected = [i for i in d_alone
                if not _segment_hits_rectangle_x(alone.points[i, 0], alone.points[i, 1], 5.0,
                                                 (-2.5, 0.5), (1.5, 11.5))
                and not _segment_hits_rectangle_x(alone.points[i, 1], alone.points[i, 2], 5.0,
                                                  (-2.5, 0.5), (1.5, 11.5))]
    assert i in expected
    for i in expected:
        match = [j for j in d_plated if np.allclose(plated.points[j, 1], alone.points[i, 1])]
        assert len(match) == 1, alone.points[i, 1]
        j = match[0]
        assert plated.delay_s[j] == alone.delay_s[i]
        assert plated.gain[j] == pytest.approx(alone.gain[i], rel=1e-12)


def test_wedges_seeing_never_drops_a_visible_edge(runtime):
    """The candidate filter only over-accepts: on a scene of boxes, a tessellated wall, a
    screen with a gap and a plate, every wedge of which any of 1000 points along the edge
    sees the antenna (the same sight lines, cast one by one) is kept, whatever hides its
    quarter points; a box wholly behind the big wall is dropped (the filter still filters)."""
    objects = [
        {"name": "near", "material": "metal", "shape": "box", "extents": [1.0, 1.0, 3.0],
         "position": [4.0, 0.5, 1.5]},
        {"name": "far", "material": "metal", "shape": "box", "extents": [2.0, 3.0, 6.0],
         "position": [12.0, -1.0, 3.0]},
        {"name": "hidden", "material": "metal", "shape": "box", "extents": [1.0, 1.0, 1.0],
         "position": [20.0, 8.0, 0.5]},
        {"name": "wall", "material": "concrete_building", "shape": "plane", "size": [6.0, 10.0],
         "position": [16.0, 8.0, 2.0], "rotation_deg": [0.0, -90.0, 0.0]},
        {"name": "left", "material": "metal", "shape": "plane", "size": [8.0, 1.2],
         "position": [8.0, -1.9, 4.0], "rotation_deg": [0.0, -90.0, 0.0]},
        {"name": "right", "material": "metal", "shape": "plane", "size": [8.0, 1.2],
         "position": [8.0, -0.5, 4.0], "rotation_deg": [0.0, -90.0, 0.0]},
    ]
    scene = scene_from_dict({"scene": {"name": "seeing", "carrier_hz": 24e9},
                             "objects": objects,
                             "radars": [{"name": "r", "position": [0.0, -1.0, 1.0]}]})
    geom = build_geometry(scene, runtime)
    wedges = extract_wedges(scene.triangles, scene.tri_object, scene.tri_material)
    p = np.asarray(scene.radars[0].position)
    kept = wedges_seeing(geom.caster, wedges, p, tri_face=geom.faces.tri_face)
    W = len(wedges)
    outside = np.array([diffraction._outside(wedges, np.array([i]), p[None] - 0.5 * (
        wedges.start[i] + wedges.end[i])[None])[0] for i in range(W)])
    seen = np.zeros(W, bool)
    idx = np.flatnonzero(outside & (wedges.length > 2 * diffraction.EDGE_CLEARANCE_M))
    for f in (np.arange(1000) + 0.5) / 1000:
        s = diffraction.EDGE_CLEARANCE_M + f * (wedges.length[idx]
                                                 - 2 * diffraction.EDGE_CLEARANCE_M)
        seen[idx[diffraction._first_blocker(geom.caster, wedges, idx, s, p) < 0]] = True
    assert seen.sum() > 10
    assert not np.any(seen & ~kept), np.flatnonzero(seen & ~kept)
    hidden = wedges.object_id == [o.name for o in scene.objects].index("hidden")
    assert hidden.any() and not np.any(kept[hidden])
