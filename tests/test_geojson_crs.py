"""A GeoJSON file's "crs" is honoured or refused by name (issue #28): a footprint in
EPSG:3857 (Web Mercator) metres was read as degrees, a 10 m square 1,107 km wide."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from clradcom.errors import SceneError
from clradcom.scene import load_scene
from clradcom.scene.geojson import WGS84_A

ORIGIN = (11.5755, 48.1374)   # lon, lat (deg)

SCENE = """\
[scene]
name = "crs"
carrier_hz = 24e9

[[objects]]
name = "block"
geojson = "b.geojson"
material = "itu_concrete"
{extra}

[[radars]]
name = "radar"
position = [-30.0, 0.0, 1.0]
role = "txrx"
"""


def _mercator(lon, lat):
    """Spherical Web Mercator (EPSG:3857) of lon/lat in degrees: x = R lon,
    y = R ln tan(pi/4 + lat/2), R the WGS 84 semi-major axis."""
    return (WGS84_A * math.radians(lon),
            WGS84_A * math.log(math.tan(math.pi / 4 + math.radians(lat) / 2)))


def _write(tmp_path, ring, crs, extra='origin_lonlat = [11.5755, 48.1374]'):
    doc = {"type": "FeatureCollection", "features": [{
        "type": "Feature", "properties": {"height": 10},
        "geometry": {"type": "Polygon", "coordinates": [ring]}}]}
    if crs is not None:
        doc["crs"] = {"type": "name", "properties": {"name": crs}}
    (tmp_path / "b.geojson").write_text(json.dumps(doc))
    path = tmp_path / "scene.toml"
    path.write_text(SCENE.format(extra=extra))
    return path


def _square(x0, y0, side):
    return [[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side], [x0, y0]]


def test_a_web_mercator_square_is_reprojected_to_its_true_size(tmp_path):
    x0, y0 = _mercator(*ORIGIN)
    scene = load_scene(_write(tmp_path, _square(x0, y0, 10.0), "EPSG:3857"))
    v = scene.triangles.reshape(-1, 3)
    width, depth = np.ptp(v[:, 0]), np.ptp(v[:, 1])
    # Mercator stretches both axes by sec(lat): 10 Mercator metres are 10 cos(lat) m
    true = 10.0 * math.cos(math.radians(ORIGIN[1]))
    assert width == pytest.approx(true, rel=5e-3)
    assert depth == pytest.approx(true, rel=5e-3)
    # its corner is the origin
    assert np.abs(v[:, :2].min(axis=0)).max() < 0.05


def test_a_file_naming_wgs84_reads_as_one_without_a_crs(tmp_path):
    ring = _square(ORIGIN[0], ORIGIN[1], 1e-4)
    plain = load_scene(_write(tmp_path, ring, None)).triangles
    for name in ("urn:ogc:def:crs:OGC:1.3:CRS84", "EPSG:4326"):
        named = load_scene(_write(tmp_path, ring, name)).triangles
        np.testing.assert_allclose(named, plain, atol=1e-6)


def test_an_unknown_crs_is_refused_by_name(tmp_path):
    path = _write(tmp_path, _square(0, 0, 10), "EPSG:999999")
    with pytest.raises(SceneError, match=r"crs 'EPSG:999999' is not a coordinate reference"):
        load_scene(path)


def test_a_crs_beside_local_metres_is_refused(tmp_path):
    path = _write(tmp_path, _square(0, 0, 10), "EPSG:3857", extra='coordinates = "metres"')
    with pytest.raises(SceneError, match=r"names its coordinate system 'EPSG:3857'.*"
                                         r"coordinates = 'metres'"):
        load_scene(path)


def test_a_linked_crs_is_refused(tmp_path):
    path = _write(tmp_path, _square(*ORIGIN, 1e-4), None)
    doc = json.loads((tmp_path / "b.geojson").read_text())
    doc["crs"] = {"type": "link", "properties": {"href": "http://example.com/crs"}}
    (tmp_path / "b.geojson").write_text(json.dumps(doc))
    with pytest.raises(SceneError, match=r"is not a named CRS"):
        load_scene(path)


def test_a_footprint_of_many_corners_is_announced_before_it_is_built(tmp_path,
                                                                      monkeypatch):
    """A 1e6-corner footprint took minutes to load without a word (issue #28): from
    LARGE_FOOTPRINT_CORNERS on, a warning names the feature, its corners and the
    triangles to come before the extrusion starts."""
    import warnings

    from clradcom.errors import SceneWarning
    from clradcom.scene import geojson
    n = 2000   # the rule, at a size a test builds in a moment
    monkeypatch.setattr(geojson, "LARGE_FOOTPRINT_CORNERS", n)
    a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    ring = np.column_stack([20 * np.cos(a), 20 * np.sin(a)]).tolist()
    path = _write(tmp_path, ring + ring[:1], None, extra='coordinates = "metres"')
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = load_scene(path)
    texts = [str(w.message) for w in caught if issubclass(w.category, SceneWarning)]
    assert any(f"feature 0 of {tmp_path / 'b.geojson'} has {n + 1:,} corners" in t
               for t in texts), texts
    assert len(scene.triangles) > 2 * n
    # a small footprint says nothing of the kind
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_scene(_write(tmp_path, _square(0, 0, 10), None, extra='coordinates = "metres"'))
    assert not any("corners" in str(w.message) for w in caught)
