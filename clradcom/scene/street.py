"""The paper's street scene as text and mesh bytes: scenes/street/ is written from these.

The scene reproduces Section IV of the seed paper (Sit et al., "Verification of an
OFDM-based range and Doppler estimation algorithm with ray-tracing"): a two-lane street
along +x with a concrete road, concrete buildings and trees on both sides, and four PEC
cars A-D; radar A on car A's front bumper (90 deg x 180 deg sector) and a second radar on
car D for the multi-user case. Everything is deterministic: the same options give the
same bytes.

:func:`plan_street` turns :class:`StreetOptions` into every number of the scene;
:func:`street_toml`, :func:`street_meshes` and :func:`street_readme` turn that plan into
the files' contents (tools/make_street.py writes them). Meshes are little-endian binary
PLY (float32 vertices, int32 faces) built here, not by a library exporter, so the bytes
do not depend on a trimesh version.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np
import trimesh

from clradcom.geometry.triangles import ray_hit_distances
from clradcom.scene.meshfiles import ply_bytes
from clradcom.scene.models import rounded_car
from clradcom.scene.records import Scene

__all__ = ["TABLE_III", "StreetOptions", "StreetPlan", "plan_street", "ply_bytes", "street_meshes",
           "street_readme", "street_toml"]

# --- the paper (Section IV, Table III) -------------------------------------------------------
CARRIER_HZ = 24e9
V_SET = {"A": 12.9, "B": -13.3, "C": 12.9, "D": -14.5}  # m/s along +x
R_SET = {"B": 16.4, "C": 26.0, "D": 34.6}  # m, "calculated from the center point of the cars"
SAME_LANE = {"A": True, "B": False, "C": True, "D": False}  # B, D drive the opposite way
#: Table III of the paper, per car seen by radar A: set range R (m, car centre), set
#: relative velocity v_rel (m/s, closing along the road), and the paper's own ray-tracing
#: simulation's detected R and v_rel. The street names the cars ``car<letter>``.
TABLE_III = {
    "B": {"range_set_m": 16.4, "v_rel_set_mps": 26.2, "range_sim_m": 16.1,
          "v_rel_sim_mps": 25.7},
    "C": {"range_set_m": 26.0, "v_rel_set_mps": 0.0, "range_sim_m": 25.2,
          "v_rel_sim_mps": 0.0},
    "D": {"range_set_m": 34.6, "v_rel_set_mps": 27.4, "range_sim_m": 34.4,
          "v_rel_sim_mps": 27.4},
}

# --- our choices -------------------------------------------------------------------------------
CAR_LENGTH, CAR_WIDTH, CAR_HEIGHT = 3.8, 1.85, 1.7
RADAR_HEIGHT = 0.5  # m above the road
RADAR_GAP = 0.075  # m between the bumper surface (at RADAR_HEIGHT) and the antenna
TX_POWER_W = 0.01  # not given in the paper; same as scenes/canonical/moving_car.toml
NOISE_FIGURE_DB = 10.0  # not given in the paper; same as moving_car.toml
X_START = -40.0  # street starts 40 m behind car A's centre
GROUND_HALF_WIDTH = 20.0  # m; the ground runs under the buildings
GROUND_CELL = (2.0, 1.0)  # m, road grid cells (x, y)
FACADE_CELL = 1.5  # m, tiles on the street face and the end walls of each block
BLOCK_DEPTH = 10.0
# building blocks (length, height, facade distance from the street axis, gap after), cycled
SOUTH_BLOCKS = [(14.0, 12.0, 8.0, 4.0), (18.0, 18.0, 9.0, 3.0), (10.0, 9.0, 8.0, 6.0),
                (22.0, 15.0, 10.5, 2.5), (12.0, 21.0, 8.5, 5.0), (16.0, 10.0, 9.5, 3.0)]
NORTH_BLOCKS = [(11.0, 15.0, 8.5, 3.0), (20.0, 9.0, 8.0, 5.0), (13.0, 19.0, 10.0, 2.0),
                (17.0, 13.0, 8.5, 6.0), (9.0, 16.0, 9.0, 3.5), (15.0, 11.0, 8.0, 4.0)]
SOUTH_FIRST_X, NORTH_FIRST_X = 2.0, 5.0  # first block starts this far after the street start
TREE_Y = 5.5  # |y| of the tree rows (sidewalk, between road edge 3.5 m and facades >= 8 m)
TREE_FIRST_X, TREE_STEP = 4.0, 8.0
TREE_SCALES = (1.0, 0.85, 1.15, 0.95)
NORTH_TREE_OFFSET = 4.0  # north row shifted half a step
# radar A's MIMO array (street_mimo.toml): 3 tx x 4 rx along the bumper (local y), the
# layout of 3 tx / 4 rx automotive radar chips (receivers lambda/2 apart, transmitters
# 4 x lambda/2 = 2 lambda apart), which makes a filled 12-element virtual ULA at lambda/2
MIMO_TX, MIMO_RX = 3, 4
MIMO_RX_SPACING_WAVELENGTHS = 0.5
MIMO_TX_SPACING_WAVELENGTHS = MIMO_RX * MIMO_RX_SPACING_WAVELENGTHS
# the drive variant (street_drive.toml): one second of the street, 20 frames 50 ms apart
DRIVE_START_S, DRIVE_STEP_S, DRIVE_COUNT = 0.0, 0.05, 20


#: radar D's own FMCW chirp sequence in street_fmcw_ofdm.toml: a 24 GHz ISM-band corner
#: radar, 250 MHz in 40 µs from 23.95 GHz (its ADC window, 2-27.6 µs, sweeps
#: 23.96-24.12 GHz, across the OFDM radar's band 24.0-24.093 GHz), 128 chirps every 50 µs,
#: 256 I/Q samples at 10 MHz behind a 2.5 MHz IF filter (60 m)
MIXED_FMCW = (("kind", '"fmcw"'), ("start_frequency_hz", "23.95e9"),
              ("sweep_bandwidth_hz", "250e6"), ("chirp_duration_s", "40e-6"),
              ("idle_duration_s", "10e-6"), ("chirps", "128"),
              ("adc_sample_rate_hz", "10e6"), ("samples_per_chirp", "256"),
              ("adc_start_s", "2e-6"), ("if_bandwidth_hz", "2.5e6"))


@dataclass(frozen=True)
class StreetOptions:
    """The variants of the street (tools/make_street.py's options; defaults: the committed
    scenes/street/)."""

    #: street length in m, starting 40 m behind car A (at least 60: car D is ~37 m ahead)
    length: float = 160.0
    #: the two rows of trees
    trees: bool = True
    #: superellipsoid exponent of the car body: 1 ellipsoid, toward 0 a box
    car_roundness: float = 0.25
    #: car body segments around (height segments: half)
    car_segments: int = 20
    #: car body grid shifted half a cell: nose and tail carry flat facets facing +-x
    car_flat_ends: bool = False
    #: lane width in m
    lane_width: float = 3.5
    #: reference of the paper's distances R: "radar" (radar A's antenna) or "car-centre"
    range_from: str = "radar"
    #: radar A carries a 3 tx x 4 rx TDM-MIMO array (street_mimo.toml); radar D none
    mimo: bool = False
    #: a [time] table: one second of the street in 20 frames (street_drive.toml)
    drive: bool = False
    #: radar D carries the FMCW chirp sequence of :data:`MIXED_FMCW` as its own waveform,
    #: radar A keeps the paper's OFDM frame (street_fmcw_ofdm.toml)
    mixed: bool = False


@dataclass
class StreetPlan:
    """Every number of the street, before any file is written."""

    #: the car mesh (vertices rounded through float32 as the PLY stores them, faces)
    car: tuple[np.ndarray, np.ndarray]
    #: the radars' position in their car's frame
    radar_local: np.ndarray
    #: car name ("A".."D") -> position of its wheels' plane centre
    positions: dict[str, np.ndarray]
    #: x where the street ends
    x_end: float
    #: (name, x0, x1, y_face, side, height) per building block
    buildings: list[tuple]
    #: (name, x, y, scale) per tree
    trees: list[tuple]



# --- geometry helpers ----------------------------------------------------------------------------
def quad_grid(origin, u, v, nu, nv, normal):
    """Grid of nu x nv quads (2 triangles each) spanning origin + [0,1]u + [0,1]v, facing normal."""
    origin, u, v = (np.asarray(a, dtype=np.float64) for a in (origin, u, v))
    if np.dot(np.cross(u, v), normal) < 0:
        u, v, nu, nv = v, u, nv, nu
    a = np.linspace(0.0, 1.0, nu + 1)
    b = np.linspace(0.0, 1.0, nv + 1)
    ga, gb = np.meshgrid(a, b, indexing="ij")
    verts = origin + ga[..., None] * u + gb[..., None] * v
    idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    p, q = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    r, s = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([p, q, r], 1), np.stack([p, r, s], 1)])
    return verts.reshape(-1, 3), faces


def merge(parts):
    verts, faces, off = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces.append(f + off)
        off += len(v)
    return np.concatenate(verts), np.concatenate(faces)


def cells(length, cell):
    return max(1, int(round(length / cell)))


def building_block(x0, x1, y_face, side, height):
    """Closed box, outward normals. Street face and end walls tiled (FACADE_CELL); back,
    roof and bottom are two triangles each (the radar cannot see them)."""
    y_back = y_face + side * BLOCK_DEPTH
    ya, yb = sorted((y_face, y_back))
    lx, ly = x1 - x0, yb - ya
    nz = cells(height, FACADE_CELL)
    parts = [
        # street face (normal -side*y)
        quad_grid([x0, y_face, 0.0], [lx, 0, 0], [0, 0, height], cells(lx, FACADE_CELL), nz,
                  [0, -side, 0]),
        quad_grid([x0, ya, 0.0], [0, ly, 0], [0, 0, height], cells(ly, FACADE_CELL), nz,
                  [-1, 0, 0]),
        quad_grid([x1, ya, 0.0], [0, ly, 0], [0, 0, height], cells(ly, FACADE_CELL), nz,
                  [1, 0, 0]),
        quad_grid([x0, y_back, 0.0], [lx, 0, 0], [0, 0, height], 1, 1, [0, side, 0]),
        quad_grid([x0, ya, height], [lx, 0, 0], [0, ly, 0], 1, 1, [0, 0, 1]),
        quad_grid([x0, ya, 0.0], [lx, 0, 0], [0, ly, 0], 1, 1, [0, 0, -1]),
    ]
    return merge(parts)


def building_layout(x_start, x_end):
    """[(name, x0, x1, y_face, side, height)] for both sides, deterministic."""
    out = []
    for side, tag, pattern, first in ((-1, "S", SOUTH_BLOCKS, SOUTH_FIRST_X),
                                      (1, "N", NORTH_BLOCKS, NORTH_FIRST_X)):
        x, k = x_start + first, 0
        while x < x_end - 4.0:
            length, height, setback, gap = pattern[k % len(pattern)]
            x1 = min(x + length, x_end)
            out.append((f"building_{tag}{k + 1:02d}", x, x1, side * setback, side, height))
            x = x1 + gap
            k += 1
    return out


def tree_mesh():
    """Low-poly tree at the origin (foot at z = 0): icosphere crown on a cylinder trunk."""
    crown = trimesh.creation.icosphere(subdivisions=1, radius=1.5)
    crown.apply_translation([0.0, 0.0, 4.3])
    trunk = trimesh.creation.cylinder(radius=0.15, height=3.2, sections=8)
    trunk.apply_translation([0.0, 0.0, 1.6])
    m = trimesh.util.concatenate([crown, trunk])
    return np.asarray(m.vertices), np.asarray(m.faces)


def tree_layout(x_start, x_end):
    out = []
    for side, tag, off in ((-1, "S", 0.0), (1, "N", NORTH_TREE_OFFSET)):
        k = 0
        x = x_start + TREE_FIRST_X + off
        while x <= x_end - 2.0:
            out.append((f"tree_{tag}{k + 1:02d}", x, side * TREE_Y,
                        TREE_SCALES[k % len(TREE_SCALES)]))
            x += TREE_STEP
            k += 1
    return out


def nose_x(mesh: trimesh.Trimesh, z: float) -> float:
    """x of the car's front surface at height z on the centre line (ray from inside)."""
    t = ray_hit_distances([0.0, 0.0, z], [1.0, 0.0, 0.0], mesh.vertices[mesh.faces])
    return float(t.max())


