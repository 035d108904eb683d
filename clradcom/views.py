"""3-D views of a scene and a link's paths: a GLB file (glTF 2.0, any glTF viewer) and a
self-contained interactive HTML page (plain WebGL written here, data inline, nothing
fetched from the network: it opens offline).

Both colour the scene by material (:func:`clradcom.plots.material_colors`, the colours of
the top view) and the paths by gain (viridis, strongest ``n_paths`` of one link), and mark
the radars; the HTML page can colour the paths by mechanism instead (its legend names
them) and opens on a camera fitted to the paths (:func:`default_camera`: from above, at
an angle, along their longer horizontal axis, so buildings beside a street do not hide
them). :class:`View` shows the page inline in Jupyter. The scene is z-up
(docs/architecture.md); glTF is y-up, so the GLB's nodes carry the rotation x -> x,
y -> -z, z -> y and its meshes keep the scene's coordinates.
"""

from __future__ import annotations

import base64
import html
import json
import os
from pathlib import Path

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.files import atomic_write
from clradcom.paths import interaction_patterns
from clradcom.plots import material_colors

__all__ = ["CAMERA_FOV_RAD", "MECHANISMS", "View", "Y_UP", "default_camera", "glb_bytes",
           "html_page", "map_quads", "path_mechanisms", "save_glb", "save_html", "view",
           "view_data"]

#: glTF node transform of every geometry: the scene's z-up to glTF's y-up.
Y_UP = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])

#: Radius of the sphere that marks a radar in the GLB (m).
RADAR_MARKER_M = 0.3

#: a path's mechanism (the first that it holds, in this order) and its colour
#: (Okabe & Ito's colour-blind-safe palette)
MECHANISMS = (("scattering", (0.80, 0.47, 0.65)), ("diffraction", (0.0, 0.62, 0.45)),
              ("physical optics / SBR", (0.90, 0.62, 0.0)), ("reflection", (0.0, 0.45, 0.70)),
              ("line of sight", (0.35, 0.35, 0.35)))
_MECHANISM_LETTERS = {"scattering": "S", "diffraction": "D", "physical optics / SBR": "PB",
                      "reflection": "R"}

#: full vertical opening of the HTML page's camera (rad; its JavaScript uses the same)
CAMERA_FOV_RAD = 0.8
#: the default camera looks down at the paths at this elevation (rad, 55 deg)
CAMERA_ELEVATION_RAD = 0.96


def path_mechanisms(patterns) -> list[str]:
    """Each path's mechanism (:data:`MECHANISMS`) from its interaction pattern
    (:func:`clradcom.paths.interaction_patterns`): scattering over diffraction over PO/SBR
    over reflection; "line of sight" for none."""
    out = []
    for pattern in patterns:
        name = next((m for m, _ in MECHANISMS[:-1]
                     if any(c in pattern for c in _MECHANISM_LETTERS[m])), MECHANISMS[-1][0])
        out.append(name)
    return out


def default_camera(path_points, radar_positions, scene_points) -> dict:
    """The HTML view's opening camera: it looks at the centre of the paths' bounding box
    (the radars' where there are no paths, the scene's where there are no radars either)
    from ``CAMERA_ELEVATION_RAD`` above the horizon, from the side of its longer
    horizontal axis where the radars are, far enough that the box's bounding sphere fills
    the vertical opening ``CAMERA_FOV_RAD`` with a 10 % margin. Returns ``target``,
    ``eye`` (3,), ``yaw``, ``pitch`` (rad; eye = target + dist (cos p cos y, cos p sin y,
    sin p)) and ``dist`` (m)."""
    for pts in (path_points, radar_positions, scene_points):
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
        if len(pts):
            break
    else:
        pts = np.zeros((1, 3))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    target = (lo + hi) / 2.0
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1.0)
    dist = 1.1 * radius / np.sin(CAMERA_FOV_RAD / 2.0)
    axis = 0 if hi[0] - lo[0] >= hi[1] - lo[1] else 1
    radars = np.asarray(radar_positions, dtype=np.float64).reshape(-1, 3)
    side = -1.0 if not len(radars) or radars[:, axis].mean() <= target[axis] else 1.0
    yaw = float(np.arctan2(0.0, side)) if axis == 0 else float(np.arctan2(side, 0.0))
    pitch = CAMERA_ELEVATION_RAD
    eye = target + dist * np.array([np.cos(pitch) * np.cos(yaw),
                                    np.cos(pitch) * np.sin(yaw), np.sin(pitch)])
    return {"target": target, "eye": eye, "yaw": yaw, "pitch": float(pitch),
            "dist": float(dist)}


