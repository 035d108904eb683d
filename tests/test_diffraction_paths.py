"""First-order UTD diffraction through the whole tracer, against closed forms."""

import numpy as np
import pytest

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