# --- TOML writing ------------------------------------------------------------------------------
def num(x: float, nd: int = 4) -> str:
    return repr(round(float(x), nd) + 0.0)


def vec(xs, nd: int = 4) -> str:
    return "[" + ", ".join(num(x, nd) for x in xs) + "]"


def plan_street(options: StreetOptions) -> StreetPlan:
    """All numbers of the scene (no files)."""
    lane = options.lane_width
    y_lane = {k: (-0.5 * lane if same else 0.5 * lane) for k, same in SAME_LANE.items()}
    car = rounded_car(CAR_LENGTH, CAR_WIDTH, CAR_HEIGHT, body_exponent=options.car_roundness,
                      body_segments=(options.car_segments, max(4, options.car_segments // 2)),
                      face_centred=options.car_flat_ends)
    car_v = np.asarray(car.vertices, dtype=np.float32).astype(np.float64)
    car_f = np.asarray(car.faces)
    lo, hi = car_v.min(axis=0), car_v.max(axis=0)
    centre_local = 0.5 * (lo + hi)
    radar_x = round(nose_x(trimesh.Trimesh(car_v, car_f, process=False), RADAR_HEIGHT)
                    + RADAR_GAP, 3)
    radar_local = np.array([radar_x, 0.0, RADAR_HEIGHT])
    pos = {"A": np.array([0.0, y_lane["A"], 0.0])}
    if options.range_from == "radar":
        ref = pos["A"] + radar_local  # world radar A (car A's yaw is 0)
    else:
        ref = pos["A"] + centre_local
    for k, r in R_SET.items():
        c = np.array([0.0, y_lane[k], 0.0]) + centre_local
        dy, dz = c[1] - ref[1], c[2] - ref[2]
        dx = math.sqrt(r * r - dy * dy - dz * dz)
        pos[k] = np.array([round(ref[0] + dx - centre_local[0], 4), y_lane[k], 0.0])
    x_end = X_START + options.length
    return StreetPlan(car=(car_v, car_f), radar_local=radar_local, positions=pos,
                      x_end=x_end, buildings=building_layout(X_START, x_end),
                      trees=tree_layout(X_START, x_end) if options.trees else [])


def street_toml(options: StreetOptions, plan: StreetPlan) -> str:
    """The text of street.toml (its meshes named as :func:`street_meshes` names them)."""
    L = []
    w = L.append
    w("# The seed paper's street (Section IV, Fig. 1): two lanes along +x, concrete road,")
    w("# concrete buildings and trees on both sides, four PEC cars. Generated by")
    w("# tools/make_street.py -- do not edit by hand; see README.md for the reading of the paper.")
    w(f"# Options: length = {num(options.length)} m, trees = {str(options.trees).lower()}, "
      f"car_roundness = {num(options.car_roundness)}, car_segments = {options.car_segments}, "
      f"car_flat_ends = {str(options.car_flat_ends).lower()}, "
      f"range_from = {options.range_from}, lane_width = {num(options.lane_width)} m"
      + (", mimo = true" if options.mimo else "")
      + (", drive = true" if options.drive else "")
      + (", mixed = true" if options.mixed else ""))
    if options.drive:
        w(f"# Drive variant: a [time] table of {DRIVE_COUNT} instants {num(DRIVE_STEP_S)} s "
          "apart (one second, the cars at their set")
        w("# speeds) for `clradcom drive --radar A` (docs/tracking.md); everything else is "
          "street.toml's.")
    if options.mixed:
        w("# FMCW + OFDM variant: radar D carries an FMCW chirp-sequence radar (its own "
          "[radars.waveform]),")
        w("# radar A the paper's OFDM one (`clradcom interference` runs the pair both ways); "
          "everything else is street.toml's.")
    if options.mimo:
        w("# MIMO variant: radar A carries a 3 tx x 4 rx array (12-element virtual ULA at "
          "lambda/2);")
        w("# everything else is street.toml's.")
    w("")
    w("[scene]")
    w('name = "street_mimo"' if options.mimo else
      'name = "street_drive"' if options.drive else
      'name = "street_fmcw_ofdm"' if options.mixed else 'name = "street"')
    w("carrier_hz = 24e9")
    w('description = "OFDM RadCom paper street: cars A, C at +12.9 m/s; B, D oncoming at '
      '-13.3 and -14.5 m/s; radar A on car A\'s front bumper"')
    if options.drive:
        w("")
        w("[time]")
        w(f"start_s = {num(DRIVE_START_S)}")
        w(f"step_s = {num(DRIVE_STEP_S)}")
        w(f"count = {DRIVE_COUNT}")
    w("")
    w("# ---- road (Table II: concrete, road) ----")
    w("[[objects]]")
    w('name = "road"')
    w('material = "concrete_road"')
    w('mesh = "meshes/road.ply"')
    w("")
    w("# ---- cars (Table II: metal = PEC); car mesh: 3.8 x 1.85 x 1.7 m, nose +x, wheels "
      "on z = 0 ----")
    for k in "ABCD":
        w("[[objects]]")
        w(f'name = "car{k}"')
        w('material = "metal"')
        w('mesh = "meshes/car.ply"')
        w(f"position = {vec(plan.positions[k])}")
        w(f"rotation_deg = {vec([0, 0, 0 if SAME_LANE[k] else 180])}")
        w(f"velocity = {vec([V_SET[k], 0, 0])}")
        if k != "A":
            w(f'description = "paper R = {R_SET[k]} m from radar A, v_set = {V_SET[k]} m/s"')
        else:
            w('description = "the radar car, v_set = 12.9 m/s"')
        w("")
    w("# ---- buildings (Table II: concrete, building) ----")
    for name, x0, x1, y_face, _side, h in plan.buildings:
        w("[[objects]]")
        w(f'name = "{name}"')
        w('material = "concrete_building"')
        w(f'mesh = "meshes/{name}.ply"')
        w(f'description = "x {num(x0, 2)}..{num(x1, 2)} m, facade at y = {num(y_face, 2)} m, '
          f'{num(h, 2)} m high"')
        w("")
    if plan.trees:
        w("# ---- trees (Table II: trees); one low-poly tree mesh, scaled ----")
    for name, x, y, s in plan.trees:
        w("[[objects]]")
        w(f'name = "{name}"')
        w('material = "trees"')
        w('mesh = "meshes/tree.ply"')
        w(f"position = {vec([x, y, 0])}")
        w(f"scale = {num(s)}")
        w("")
    w("# ---- radars ----")
    w("# The paper's sector antenna (90 deg azimuth x 180 deg elevation), on the front bumper,")
    w("# boresight along the car's travel. The paper has separate tx and rx antennas side by")
    w("# side; here one monostatic txrx port. Polarisation is not stated in the paper: V.")
    w("# tx power and noise figure are not given in the paper (same values as moving_car.toml).")
    for k, note in (("A", "the paper's radar (single-user runs use only this one)"),
                    ("D", "multi-user case: the same radar on car D, facing -x (its travel "
                          "direction). Single-radar runs can ignore it.")):
        w(f"# {note}")
        w("[[radars]]")
        w(f'name = "{k}"')
        w(f'rides_on = "car{k}"')
        w(f"position = {vec(plan.radar_local, 4)}   # car frame: "
          f"{num(RADAR_GAP, 3)} m ahead of the bumper, {num(RADAR_HEIGHT, 2)} m up")
        w("orientation_deg = [0.0, 0.0, 0.0]")
        w('pattern = { type = "sector", azimuth_width_deg = 90.0, elevation_width_deg = 180.0 }')
        w('polarization = "V"')
        w('role = "txrx"')
        w(f"tx_power_w = {num(TX_POWER_W)}")
        w(f"noise_figure_db = {num(NOISE_FIGURE_DB)}")
        if options.mimo and k == "A":
            w("# 3 tx x 4 rx along the bumper (local y), as 3 tx / 4 rx automotive radar "
              "chips: rx lambda/2")
            w("# apart, tx 2 lambda apart -> virtual ULA of 12 elements at lambda/2 (TDM: "
              "one tx per symbol)")
            w(f'tx_array = {{ kind = "ula", count = {MIMO_TX}, spacing_wavelengths = '
              f'{num(MIMO_TX_SPACING_WAVELENGTHS)} }}')
            w(f'rx_array = {{ kind = "ula", count = {MIMO_RX}, spacing_wavelengths = '
              f'{num(MIMO_RX_SPACING_WAVELENGTHS)} }}')
        if options.mixed and k == "D":
            w("")
            w("# D's own frame: an FMCW chirp sequence in the 24 GHz ISM band (A keeps the "
              "paper's OFDM)")
            w("[radars.waveform]")
            for key, value in MIXED_FMCW:
                w(f"{key} = {value}")
        w("")
    return "\n".join(L).rstrip("\n") + "\n"


def street_meshes(plan: StreetPlan) -> dict[str, bytes]:
    """The PLY files of the street's meshes folder: file name -> bytes (one car mesh for
    all four cars, one tree mesh for every tree)."""
    x0, x1 = X_START, plan.x_end
    nx = cells(x1 - x0, GROUND_CELL[0])
    ny = cells(2 * GROUND_HALF_WIDTH, GROUND_CELL[1])
    out = {"road.ply": ply_bytes(*quad_grid([x0, -GROUND_HALF_WIDTH, 0.0], [x1 - x0, 0, 0],
                                            [0, 2 * GROUND_HALF_WIDTH, 0], nx, ny, [0, 0, 1])),
           "car.ply": ply_bytes(*plan.car)}
    for name, bx0, bx1, y_face, side, h in plan.buildings:
        out[f"{name}.ply"] = ply_bytes(*building_block(bx0, bx1, y_face, side, h))
    if plan.trees:
        out["tree.ply"] = ply_bytes(*tree_mesh())
    return out


def street_readme(options: StreetOptions, plan: StreetPlan, scene: Scene,
                  truth: list[dict]) -> str:
    """The text of the street's README.md: layout, reading of the paper, ground truth.

    ``scene`` is the street as loaded from the written files, ``truth`` radar A's ground
    truth for cars B, C and D (``clradcom.radar.truth.detection_truth(scene, "A",
    ["carB", "carC", "carD"])``).
    """
    pos, rl = plan.positions, plan.radar_local
    ra = scene.radars[scene.radar_index("A")].position
    per_class = Counter()
    for o in scene.objects:
        per_class[o.name.split("_")[0].rstrip("ABCD") if o.name.startswith("car")
                  else o.name.split("_")[0]] += o.tri_stop - o.tri_start
    L = []
    w = L.append
    w("# Street scene (seed paper, Section IV)")
    w("")
    w("Generated by `python tools/make_street.py` (deterministic; `--help` lists the variants:")
    w("output folder, street length, trees on/off, car roundness/segments/flat ends, lane "
      "width, range")
    w("reference). Do not edit these files by hand. Load with")
    w("`clradcom.scene.load_scene('scenes/street/street.toml')`.")
    w("")
    w("## Layout")
    w("")
    w(f"- Street along +x from x = {num(X_START, 1)} to {num(plan.x_end, 1)} m; two lanes of "
      f"{num(options.lane_width, 2)} m, centre line y = 0. Right-hand traffic: cars driving "
      "+x (A, C)")
    w(f"  in the lane y = {num(-0.5 * options.lane_width, 3)} m, oncoming cars (B, D, rotated "
      f"180°) at y = {num(0.5 * options.lane_width, 3)} m.")
    w(f"- Ground (`road`, `concrete_road`): one grid of {num(GROUND_CELL[0], 1)} × "
      f"{num(GROUND_CELL[1], 1)} m cells, |y| ≤ {num(GROUND_HALF_WIDTH, 1)} m (runs under the "
      "buildings).")
    w(f"- Buildings (`concrete_building`): {len(plan.buildings)} closed blocks, "
      f"{num(BLOCK_DEPTH, 1)} m deep, 9–21 m high, facades 8–10.5 m from the axis (setbacks),")
    w("  gaps of 2–6 m (side streets); street face and end walls tiled in ~1.5 m squares.")
    w(f"- Trees (`trees`): {len(plan.trees)} low-poly trees (icosphere crown r = 1.5 m at 4.3 m "
      "on a 3.2 m trunk, scaled 0.85–1.15),")
    w(f"  rows at |y| = {num(TREE_Y, 1)} m every {num(TREE_STEP, 1)} m.")
    w("- Cars (`metal`, PEC): `meshes/car.ply` (`clradcom.scene.models.rounded_car`, "
      "= `car_mesh()` by default), 3.8 × 1.85 × 1.7 m,")
    w("  nose +x, wheels on z = 0; bounding-box centre 0.85 m above the road.")
    w("")
    w("| car | position (m, wheels' plane) | yaw | velocity (m/s) |")
    w("|---|---|---|---|")
    for k in "ABCD":
        w(f"| {k} | {vec(pos[k])} | {0 if SAME_LANE[k] else 180}° | {vec([V_SET[k], 0, 0])} |")
    w("")
    w(f"Radars (`rides_on`, car frame {vec(rl, 4)}: {num(RADAR_GAP, 3)} m in front of the "
      f"bumper surface at {num(RADAR_HEIGHT, 2)} m, in free air): `A` on car A, world "
      f"{vec(ra, 4)}, boresight +x; `D` on car D, boresight −x (multi-user case; single-radar "
      "runs ignore it). Both: sector 90° az × 180° el (G = 4), `V`, `txrx`, "
      f"{num(TX_POWER_W)} W, NF {num(NOISE_FIGURE_DB)} dB.")
    w("")
    w("Triangles: " + ", ".join(f"{k} {v}" for k, v in per_class.items())
      + f"; total {len(scene.triangles)}.")
    w("")
    w("## Reading of the paper")
    w("")
    w("- \"The distances R, calculated from the center point of the cars of B, C and D from "
      "A are 16.4 m, 26 m, and 34.6 m\" — read as the Euclidean range from radar A (its "
      "antenna on car A's bumper) to each car's centre, not along-track and not from car A's "
      "centre. Evidence: Table III's simulated ranges (16.1, 25.2, 34.4 m) all lie within "
      "half a car length (1.9 m, the paper's tolerance) *below* R; measured from car A's "
      "centre the echoes would start ~3.8 m short. `--range-from car-centre` gives the "
      "other reading (centre to centre, Euclidean).")
    w("- B and D are in the oncoming lane, so they sit 3.5 m to the side: along x they are "
      "less than R ahead. The paper's simulated v_rel for B (25.7 m/s vs set 26.2) matches "
      "the radial projection 26.2·cos(az) of this offset.")
    w("- Car speeds: Table III v_set; v_rel (set) = 12.9 + 13.3 = 26.2 and 12.9 + 14.5 = 27.4 "
      "m/s is along-track; the radar measures the radial part.")
    w("- Polarisation and tx power are not stated: V, 0.01 W (as `moving_car.toml`). The "
      "paper's separate tx and rx antennas are one monostatic `txrx` port here.")
    w("- Fig. 1 (the scene picture) is not reproduced in the text; the building layout "
      "(heights, setbacks, gaps) is our own, \"buildings and vegetation on both sides\".")
    w("")
    w("## Ground truth for radar A (t = 0)")
    w("")
    w("From the loaded scene with `clradcom.radar.truth.detection_truth(scene, 'A', "
      "['carB', 'carC', 'carD'])`; p radar A position, c the car's bounding-box centre, "
      "u = (c − p)/|c − p|: R = |c − p|; nearest = distance from p to the car's closest "
      "triangle; v_rel = −(v_car − v_A)·u (positive closing); f_D = 2 v_rel / λ, "
      "λ = c0 / 24 GHz. A detection of car X is correct when its range is within "
      "[nearest − 0.5 m, R + 1.9 m] (the paper: ±1.9 m about R) and its velocity within one "
      "velocity cell (1.97 m/s) of v_rel.")
    w("")
    w("| car | R (m) | paper R | nearest (m) | az (°) | v_rel radial (m/s) | v_rel along "
      "(paper) | f_D (Hz) | paper simulated R, v_rel |")
    w("|---|---|---|---|---|---|---|---|---|")
    sim = {"carB": "16.1, 25.7", "carC": "25.2, 0", "carD": "34.4, 27.4"}
    for t in truth:
        k = t["name"][-1]
        w(f"| {k} | {t['range_centre_m']:.3f} | {R_SET[k]} | {t['range_nearest_m']:.3f} | "
          f"{t['azimuth_deg']:.2f} | {t['v_rel_m_s']:.3f} | {t['v_rel_along_m_s']:.1f} | "
          f"{t['doppler_hz']:.1f} | {sim[t['name']]} |")
    w("")
    w("The paper also sees the buildings beyond 60 m at the radar's own speed "
      "(v_rel ≈ 12.9 m/s cos(az)), and ground/car multiple bounces.")
    w("")
    w("## MIMO variant (`street_mimo.toml`)")
    w("")
    w("The same street (same meshes), scene name `street_mimo`, with radar A carrying a "
      f"{MIMO_TX} tx × {MIMO_RX} rx array along its bumper (local y): receivers "
      f"{num(MIMO_RX_SPACING_WAVELENGTHS)} λ apart, transmitters "
      f"{num(MIMO_TX_SPACING_WAVELENGTHS)} λ apart, so the time-division (TDM) virtual array "
      "is a filled 12-element ULA at λ/2 (±90° unambiguous, Rayleigh width 2/12 in sin az, "
      "about 9.6° at boresight). This is the azimuth layout of the 3 tx / 4 rx radar chips "
      "used in automotive radars (receivers at λ/2, transmitters 2λ apart), scaled to "
      "24 GHz by the wavelength; 24 GHz automotive front ends often have fewer channels "
      "(e.g. 2 tx / 2 rx), the paper's radar has one tx and one rx antenna. "
      "`clradcom cube scenes/street/street_mimo.toml` traces it and builds the radar cube, "
      "the point cloud and the truth table (docs/dsp.md §9).")
    w("")
    w("## FMCW + OFDM variant (`street_fmcw_ofdm.toml`)")
    w("")
    w("The same street, scene name `street_fmcw_ofdm`, with radar D carrying an FMCW "
      "chirp-sequence radar of its own (`[radars.waveform]`: 250 MHz in 40 µs from "
      "23.95 GHz, 128 chirps every 50 µs, 256 I/Q samples at 10 MHz, IF 2.5 MHz) while "
      "radar A keeps the paper's OFDM frame. `clradcom interference "
      "scenes/street/street_fmcw_ofdm.toml` runs D's chirps into A's OFDM image, "
      "`--victim D --interferer A` A's OFDM into D's beat signal (docs/interference.md §6).")
    w("")
    w("## Drive variant (`street_drive.toml`)")
    w("")
    w("The same street, scene name `street_drive`, with a `[time]` table: "
      f"{DRIVE_COUNT} instants {num(DRIVE_STEP_S)} s apart from {num(DRIVE_START_S)} s, "
      "the cars moving at their set speeds. `clradcom drive scenes/street/street_drive.toml "
      "--radar A` traces radar A's echoes at every instant and writes the radar video, the "
      "detection table with a time column and the tracks of the cars against their truth "
      "(docs/tracking.md).")
    return "\n".join(L) + "\n"