def _check_n_paths(n_paths) -> int:
    if isinstance(n_paths, bool) or not isinstance(n_paths, int | np.integer) or n_paths < 0:
        raise ArgumentError("must be an integer >= 0", argument="n_paths", value=n_paths)
    return int(n_paths)


def _pick_link(snapshot, link):
    if snapshot is None:
        return None
    if link is None:
        return snapshot.links[0] if len(snapshot.links) else None
    if isinstance(link, str):
        tx, sep, rx = link.partition("->")
        if not sep:
            raise ArgumentError("must name a link as 'TX->RX'", argument="link", value=link)
        try:
            return snapshot.link(tx, rx)
        except KeyError as exc:
            raise ArgumentError(str(exc.args[0]), argument="link", value=link) from None
    return link


def view_data(scene, snapshot=None, link=None, n_paths: int = 50) -> dict:
    """What both views draw, as plain arrays: ``triangles`` (T, 3, 3) and
    ``triangle_rgb`` (T, 3) in 0..1; per material ``materials`` (names) and
    ``material_rgb``; the link's strongest ``n_paths`` paths as ``paths`` (list of (n, 3)
    polylines), ``path_db`` (gain in dB), ``path_rgb`` (viridis over the dB span),
    ``path_labels``, ``path_mechanism`` (:func:`path_mechanisms`) and ``path_kind_rgb``;
    ``radars`` (names) and ``radar_positions`` (R, 3); ``link`` ("TX->RX" or "")."""
    from matplotlib import colormaps  # plotting is optional for the rest of the package

    n_paths = _check_n_paths(n_paths)
    link = _pick_link(snapshot, link)
    mat_rgb = material_colors(len(scene.materials))
    tri_mat = np.asarray(scene.tri_material, dtype=np.int64)
    out = {
        "triangles": np.asarray(scene.triangles, dtype=np.float64),
        "triangle_rgb": mat_rgb[tri_mat],
        "materials": [m.name for m in scene.materials],
        "material_rgb": mat_rgb,
        "material_used": np.isin(np.arange(len(scene.materials)), tri_mat),
        "radars": [r.name for r in scene.radars],
        "radar_positions": np.array([r.position for r in scene.radars],
                                    dtype=np.float64).reshape(-1, 3),
        "paths": [], "path_db": np.zeros(0), "path_rgb": np.zeros((0, 3)),
        "path_labels": [], "path_mechanism": [], "path_kind_rgb": np.zeros((0, 3)),
        "link": "",
    }
    if link is not None and link.paths.n_paths and n_paths:
        p = link.paths
        order = np.argsort(-np.abs(p.gain), kind="stable")[:n_paths]
        with np.errstate(divide="ignore"):
            db = 20.0 * np.log10(np.abs(p.gain[order]))
        db = np.where(np.isfinite(db), db, -400.0)
        span = max(float(db.max() - db.min()), 1e-9)
        rgb = colormaps["viridis"]((db - db.min()) / span)[:, :3]
        patterns = interaction_patterns(p)
        kinds = path_mechanisms([patterns[i] for i in order])
        colour = dict(MECHANISMS)
        out.update(
            path_mechanism=kinds,
            path_kind_rgb=np.array([colour[k] for k in kinds], dtype=np.float64),
            paths=[p.points[i, :p.n_interactions[i] + 2].copy() for i in order],
            path_db=db, path_rgb=rgb, link=link.label,
            path_labels=[f"path {int(i)} {patterns[i] or 'LoS'} {d:.1f} dB"
                         for i, d in zip(order, db, strict=True)])
    return out


