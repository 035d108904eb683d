"""Scene views: the top view coloured by material, the GLB and the self-contained HTML
page (data inline, no network), and figures that Jupyter shows inline."""

import base64
import html
import io
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import trimesh

from clradcom.errors import ArgumentError
from clradcom.paths import interaction_patterns
from clradcom.plots import material_colors, plot_top_view
from clradcom.scene import load_scene
from clradcom.snapshot import Snapshot, load_snapshot
from clradcom.views import (
    CAMERA_FOV_RAD,
    MECHANISMS,
    Y_UP,
    default_camera,
    glb_bytes,
    html_page,
    page_payload,
    path_mechanisms,
    save_glb,
    save_html,
    view,
)

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def scene():
    return load_scene(DATA / "all_mechanisms.toml")


@pytest.fixture(scope="module")
def snap():
    return load_snapshot(DATA / "all_mechanisms_v1.npz")


def test_top_view_colours_each_material_and_names_it(scene, snap, tmp_path):
    fig = plot_top_view(scene, snap, path=tmp_path / "top.png")
    ax = fig.axes[0]
    faces = ax.collections[0]
    rgb = faces.get_facecolors()[:, :3]
    z_top = scene.triangles[:, :, 2].max(axis=1)
    order = np.argsort(z_top, kind="stable")
    want = material_colors(len(scene.materials))[scene.tri_material[order]]
    np.testing.assert_allclose(rgb, want)
    assert len({tuple(c) for c in np.round(rgb, 6)}) == len(scene.materials) == 4
    # lowest first: the car's roof is drawn after the road under it
    assert np.all(np.diff(z_top[order]) >= 0)
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert legend == [m.name for m in scene.materials]
    again = plot_top_view(scene, snap, path=tmp_path / "again.png")
    assert again is not fig
    assert (tmp_path / "again.png").read_bytes() == (tmp_path / "top.png").read_bytes()


def test_figures_show_inline_in_jupyter(scene, snap):
    """IPython displays an object through its _repr_png_: real PNG bytes of the figure."""
    fig = plot_top_view(scene, snap)
    png = fig._repr_png_()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    import matplotlib.image as mpimg

    img = mpimg.imread(io.BytesIO(png))
    w, h = fig.get_size_inches() * 100
    assert img.shape[:2] == (round(h), round(w))
    assert img[..., :3].std() > 0.05  # a picture, not a blank canvas


def test_glb_loads_back_with_materials_paths_and_radars(scene, snap, tmp_path):
    path = save_glb(tmp_path / "s.glb", scene, snap, n_paths=7)
    assert path.read_bytes()[:4] == b"glTF"
    back = trimesh.load(path, file_type="glb")
    meshes = {k: g for k, g in back.geometry.items() if k.startswith("material ")}
    assert sorted(meshes) == sorted(f"material {m.name}" for m in scene.materials)
    assert sum(len(g.faces) for g in meshes.values()) == len(scene.triangles)
    for m, mat in enumerate(scene.materials):
        g = meshes[f"material {mat.name}"]
        want = scene.triangles[scene.tri_material == m].reshape(-1, 3)
        np.testing.assert_allclose(np.sort(g.vertices, axis=0), np.sort(want, axis=0),
                                   atol=1e-5)  # glTF stores float32
        assert g.visual.material.name == mat.name
        rgba = np.asarray(g.visual.material.baseColorFactor, dtype=float)
        np.testing.assert_allclose(rgba[:3] / 255, material_colors(4)[m], atol=1 / 255)
    lines = [g for k, g in back.geometry.items() if k.startswith("path ")]
    assert len(lines) == 7 and all(isinstance(g, trimesh.path.Path3D) for g in lines)
    strongest = snap.links[0].paths
    i = int(np.argmax(np.abs(strongest.gain)))
    label = next(k for k in back.geometry if k.startswith(f"path {i} "))
    want = strongest.points[i, :strongest.n_interactions[i] + 2]
    np.testing.assert_allclose(np.unique(back.geometry[label].vertices, axis=0),
                               np.unique(want, axis=0), atol=1e-5)
    assert {k for k in back.geometry if k.startswith("radar ")} == {"radar A", "radar B"}
    # every node is turned z-up -> y-up
    node = back.graph.nodes_geometry[0]
    np.testing.assert_allclose(back.graph[node][0], Y_UP, atol=1e-12)
    assert glb_bytes(scene, snap, n_paths=7) == path.read_bytes()


