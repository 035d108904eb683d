"""Diffraction mixed with reflections and chains of 2-3 edges, through the whole tracer."""

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.special import fresnel

from clradcom.paths import InteractionType
from clradcom.physics.em import C0
from clradcom.scene.reader import scene_from_dict
from clradcom.trace import DiffractionSettings, SpecularSettings, TraceSettings, trace_scene

LAM = C0 / 24e9
D = int(InteractionType.DIFFRACTION)
R = int(InteractionType.REFLECTION)


def screen(name, x, top, width=100.0):
    """A thin PEC screen in the plane x = const whose horizontal top edge is at z = top."""
    return {"name": name, "material": "metal", "shape": "plane", "size": [width, width],
            "position": [x, 0.0, top - width / 2], "rotation_deg": [0.0, -90.0, 0.0]}


def radars(tx, rx, pol="V", roles=("tx", "rx")):
    return [{"name": "a", "role": roles[0], "position": list(tx), "polarization": pol},
            {"name": "b", "role": roles[1], "position": list(rx), "polarization": pol,
             "orientation_deg": [0.0, 0.0, 180.0]}]


def patterns_of(paths):
    return ["".join("D" if c == D else "R" for c in paths.interaction[i, :k])
            for i, k in enumerate(paths.n_interactions)]


def on_heights(paths, pattern, heights):
    """Indices of paths with this pattern whose interaction points lie at these z."""
    return [i for i, p in enumerate(patterns_of(paths)) if p == pattern
            and np.allclose(paths.points[i, 1:len(p) + 1, 2], heights, atol=1e-9)]


def knife_edge_loss_db(nu):
    """ITU-R P.526 J(nu) from the Fresnel integrals."""
    s, c = fresnel(nu)
    return -20 * np.log10(np.sqrt((1 - c - s) ** 2 + (c - s) ** 2) / 2)


def nu_of(h, d1, d2):
    return h * np.sqrt(2 / LAM * (1 / d1 + 1 / d2))


@pytest.mark.parametrize(("h1", "h2"), [(0.7, 0.7), (1.0, 0.8), (1.5, 1.5)])
def test_two_edges_match_itu_p526_two_edge_method(runtime, h1, h2):
    """Two PEC screens well in each other's shadow: the UTD double diffraction against
    ITU-R P.526 sec. 4.5.2 (L1 + L2 + Lc, valid where both edges lose more than 15 dB).
    ITU's edges are Kirchhoff's absorbing screens; a PEC half-plane's face terms add to
    the soft and subtract from the hard coefficient, so the two polarisations straddle
    ITU and their mean loss meets it."""
    a, b, c = 12.0, 8.0, 10.0
    l1 = knife_edge_loss_db(nu_of(h1 - h2 * a / (a + b), a, b))
    l2 = knife_edge_loss_db(nu_of(h2 - h1 * c / (b + c), b, c))
    assert l1 > 15 and l2 > 15
    itu = l1 + l2 + 10 * np.log10((a + b) * (b + c) / (b * (a + b + c)))
    settings = TraceSettings(specular=SpecularSettings(max_reflections=0, rays=1000),
                             diffraction=DiffractionSettings(max_diffractions=2))
    losses = {}
    for pol in ("V", "H"):
        scene = scene_from_dict({
            "scene": {"name": "two-screens", "carrier_hz": 24e9},
            "objects": [screen("s1", 0.0, h1), screen("s2", b, h2)],
            "radars": radars([-a, 0.0, 0.0], [b + c, 0.0, 0.0], pol)})
        paths = trace_scene(scene, settings, runtime=runtime).links[0].paths
        dd = on_heights(paths, "DD", [h1, h2])  # the top edges, not the screens' sides
        assert len(dd) == 1
        i = dd[0]
        d_tot = np.linalg.norm(np.diff(paths.points[i, :4], axis=0), axis=1).sum()
        assert paths.delay_s[i] == pytest.approx(d_tot / C0, rel=1e-12)
        np.testing.assert_allclose(paths.points[i, 1], [0.0, 0.0, h1], atol=1e-9)
        np.testing.assert_allclose(paths.points[i, 2], [b, 0.0, h2], atol=1e-9)
        losses[pol] = -20 * np.log10(np.abs(paths.gain[i]) / (LAM / (4 * np.pi * d_tot)))
    assert losses["V"] < itu < losses["H"]
    assert losses["H"] - losses["V"] < 3.0
    assert 0.5 * (losses["V"] + losses["H"]) == pytest.approx(itu, abs=0.1)