# ---------------------------------------------------------------------------------------
# GLB


def _rgba8(rgb) -> list[int]:
    return [int(round(255 * float(c))) for c in rgb] + [255]


def glb_bytes(scene, snapshot=None, link=None, n_paths: int = 50) -> bytes:
    """The GLB: one mesh per material (named ``material <name>``, a PBR material of that
    name and colour), one line geometry per path (``path <i> <pattern> <dB> dB``), one
    sphere per radar (``radar <name>``)."""
    import trimesh  # a dependency; imported where it is used (it is slow to import)

    d = view_data(scene, snapshot, link, n_paths)
    out = trimesh.Scene()
    tri = d["triangles"]
    tri_mat = np.asarray(scene.tri_material, dtype=np.int64)
    for m, name in enumerate(d["materials"]):
        mask = tri_mat == m
        if not mask.any():
            continue
        verts = tri[mask].reshape(-1, 3)
        mesh = trimesh.Trimesh(vertices=verts, faces=np.arange(len(verts)).reshape(-1, 3),
                               process=False)
        mesh.visual = trimesh.visual.TextureVisuals(
            material=trimesh.visual.material.PBRMaterial(
                name=name, baseColorFactor=_rgba8(d["material_rgb"][m]),
                metallicFactor=0.0, roughnessFactor=1.0, doubleSided=True))
        out.add_geometry(mesh, geom_name=f"material {name}", node_name=f"material {name}",
                         transform=Y_UP)
    for line, rgb, label in zip(d["paths"], d["path_rgb"], d["path_labels"], strict=True):
        color = np.array([_rgba8(rgb)], dtype=np.uint8)
        path = trimesh.path.Path3D(entities=[trimesh.path.entities.Line(
            np.arange(len(line)))], vertices=line, colors=color)
        out.add_geometry(path, geom_name=label, node_name=label, transform=Y_UP)
    for name, pos in zip(d["radars"], d["radar_positions"], strict=True):
        ball = trimesh.creation.icosphere(subdivisions=1, radius=RADAR_MARKER_M)
        ball.apply_translation(pos)
        ball.visual = trimesh.visual.TextureVisuals(
            material=trimesh.visual.material.PBRMaterial(
                name=f"radar {name}", baseColorFactor=[230, 30, 30, 255]))
        out.add_geometry(ball, geom_name=f"radar {name}", node_name=f"radar {name}",
                         transform=Y_UP)
    return out.export(file_type="glb")


def save_glb(path: str | os.PathLike, scene, snapshot=None, link=None, n_paths: int = 50,
             *, inputs=()) -> Path:
    """Write :func:`glb_bytes` to ``path`` atomically. Returns the path."""
    data = glb_bytes(scene, snapshot, link, n_paths)
    return atomic_write(path, lambda fh: fh.write(data), inputs=inputs)


# ---------------------------------------------------------------------------------------
# HTML


def _b64(array, dtype) -> str:
    return base64.b64encode(np.ascontiguousarray(array, dtype=dtype).tobytes()).decode()


def _hex(rgb) -> str:
    return "#" + "".join(f"{int(round(255 * float(c))):02x}" for c in rgb)