def decode(payload, key, dtype, width):
    return np.frombuffer(base64.b64decode(payload[key]), dtype=dtype).reshape(-1, width)


def test_html_is_self_contained_and_holds_the_data(scene, snap, tmp_path):
    page = save_html(tmp_path / "s.html", scene, snap, n_paths=5).read_text("utf-8")
    assert not re.search(r"https?://|//cdn|<link|\bsrc=|import\(|fetch\(", page)
    data = json.loads(re.search(r'<script type="application/json" id="data">(.*?)</script>',
                                page, re.S).group(1))
    assert data == page_payload(scene, snap, n_paths=5)
    np.testing.assert_array_equal(decode(data, "tri", "<f4", 9),
                                  scene.triangles.reshape(-1, 9).astype(np.float32))
    np.testing.assert_array_equal(
        decode(data, "tri_rgb", np.uint8, 3),
        np.round(material_colors(4)[scene.tri_material] * 255).astype(np.uint8))
    p = snap.links[0].paths
    order = np.argsort(-np.abs(p.gain), kind="stable")[:5]
    n_segments = int(np.sum(p.n_interactions[order] + 1))
    seg = decode(data, "seg", "<f4", 6)
    assert len(seg) == n_segments
    first = p.points[order[0], :p.n_interactions[order[0]] + 2]
    np.testing.assert_allclose(seg[0], np.concatenate(first[:2]), rtol=1e-6)
    assert [name for name, _ in data["legend"]] == [m.name for m in scene.materials]
    assert data["radar_names"] == ["A", "B"] and data["link"] == "A->A"
    assert len(page) < 60_000


def test_html_script_runs_and_draws_everything(scene, snap, tmp_path):
    """The page's own script, run by node against a recording stand-in for the browser's
    WebGL context: it decodes the inline data and draws every triangle, path segment and
    radar. (test_a_real_browser_draws_the_paths_and_radars draws it in Chromium.)"""
    node = shutil.which("node")
    if node is None:
        pytest.skip("node is not installed: the page's script is checked where it is")
    page = html_page(scene, snap, n_paths=5)
    script = page.rsplit("<script>", 1)[1].split("</script>", 1)[0]
    data = re.search(r'id="data">(.*?)</script>', page, re.S).group(1)
    harness = """
const calls=[]; const consts={TRIANGLES:4,LINES:1,POINTS:0,ARRAY_BUFFER:34962,
STATIC_DRAW:35044,FLOAT:5126,VERTEX_SHADER:35633,FRAGMENT_SHADER:35632,DEPTH_TEST:2929,
COLOR_BUFFER_BIT:16384,DEPTH_BUFFER_BIT:256};
const fakeGl=new Proxy({}, {get:(t,k)=>k in consts?consts[k]:(...a)=>{calls.push([k,a]);
  return k==="getAttribLocation"?0:{};}});
const els={data:{textContent:DATA},legend:{innerHTML:""},
  view:{clientWidth:640,clientHeight:480,width:0,height:0,getContext:()=>fakeGl,
        addEventListener(){}}};
globalThis.document={getElementById:id=>els[id]};
globalThis.window={addEventListener(){}}; globalThis.devicePixelRatio=1;
""".replace("DATA", json.dumps(data)) + script + """
const draws=calls.filter(c=>c[0]==="drawArrays").map(c=>[c[1][0],c[1][2]]);
const m=calls.find(c=>c[0]==="uniformMatrix4fv")[1][2];
console.log(JSON.stringify({draws, legend:els.legend.innerHTML, finite:m.every(isFinite)}));
"""
    (tmp_path / "page.js").write_text(harness)
    run = subprocess.run([node, str(tmp_path / "page.js")], capture_output=True, text=True,
                         timeout=60)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    p = snap.links[0].paths
    order = np.argsort(-np.abs(p.gain), kind="stable")[:5]
    assert out["draws"] == [[4, 3 * len(scene.triangles)],
                            [1, 2 * int(np.sum(p.n_interactions[order] + 1))],
                            [0, len(scene.radars)]]
    assert out["finite"]
    for m in scene.materials:
        assert m.name in out["legend"]