def _keller_residuals(points, n):
    """|s_in . e - s_out . e| at every interior point, e taken as the edge (here y)."""
    out = []
    for j in range(1, n + 1):
        s_in = points[j] - points[j - 1]
        s_out = points[j + 1] - points[j]
        out.append(abs(s_in[1] / np.linalg.norm(s_in) - s_out[1] / np.linalg.norm(s_out)))
    return np.array(out)


def test_three_skewed_edges_obey_keller_and_match_brute_force(runtime):
    """Three screens with oblique tx/rx: each traced point satisfies Keller's law and the
    chain equals a brute-force minimisation of the path length over the three edges."""
    xs, tops = (0.0, 3.0, 6.0), (0.5, 0.55, 0.45)
    tx = np.array([-6.0, -2.0, 0.0])
    rx = np.array([12.0, 3.0, 0.1])
    scene = scene_from_dict({
        "scene": {"name": "three-screens", "carrier_hz": 24e9},
        "objects": [screen(f"s{k}", x, z, 40.0)
                    for k, (x, z) in enumerate(zip(xs, tops, strict=True))],
        "radars": radars(tx, rx)})
    settings = TraceSettings(
        specular=SpecularSettings(max_reflections=0, rays=1000),
        diffraction=DiffractionSettings(max_diffractions=3, max_reflections=0, max_hop_m=5.0))
    paths = trace_scene(scene, settings, runtime=runtime).links[0].paths
    ddd = on_heights(paths, "DDD", tops)
    assert len(ddd) == 1
    pts = paths.points[ddd[0], :5]
    assert _keller_residuals(pts, 3).max() < 1e-9

    def length(y):
        nodes = [tx] + [np.array([x, yy, z]) for x, yy, z in zip(xs, y, tops, strict=True)] + [rx]
        return sum(np.linalg.norm(q - p) for p, q in zip(nodes[:-1], nodes[1:], strict=True))

    best = minimize(length, np.zeros(3), method="Nelder-Mead",
                    options={"xatol": 1e-10, "fatol": 1e-13, "maxiter": 20000})
    np.testing.assert_allclose(pts[1:4, 1], best.x, atol=1e-5)
    assert paths.delay_s[ddd[0]] * C0 == pytest.approx(best.fun, rel=1e-10)


def ground(size=200.0):
    return {"name": "ground", "material": "metal", "shape": "plane", "size": [size, size],
            "position": [0.0, 0.0, -1.0]}