def map_quads(grid, values_db, cmap: str = "viridis"):
    """(triangles (2C, 3, 3) float, rgb (2C, 3) in 0..1, (vmin, vmax)) of a radio map's
    cells that hold a value: two triangles per cell at the layer's height, coloured by
    ``cmap`` over the values' 1st percentile to maximum (as
    :func:`clradcom.plots.plot_radio_map` scales them)."""
    from matplotlib import colormaps

    values = np.asarray(values_db, dtype=np.float64)
    if values.shape != (grid.ny, grid.nx):
        raise ArgumentError(f"must be a (ny, nx) = ({grid.ny}, {grid.nx}) array",
                            argument="values_db", value=values.shape)
    iy, ix = np.nonzero(np.isfinite(values))
    if not len(iy):
        return np.zeros((0, 3, 3)), np.zeros((0, 3)), (0.0, 0.0)
    v = values[iy, ix]
    lo, hi = float(np.percentile(v, 1)), float(v.max())
    x0 = grid.x_min + grid.cell_m * ix
    y0 = grid.y_min + grid.cell_m * iy
    x1, y1 = x0 + grid.cell_m, y0 + grid.cell_m
    z = np.full_like(x0, grid.height_m)
    corners = [np.stack([a, b, z], axis=1) for a, b in ((x0, y0), (x1, y0), (x1, y1),
                                                         (x0, y1))]
    tri = np.concatenate([np.stack([corners[0], corners[1], corners[2]], axis=1),
                          np.stack([corners[0], corners[2], corners[3]], axis=1)])
    rgb = colormaps[cmap](np.clip((v - lo) / max(hi - lo, 1e-12), 0.0, 1.0))[:, :3]
    return tri, np.concatenate([rgb, rgb]), (lo, hi)


def page_payload(scene, snapshot=None, link=None, n_paths: int = 50,
                 radio_map=None) -> dict:
    """The JSON the page embeds: little-endian float32 positions and uint8 colours as
    base64 (``tri``: T x 9 floats, ``tri_rgb``: T x 3 bytes, ``seg``: S x 6 floats,
    ``seg_rgb``: S x 3 bytes, ``radar``: R x 3 floats), names and the legend; with
    ``radio_map`` = (grid, values_db, label) also the map's cells as unlit coloured
    quads (``map``, ``map_rgb``, ``map_label``, ``map_range``: :func:`map_quads`)."""
    d = view_data(scene, snapshot, link, n_paths)
    segs = [np.stack([line[:-1], line[1:]], axis=1) for line in d["paths"]]
    seg = np.concatenate(segs).reshape(-1, 6) if segs else np.zeros((0, 6))
    seg_rgb, seg_kind_rgb = ((np.concatenate([np.repeat(rgb[None], len(s), axis=0)
                                              for rgb, s in zip(d[key], segs, strict=True)])
                              if segs else np.zeros((0, 3)))
                             for key in ("path_rgb", "path_kind_rgb"))
    cam = default_camera(np.concatenate(d["paths"]) if d["paths"] else np.zeros((0, 3)),
                         d["radar_positions"], d["triangles"].reshape(-1, 3))
    present = set(d["path_mechanism"])
    extra = {"map": "", "map_rgb": "", "map_label": "", "map_range": []}
    if radio_map is not None:
        grid, values_db, label = radio_map
        quads, rgb, (lo, hi) = map_quads(grid, values_db)
        extra = {"map": _b64(quads.reshape(-1, 9), "<f4"),
                 "map_rgb": _b64(np.round(rgb * 255), np.uint8), "map_label": str(label),
                 "map_range": [lo, hi] if len(quads) else []}
    return {
        **extra,
        "title": scene.name,
        "link": d["link"],
        "tri": _b64(d["triangles"].reshape(-1, 9), "<f4"),
        "tri_rgb": _b64(np.round(d["triangle_rgb"] * 255), np.uint8),
        "seg": _b64(seg, "<f4"),
        "seg_rgb": _b64(np.round(seg_rgb * 255), np.uint8),
        "seg_kind_rgb": _b64(np.round(seg_kind_rgb * 255), np.uint8),
        "mechanisms": [[name, _hex(rgb)] for name, rgb in MECHANISMS if name in present],
        "camera": {"target": [float(x) for x in cam["target"]], "yaw": cam["yaw"],
                   "pitch": cam["pitch"], "dist": cam["dist"]},
        "radar": _b64(d["radar_positions"], "<f4"),
        "radar_names": d["radars"],
        "legend": [[name, _hex(rgb)] for name, rgb, used in zip(
            d["materials"], d["material_rgb"], d["material_used"], strict=True) if used],
        "paths": len(d["paths"]),
        "db_range": ([float(d["path_db"].min()), float(d["path_db"].max())]
                     if len(d["path_db"]) else []),
    }


_PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<title>@TITLE@</title>
<style>
html,body{margin:0;height:100%;font:13px sans-serif;background:#f4f4f2;overflow:hidden}
canvas{width:100%;height:100%;display:block;cursor:grab}
#info{position:absolute;left:8px;top:8px;background:rgba(255,255,255,.88);padding:6px 9px;
border-radius:4px;max-width:40%}
#info i{display:inline-block;width:11px;height:11px;margin:0 5px -1px 0;border:1px solid #555}
#bar{height:9px;background:linear-gradient(90deg,#440154,#3b528b,#21918c,#5ec962,#fde725)}
</style></head><body>
<canvas id="view"></canvas>
<div id="info"><b>@TITLE@</b><div id="legend"></div>
<div>drag: turn, wheel: zoom, shift+drag: move</div></div>
<script type="application/json" id="data">@DATA@</script>
<script>
"use strict";
const D = JSON.parse(document.getElementById("data").textContent);
function bytes(s){const b=atob(s),u=new Uint8Array(b.length);
  for(let i=0;i<b.length;i++)u[i]=b.charCodeAt(i);return u;}
function f32(s){return new Float32Array(bytes(s).buffer);}
const tri=f32(D.tri), triRgb=bytes(D.tri_rgb), seg=f32(D.seg), segRgb=bytes(D.seg_rgb),
  segKindRgb=bytes(D.seg_kind_rgb), radar=f32(D.radar), cells=f32(D.map),
  cellRgb=bytes(D.map_rgb);
let byKind=false;
function legend(){
  let lg=D.legend.map(m=>`<div><i style="background:${m[1]}"></i>${esc(m[0])}</div>`)
    .join("");
  if(D.paths){lg+=`<div>${D.paths} strongest paths of ${esc(D.link)}, coloured by `+
    `<a href="#" id="mode">${byKind?"mechanism":"gain (dB)"}</a> (click to change)</div>`;
    lg+=byKind?D.mechanisms.map(m=>`<div><i style="background:${m[1]}"></i>${esc(m[0])}`+
      `</div>`).join(""):`<div id="bar"></div><div>${D.db_range[0].toFixed(1)} .. `+
      `${D.db_range[1].toFixed(1)} dB</div>`;}
  else{lg+="<div>no paths drawn (no snapshot, or a link without paths)</div>";}
  if(D.map_range.length){lg+=`<div>radio map: ${esc(D.map_label)}</div><div id="bar"></div>`+
    `<div>${D.map_range[0].toFixed(1)} .. ${D.map_range[1].toFixed(1)}</div>`;}
  lg+=D.radar_names.map(n=>`<div><i style="background:#e61e1e"></i>radar ${esc(n)}</div>`)
    .join("");
  document.getElementById("legend").innerHTML=lg;
  const a=document.getElementById("mode");
  if(a)a.onclick=e=>{e.preventDefault();byKind=!byKind;colourPaths();legend();draw();};}
legend();
function esc(t){return String(t).replace(/[&<>"]/g,c=>({"&":"&amp;","<":"&lt;",">":"&gt;",
  '"':"&quot;"}[c]));}
// bounds of everything drawn
let lo=[1e30,1e30,1e30], hi=[-1e30,-1e30,-1e30];
for(const a of [tri,seg,radar,cells])for(let i=0;i<a.length;i+=3)for(let k=0;k<3;k++){
  lo[k]=Math.min(lo[k],a[i+k]);hi[k]=Math.max(hi[k],a[i+k]);}