def test_views_refuse_bad_arguments(scene, snap):
    with pytest.raises(ArgumentError, match="n_paths"):
        html_page(scene, snap, n_paths=-1)
    with pytest.raises(ArgumentError, match="link.*TX->RX"):
        html_page(scene, snap, link="AB")
    with pytest.raises(ArgumentError, match="link.*no link 'B' -> 'B'"):
        glb_bytes(scene, snap, link="B->B")
    assert page_payload(scene, None)["paths"] == 0  # the scene alone


def _box(lo, hi):
    """The 12 triangles of an axis-aligned box."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    c = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                  [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]])
    faces = [(0, 1, 2), (0, 2, 3), (4, 5, 6), (4, 6, 7), (0, 1, 5), (0, 5, 4),
             (1, 2, 6), (1, 6, 5), (2, 3, 7), (2, 7, 6), (3, 0, 4), (3, 4, 7)]
    return c[np.array(faces)]


def _blocked(eye, points, triangles):
    """Whether the segment from eye to each point crosses a triangle (Moller-Trumbore)."""
    out = []
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    e1, e2 = b - a, c - a
    for p in points:
        d = p - eye
        h = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, h)
        ok = np.abs(det) > 1e-12
        f = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = eye - a
        u = f * np.einsum("ij,ij->i", s, h)
        q = np.cross(s, e1)
        v = f * (q @ d)
        t = f * np.einsum("ij,ij->i", e2, q)
        out.append(bool(np.any(ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-6)
                               & (t < 1 - 1e-6))))
    return np.array(out)


def test_default_camera_sees_the_paths_in_a_street_canyon():
    # a street along x between two 18 m buildings, a radar on the right lane and paths to
    # cars 10-40 m ahead (and back): the camera looks from above along the street
    buildings = np.concatenate([_box((-10, 8, 0), (60, 20, 18)),
                                _box((-10, -20, 0), (60, -8, 18))])
    radar = np.array([[0.0, -1.75, 0.5]])
    ends = np.array([[10, 1.75, 0.8], [20, -1.75, 0.8], [30, 1.75, 0.8], [40, -1.75, 0.8]])
    path_points = np.concatenate([np.linspace(radar[0], e, 6) for e in ends])
    cam = default_camera(path_points, radar, buildings.reshape(-1, 3))
    lo, hi = path_points.min(axis=0), path_points.max(axis=0)
    eye, target = cam["eye"], cam["target"]
    np.testing.assert_allclose(target, (lo + hi) / 2)
    assert eye[2] > 18.0  # above the roofs
    assert eye[0] < lo[0]  # behind the radar, looking along the street
    # every corner of the paths' box lies inside the view's opening
    look = (target - eye) / np.linalg.norm(target - eye)
    for corner in np.array(np.meshgrid(*zip(lo, hi, strict=True))).T.reshape(-1, 3):
        to = (corner - eye) / np.linalg.norm(corner - eye)
        assert np.arccos(np.clip(to @ look, -1, 1)) < CAMERA_FOV_RAD / 2
    # no path point is hidden behind a building
    assert not _blocked(eye, path_points, buildings).any()
    # the page's camera of before (yaw -0.6, pitch 0.6 about the centre of everything)
    # had half of them behind the buildings
    everything = np.concatenate([buildings.reshape(-1, 3), path_points])
    centre = (everything.min(axis=0) + everything.max(axis=0)) / 2
    size = (everything.max(axis=0) - everything.min(axis=0)).max()
    old = centre + 1.2 * size * np.array([np.cos(0.6) * np.cos(-0.6),
                                          np.cos(0.6) * np.sin(-0.6), np.sin(0.6)])
    assert _blocked(old, path_points, buildings).mean() > 0.3


def test_paths_coloured_by_mechanism_with_a_legend(scene, snap):
    assert path_mechanisms(["", "R", "RR", "P", "B", "RD", "SR", "DS"]) == [
        "line of sight", "reflection", "reflection", "physical optics / SBR",
        "physical optics / SBR", "diffraction", "scattering", "scattering"]
    data = page_payload(scene, snap, n_paths=50)
    p = snap.links[0].paths
    order = np.argsort(-np.abs(p.gain), kind="stable")[:50]
    kinds = path_mechanisms([interaction_patterns(p)[i] for i in order])
    colour = dict(MECHANISMS)
    want = np.concatenate([np.repeat([colour[k]], p.n_interactions[i] + 1, axis=0)
                           for k, i in zip(kinds, order, strict=True)])
    np.testing.assert_array_equal(decode(data, "seg_kind_rgb", np.uint8, 3),
                                  np.round(want * 255).astype(np.uint8))
    assert [name for name, _ in data["mechanisms"]] == [
        m for m, _ in MECHANISMS if m in set(kinds)]
    assert len(data["mechanisms"]) >= 3  # the all-mechanisms scene has several
    cam = data["camera"]
    assert cam["dist"] > 0 and 0 < cam["pitch"] < np.pi / 2


def test_top_view_title_says_what_it_draws(scene, snap):
    fig = plot_top_view(scene, snap, n_paths=5)
    assert fig.axes[0].get_title() == "all_mechanisms: top view, 5 strongest paths of A->A"
    empty = Snapshot(scene_name=scene.name, carrier_hz=float(scene.carrier_hz),
                     scene_hash=scene.content_hash(), links=(), metadata={})
    title = plot_top_view(scene, empty).axes[0].get_title()
    assert "strongest" not in title and "no snapshot" in title


def test_view_shows_inline_in_jupyter_offline(scene, snap, tmp_path):
    v = view(scene, snap, n_paths=5)
    frame = v._repr_html_()
    assert frame.startswith("<iframe srcdoc=") and "http" not in frame
    assert html.unescape(frame.split('srcdoc="', 1)[1].split('" style=', 1)[0]) == \
        html_page(scene, snap, n_paths=5)
    assert "all_mechanisms" in repr(v) and len(repr(v)) < 100
    assert v.save(tmp_path / "v.html").read_text("utf-8") == html_page(scene, snap, n_paths=5)


def _screenshot(page: str, folder: Path, name: str) -> np.ndarray:
    """The page drawn by headless Chromium (WebGL through SwiftShader), its text overlay
    hidden so that only the canvas counts: (H, W, 3) uint8."""
    browser = shutil.which("chromium-headless-shell") or shutil.which("chromium")
    if browser is None:
        pytest.skip("Chromium is not installed: the page is drawn where it is (.ci/run "
                    "installs chromium-headless-shell)")
    from PIL import Image

    html_file, png = folder / f"{name}.html", folder / f"{name}.png"
    html_file.write_text(page.replace("</head>", "<style>#info{display:none}</style></head>",
                                      1), encoding="utf-8")
    subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu",
                    "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                    "--window-size=800,600", "--virtual-time-budget=3000",
                    f"--screenshot={png}", html_file.as_uri()],
                   check=True, capture_output=True, timeout=120)
    return np.asarray(Image.open(png).convert("RGB"))


def _pixels_near(image: np.ndarray, colours: np.ndarray, tol: int = 6) -> int:
    """How many pixels of ``image`` lie within ``tol`` of any of ``colours`` (N, 3)."""
    flat = image.reshape(-1, 1, 3).astype(np.int16)
    return int((np.abs(flat - colours[None].astype(np.int16)).max(axis=2) <= tol)
               .any(axis=1).sum())


def test_a_real_browser_draws_the_paths_and_radars(scene, snap, tmp_path):
    """The HTML view in headless Chromium (issue #31): the scene's triangles, the paths in
    their gain colours and the radars are on the screen from the default camera; the same
    scene without a snapshot shows none of the path colours."""
    payload = page_payload(scene, snap, n_paths=50)
    path_rgb = np.unique(np.frombuffer(base64.b64decode(payload["seg_rgb"]), np.uint8)
                         .reshape(-1, 3), axis=0)
    tri_rgb = np.unique(np.frombuffer(base64.b64decode(payload["tri_rgb"]), np.uint8)
                        .reshape(-1, 3), axis=0)
    # path colours that no material shares (the lit faces are darker shades of theirs)
    own = path_rgb[np.abs(path_rgb[:, None].astype(int) - tri_rgb[None]).max(axis=2)
                   .min(axis=1) > 40]
    assert len(own) >= 3
    radar_rgb = np.array([[230, 31, 31]])
    with_paths = _screenshot(html_page(scene, snap, n_paths=50), tmp_path, "paths")
    without = _screenshot(html_page(scene), tmp_path, "none")
    background = np.array([[245, 245, 242]])
    for image in (with_paths, without):
        # WebGL drew the scene: most of the canvas is not the page's background
        assert image.shape[2] == 3 and _pixels_near(image, background, 3) < 0.8 * image[..., 0].size
        assert _pixels_near(image, radar_rgb, 12) >= 10
    drawn = _pixels_near(with_paths, own)
    assert drawn >= 150, drawn
    assert _pixels_near(without, own) < drawn / 20