def test_reflection_after_an_edge_equals_the_edge_seen_from_the_image(runtime):
    """Screen on a PEC ground: the edge -> ground -> rx path carries what the edge sends
    to rx's image below the ground (a PEC mirror preserves the transverse field), with
    the unfolded delay and its reflection point on the ground."""
    tx = [-10.0, 0.0, 0.0]
    rx = [10.0, 0.0, 0.5]
    rx_image = [10.0, 0.0, -2.5]
    base = {"scene": {"name": "edge-ground", "carrier_hz": 24e9}}
    with_ground = scene_from_dict({**base, "objects": [screen("s", 0.0, 0.3, 60.0), ground()],
                                   "radars": radars(tx, rx)})
    image = scene_from_dict({**base, "objects": [screen("s", 0.0, 0.3, 60.0)],
                             "radars": radars(tx, rx_image)})
    settings = TraceSettings(specular=SpecularSettings(max_reflections=1, rays=50_000),
                             diffraction=DiffractionSettings(max_diffractions=1,
                                                             max_reflections=1))
    p = trace_scene(with_ground, settings, runtime=runtime).links[0].paths
    q = trace_scene(image, settings, runtime=runtime).links[0].paths
    dr = on_heights(p, "DR", [0.3, -1.0])
    rd = on_heights(p, "RD", [-1.0, 0.3])
    d_img = on_heights(q, "D", [0.3])
    assert len(dr) == 1 and len(rd) == 1 and len(d_img) == 1
    i, j = dr[0], d_img[0]
    assert p.delay_s[i] == pytest.approx(q.delay_s[j], rel=1e-12)
    assert np.linalg.norm(p.matrix[i]) == pytest.approx(np.linalg.norm(q.matrix[j]), rel=1e-9)
    assert p.points[i, 2, 2] == pytest.approx(-1.0, abs=1e-9)  # on the ground
    np.testing.assert_allclose(p.points[i, 1], q.points[j, 1], atol=1e-9)
    # the tx-side mirror path is a different path: longer tx leg, shorter rx leg
    assert p.delay_s[rd[0]] != pytest.approx(p.delay_s[i], rel=1e-6)


def test_mixed_paths_are_reciprocal(runtime):
    """A box on a ground plane, tx and rx on opposite sides, out of plane: every mixed
    path of a -> b has a partner in b -> a with the reversed sequence, the same delay and
    the same co-polar gain (reciprocity of the dyads)."""
    objects = [ground(),
               {"name": "box", "material": "metal", "shape": "box",
                "extents": [2.0, 3.0, 1.5], "position": [0.0, 0.3, -0.25]}]
    spec = {"scene": {"name": "box", "carrier_hz": 24e9}, "objects": objects,
            "radars": radars([-6.0, -1.5, 0.2], [5.0, 2.0, 0.1], roles=("txrx", "txrx"))}
    scene = scene_from_dict(spec)
    settings = TraceSettings(specular=SpecularSettings(max_reflections=1, rays=100_000),
                             diffraction=DiffractionSettings(max_diffractions=2,
                                                             max_reflections=1))
    snap = trace_scene(scene, settings, runtime=runtime)
    ab, ba = snap.link("a", "b").paths, snap.link("b", "a").paths
    diffracted_ab = [i for i, s in enumerate(patterns_of(ab)) if "D" in s]
    diffracted_ba = [i for i, s in enumerate(patterns_of(ba)) if "D" in s]
    kinds = {patterns_of(ab)[i] for i in diffracted_ab}
    assert {"D", "DR", "RD", "DD"} <= kinds
    assert len(diffracted_ab) == len(diffracted_ba)
    for i in diffracted_ab:
        k = ab.n_interactions[i]
        cand = [j for j in diffracted_ba if ba.n_interactions[j] == k
                and np.array_equal(ba.object_id[j, :k], ab.object_id[i, :k][::-1])
                and abs(ba.delay_s[j] - ab.delay_s[i]) < 1e-15]
        assert len(cand) == 1, (patterns_of(ab)[i], ab.delay_s[i])
        j = cand[0]
        np.testing.assert_allclose(ba.points[j, :k + 2][::-1], ab.points[i, :k + 2],
                                   atol=1e-9)
        assert ba.gain[j] == pytest.approx(ab.gain[i], rel=1e-9, abs=1e-18)


def test_settings_refuse_budgets_out_of_range():
    with pytest.raises(ValueError, match=r"^DiffractionSettings\.max_reflections = -1: must"):
        DiffractionSettings(max_reflections=-1)
    with pytest.raises(ValueError, match=r"^DiffractionSettings\.max_hop_m = 0\.0: must"):
        DiffractionSettings(max_hop_m=0.0)
    with pytest.raises(ValueError, match=r"^DiffractionSettings\.max_chains = 0: must"):
        DiffractionSettings(max_chains=0)