if(lo[0]>hi[0]){lo=[-1,-1,-1];hi=[1,1,1];}
let centre=[0,1,2].map(k=>(lo[k]+hi[k])/2);
const size=Math.max(hi[0]-lo[0],hi[1]-lo[1],hi[2]-lo[2],1);
// vertex arrays: triangles with flat normals, segments, radar points
const nt=tri.length/9, tp=new Float32Array(nt*9), tn=new Float32Array(nt*9),
  tc=new Float32Array(nt*9);
for(let t=0;t<nt;t++){const p=tri.subarray(9*t,9*t+9);
  const u=[p[3]-p[0],p[4]-p[1],p[5]-p[2]], v=[p[6]-p[0],p[7]-p[1],p[8]-p[2]];
  let n=[u[1]*v[2]-u[2]*v[1],u[2]*v[0]-u[0]*v[2],u[0]*v[1]-u[1]*v[0]];
  const l=Math.hypot(n[0],n[1],n[2])||1;n=n.map(x=>x/l);
  for(let j=0;j<3;j++)for(let k=0;k<3;k++){tp[9*t+3*j+k]=p[3*j+k]-centre[k];
    tn[9*t+3*j+k]=n[k];tc[9*t+3*j+k]=triRgb[3*t+k]/255;}}
const ns=seg.length/6, sp=new Float32Array(ns*6), sc=new Float32Array(ns*6);
for(let s=0;s<ns;s++)for(let j=0;j<2;j++)for(let k=0;k<3;k++)
  sp[6*s+3*j+k]=seg[6*s+3*j+k]-centre[k];
let segColours=null;
function colourPaths(){const rgb=byKind?segKindRgb:segRgb;
  for(let s=0;s<ns;s++)for(let j=0;j<2;j++)for(let k=0;k<3;k++)
    sc[6*s+3*j+k]=rgb[3*s+k]/255;
  if(segColours&&gl){gl.bindBuffer(gl.ARRAY_BUFFER,segColours);
    gl.bufferData(gl.ARRAY_BUFFER,sc,gl.STATIC_DRAW);}}
colourPaths();
const nr=radar.length/3, rp=new Float32Array(nr*3), rc=new Float32Array(nr*3);
for(let r=0;r<nr;r++)for(let k=0;k<3;k++){rp[3*r+k]=radar[3*r+k]-centre[k];
  rc[3*r+k]=[0.9,0.12,0.12][k];}
const nm=cells.length/9, mp=new Float32Array(nm*9), mc=new Float32Array(nm*9);
for(let t=0;t<nm;t++)for(let j=0;j<3;j++)for(let k=0;k<3;k++){
  mp[9*t+3*j+k]=cells[9*t+3*j+k]-centre[k];mc[9*t+3*j+k]=cellRgb[3*t+k]/255;}
const canvas=document.getElementById("view");
const gl=canvas.getContext("webgl",{antialias:true});
if(!gl){document.getElementById("legend").innerHTML+="<p>WebGL is not available.</p>";}
const VS=`attribute vec3 p;attribute vec3 n;attribute vec3 c;uniform mat4 m;uniform float lit;
varying vec3 col;void main(){gl_Position=m*vec4(p,1.0);gl_PointSize=9.0;
vec3 l=normalize(vec3(0.3,0.5,0.8));float d=abs(dot(n,l));
col=mix(c,c*(0.45+0.55*d),lit);}`;
const FS=`precision mediump float;varying vec3 col;void main(){gl_FragColor=vec4(col,1.0);}`;
function shader(type,src){const s=gl.createShader(type);gl.shaderSource(s,src);
  gl.compileShader(s);return s;}
const prog=gl.createProgram();gl.attachShader(prog,shader(gl.VERTEX_SHADER,VS));
gl.attachShader(prog,shader(gl.FRAGMENT_SHADER,FS));gl.linkProgram(prog);gl.useProgram(prog);
function buffer(a){const b=gl.createBuffer();gl.bindBuffer(gl.ARRAY_BUFFER,b);
  gl.bufferData(gl.ARRAY_BUFFER,a,gl.STATIC_DRAW);return b;}
const zero=new Float32Array(Math.max(ns*6,nr*3,nm*9,3));
segColours=buffer(sc);
const parts=[[gl.TRIANGLES,buffer(tp),buffer(tn),buffer(tc),nt*3,1],
  [gl.LINES,buffer(sp),buffer(zero),segColours,ns*2,0],
  [gl.POINTS,buffer(rp),buffer(zero),buffer(rc),nr,0],
  [gl.TRIANGLES,buffer(mp),buffer(zero),buffer(mc),nm*3,0]];
function attr(name,buf){const loc=gl.getAttribLocation(prog,name);
  gl.bindBuffer(gl.ARRAY_BUFFER,buf);gl.enableVertexAttribArray(loc);
  gl.vertexAttribPointer(loc,3,gl.FLOAT,false,0,0);}
// camera: orbit about a point, z up; it opens on the one fitted to the paths
// (clradcom.views.default_camera)
let yaw=D.camera.yaw, pitch=D.camera.pitch, dist=D.camera.dist,
  pan=[0,1,2].map(k=>D.camera.target[k]-centre[k]);
function mul(a,b){const o=new Float32Array(16);for(let i=0;i<4;i++)for(let j=0;j<4;j++){
  let s=0;for(let k=0;k<4;k++)s+=a[k*4+j]*b[i*4+k];o[i*4+j]=s;}return o;}
function view(){const e=[dist*Math.cos(pitch)*Math.cos(yaw)+pan[0],
  dist*Math.cos(pitch)*Math.sin(yaw)+pan[1],dist*Math.sin(pitch)+pan[2]];
  let f=[pan[0]-e[0],pan[1]-e[1],pan[2]-e[2]];let l=Math.hypot(...f);f=f.map(x=>x/l);
  let s=[f[1],-f[0],0];l=Math.hypot(...s)||1;s=s.map(x=>x/l);
  const u=[s[1]*f[2]-s[2]*f[1],s[2]*f[0]-s[0]*f[2],s[0]*f[1]-s[1]*f[0]];
  const d=k=>-(k[0]*e[0]+k[1]*e[1]+k[2]*e[2]);
  return new Float32Array([s[0],u[0],-f[0],0,s[1],u[1],-f[1],0,s[2],u[2],-f[2],0,
    d(s),d(u),-d(f),1]);}
function persp(aspect){const near=size*1e-3, far=size*20, t=1/Math.tan(@HALF_FOV@);
  return new Float32Array([t/aspect,0,0,0,0,t,0,0,0,0,(far+near)/(near-far),-1,
    0,0,2*far*near/(near-far),0]);}
function draw(){if(!gl)return;const w=canvas.clientWidth*devicePixelRatio,
  h=canvas.clientHeight*devicePixelRatio;
  if(canvas.width!==w||canvas.height!==h){canvas.width=w;canvas.height=h;}
  gl.viewport(0,0,w,h);gl.clearColor(0.96,0.96,0.95,1);gl.enable(gl.DEPTH_TEST);
  gl.clear(gl.COLOR_BUFFER_BIT|gl.DEPTH_BUFFER_BIT);
  gl.uniformMatrix4fv(gl.getUniformLocation(prog,"m"),false,mul(persp(w/h),view()));
  for(const [mode,p,n,c,count,lit] of parts){if(!count)continue;attr("p",p);attr("n",n);
    attr("c",c);gl.uniform1f(gl.getUniformLocation(prog,"lit"),lit);
    gl.drawArrays(mode,0,count);}}
let drag=null;
canvas.addEventListener("mousedown",e=>{drag=[e.clientX,e.clientY,e.shiftKey];});
window.addEventListener("mouseup",()=>{drag=null;});
window.addEventListener("mousemove",e=>{if(!drag)return;const dx=e.clientX-drag[0],
  dy=e.clientY-drag[1];drag=[e.clientX,e.clientY,drag[2]];
  if(drag[2]){const k=dist/600;pan[0]+=k*(dy*Math.cos(yaw)+dx*Math.sin(yaw));
    pan[1]+=k*(dy*Math.sin(yaw)-dx*Math.cos(yaw));}
  else{yaw-=dx*0.01;pitch=Math.max(-1.5,Math.min(1.5,pitch+dy*0.01));}draw();});
canvas.addEventListener("wheel",e=>{e.preventDefault();dist*=Math.exp(e.deltaY*0.001);
  draw();},{passive:false});
window.addEventListener("resize",draw);
draw();
</script></body></html>
"""


def html_page(scene, snapshot=None, link=None, n_paths: int = 50, radio_map=None) -> str:
    """A self-contained HTML page that draws the scene and paths with WebGL: the data
    inline (:func:`page_payload` as JSON), the viewer inline, no external URL; with
    ``radio_map`` = (grid, values_db, label) the map as a coloured plane in the scene."""
    payload = json.dumps(page_payload(scene, snapshot, link, n_paths, radio_map),
                         separators=(",", ":"))
    payload = payload.replace("</", "<\\/")  # never close the script element early
    title = html.escape(f"{scene.name}: scene and paths")
    return (_PAGE.replace("@TITLE@", title).replace("@HALF_FOV@", repr(CAMERA_FOV_RAD / 2))
            .replace("@DATA@", payload))


def save_html(path: str | os.PathLike, scene, snapshot=None, link=None, n_paths: int = 50,
              *, radio_map=None, inputs=()) -> Path:
    """Write :func:`html_page` to ``path`` (UTF-8) atomically. Returns the path."""
    data = html_page(scene, snapshot, link, n_paths, radio_map).encode("utf-8")
    return atomic_write(path, lambda fh: fh.write(data), inputs=inputs)


class View:
    """A scene (and a snapshot's paths) for Jupyter: displayed inline as the
    interactive HTML page (:func:`html_page`) in an ``<iframe srcdoc>``, offline (the
    page carries its data and viewer; nothing is fetched). :meth:`save` writes the page."""

    def __init__(self, scene, snapshot=None, link=None, n_paths: int = 50, *,
                 height_px: int = 480):
        _check_n_paths(n_paths)
        if isinstance(height_px, bool) or not isinstance(height_px, int) or height_px < 50:
            raise ArgumentError("must be an integer >= 50 (pixels)", argument="height_px",
                                value=height_px)
        self.scene, self.snapshot, self.link, self.n_paths = scene, snapshot, link, n_paths
        self.height_px = height_px

    def __repr__(self) -> str:
        return (f"View(scene {self.scene.name!r}, "
                f"{'no snapshot' if self.snapshot is None else 'with a snapshot'}, "
                f"{self.n_paths} paths)")

    def html(self) -> str:
        return html_page(self.scene, self.snapshot, self.link, self.n_paths)

    def _repr_html_(self) -> str:
        return (f'<iframe srcdoc="{html.escape(self.html(), quote=True)}" '
                f'style="width:100%;height:{self.height_px}px;border:0"></iframe>')

    def save(self, path: str | os.PathLike) -> Path:
        return save_html(path, self.scene, self.snapshot, self.link, self.n_paths)


def view(scene, snapshot=None, link=None, n_paths: int = 50) -> View:
    """:class:`View` of ``scene`` and a snapshot's paths: in Jupyter, ``view(scene, snap)``
    as the last line of a cell draws it inline."""
    return View(scene, snapshot, link, n_paths)
