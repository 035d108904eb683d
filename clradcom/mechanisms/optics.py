"""Physical optics in place of GO for the objects that ask for it (docs/po.md).

A GO image path off a flat facet is the return of an infinite mirror; the PO integral
over the lit facets gives the facet's own strength and its off-specular lobes
(:mod:`~clradcom.mechanisms.physical_optics`), and SBR-PO does the same for corners
(:mod:`~clradcom.mechanisms.sbr`). Per object (:func:`object_optics`: its ``optics``
key, else the default that :attr:`OpticsSettings.mode` gives objects that reflect like a
conductor or a body, :func:`reflects_like_a_target`):

* ``"both"``: its single GO reflections make way for PO facet returns; multi-bounce
  paths stay GO;
* ``"po"``: every GO reflection path that ends on it makes way for PO facet returns
  (first bounce) and SBR-PO tube returns (bounces 2..max_bounces);
* ``"go"``: untouched.

The rule is what the object is made of, not a PEC flag: a material that reflects at
least :data:`TARGET_REFLECTANCE` of the power at normal incidence (|Gamma(0)|^2 >= 0.4,
-4.0 dB) is a metal of any conductivity (itu_metal, a car's paint over steel) or a
water-rich body (skin, a pedestrian); building materials, the road and vegetation reflect
less and keep their GO mirror paths. A non-PEC object's facets and SBR footprints carry
the currents of a penetrable surface, its own Fresnel coefficients (docs/po.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clradcom.errors import ArgumentError, ArgumentTypeError
from clradcom.mechanisms.common import Geometry, check_number
from clradcom.mechanisms.physical_optics import po_paths
from clradcom.mechanisms.sbr import ACCURACY_DB_RANGE, SbrTubes, launched, sbr_paths, shoot_sbr
from clradcom.paths import InteractionType, Paths
from clradcom.physics.em import fresnel_coefficients
from clradcom.physics.po import SPLIT_RULES
from clradcom.scene.records import OPTICS, Radar, Scene

__all__ = ["MODES", "OPTICS_NAMES", "TARGET_REFLECTANCE", "OpticsSettings", "SbrShot",
           "link_paths", "normal_reflectance", "object_optics", "optics_summary", "prepare",
           "reflects_like_a_target", "replaced_paths"]

#: the share of power at normal incidence, |Gamma(0)|^2, from which a material counts as
#: a conductor or a body (a radar target) and its objects get the mode's physical optics:
#: metals of any conductivity (itu_metal 0.999, -0.0045 dB; even sigma = 20 S/m 0.48) and
#: water-rich tissue (skin-like 16 - 16j: 0.46) lie above; ITU concrete (0.15), glass
#: (0.19), marble (0.21), brick (0.11), wood (0.03) and the paper's trees (0.32, -5.0 dB) below
TARGET_REFLECTANCE = 0.4

#: what each optics means, for the trace's summary line
OPTICS_NAMES = {"po": "PO facets + SBR-PO", "both": "PO facets, GO multi-bounce",
                "go": "GO image paths"}

#: OpticsSettings.mode -> the optics of target objects without their own ``optics`` key:
#: "none" GO image paths; "pec" PO facet integrals for the first bounce (a facet's true
#: RCS, not an infinite mirror's), GO for later ones; "sbr" PO facets plus shooting-and-
#: bouncing ray tubes with PO for bounces 2..max_bounces
MODES = {"none": "go", "pec": "both", "sbr": "po"}


@dataclass(frozen=True)
class OpticsSettings:
    """Which objects get physical optics, and how densely SBR tubes are shot."""

    mode: str = "none"
    #: pitch of the SBR ray-tube grid at every target, in wavelengths; None chooses it per
    #: object from sbr_accuracy_db (:func:`clradcom.mechanisms.sbr.spacing_for_accuracy`);
    #: an object's own ``sbr_spacing_wavelengths`` scene key wins over both
    sbr_spacing_wavelengths: float | None = None
    #: the error (dB) the tube grid may add to a corner's return when the pitch is chosen
    sbr_accuracy_db: float = 0.5
    #: also launch tubes at the objects' mirror images in large faces of the environment
    #: (the road, facades): the returns lit through one reflection there
    sbr_mirrors: bool = True
    #: most SBR bounces; None follows the specular search's max_reflections
    max_bounces: int | None = None
    #: how far PO facets near an antenna are split (:data:`clradcom.physics.po.
    #: SPLIT_RULES`): "near" out of its near zone (closer than twice their size),
    #: "fresnel" also into their far field (2 D^2/lambda), "none" kept whole
    po_split: str = "near"

    def __post_init__(self):
        if not isinstance(self.mode, str) or self.mode not in MODES:
            raise ArgumentError(f"must be one of {', '.join(map(repr, MODES))}",
                                argument="OpticsSettings.mode", value=self.mode)
        if self.sbr_spacing_wavelengths is not None:
            check_number("OpticsSettings", "sbr_spacing_wavelengths",
                         self.sbr_spacing_wavelengths, low=0.01, high=100.0)
        check_number("OpticsSettings", "sbr_accuracy_db", self.sbr_accuracy_db,
                     low=ACCURACY_DB_RANGE[0], high=ACCURACY_DB_RANGE[1])
        if not isinstance(self.sbr_mirrors, bool):
            raise ArgumentTypeError("must be True or False",
                                    argument="OpticsSettings.sbr_mirrors",
                                    value=self.sbr_mirrors)
        if self.max_bounces is not None:
            check_number("OpticsSettings", "max_bounces", self.max_bounces, low=0, high=16,
                         integer=True)
        if not isinstance(self.po_split, str) or self.po_split not in SPLIT_RULES:
            raise ArgumentError(f"must be one of {', '.join(map(repr, SPLIT_RULES))}",
                                argument="OpticsSettings.po_split", value=self.po_split)


def normal_reflectance(scene: Scene) -> np.ndarray:
    """(M,) |Gamma(0)|^2 of each of the scene's materials: the power a smooth half-space
    of it reflects at normal incidence, (|1 - sqrt(eps_r)| / |1 + sqrt(eps_r)|)^2; 1 for
    PEC (:func:`clradcom.physics.em.fresnel_coefficients` at cos theta = 1)."""
    r_te, _ = fresnel_coefficients(scene.material_eps_r, 1.0, scene.material_pec)
    return np.abs(r_te) ** 2


def reflects_like_a_target(scene: Scene) -> np.ndarray:
    """(M,) bool: the materials whose objects get the mode's physical optics by default:
    PEC, or |Gamma(0)|^2 >= :data:`TARGET_REFLECTANCE` (metals of any conductivity, skin,
    water)."""
    return np.asarray(scene.material_pec, dtype=bool) | (
        normal_reflectance(scene) >= TARGET_REFLECTANCE)


def object_optics(scene: Scene, mode: str) -> list[str]:
    """Optics per object: its own ``optics`` key, else the scene-level default for objects
    whose material reflects like a conductor or a body (:func:`reflects_like_a_target`;
    ``mode``: "none" -> go, "pec" -> both, "sbr" -> po); other objects without a key are
    "go"."""
    if not isinstance(mode, str) or mode not in MODES:
        raise ArgumentError(f"must be one of {', '.join(map(repr, MODES))}", argument="mode",
                            value=mode)
    target = reflects_like_a_target(scene)
    out = []
    for o in scene.objects:
        own = getattr(o, "optics", None)
        if own is not None:
            if own not in OPTICS:
                raise ArgumentError(f"object {o.name!r}: optics must be one of "
                                 f"{', '.join(OPTICS)}, got {own!r}")
            out.append(own)
        else:
            out.append(MODES[mode] if target[o.material] else "go")
    return out


def optics_summary(scene: Scene, mode: str, most: int = 8) -> list[str]:
    """Lines saying which objects get which optics under ``mode`` and why (their own key,
    or their material's reflectance), at most ``most`` names per line."""
    modes = object_optics(scene, mode)
    refl = normal_reflectance(scene)
    lines = [f"optics (OpticsSettings.mode {mode!r}; without their own optics key, objects "
             f"reflecting |Gamma(0)|^2 >= {10 * np.log10(TARGET_REFLECTANCE):.1f} dB get "
             f"{MODES[mode]!r}):"]
    for kind in ("po", "both", "go"):
        picked = [i for i, m in enumerate(modes) if m == kind]
        if not picked:
            continue
        names = []
        for i in picked[:most]:
            o = scene.objects[i]
            why = ("own key" if o.optics is not None else
                   f"{o.material_name} {10 * np.log10(max(refl[o.material], 1e-30)):+.1f} dB")
            names.append(f"{o.name} ({why})")
        more = f" and {len(picked) - most} more" if len(picked) > most else ""
        lines.append(f"  {kind} ({OPTICS_NAMES[kind]}): {len(picked)} object(s): "
                     f"{', '.join(names)}{more}")
    return lines


def po_object_ids(scene: Scene, settings: OpticsSettings) -> np.ndarray:
    """The objects whose first bounce is a PO facet integral (optics "both" or "po")."""
    return np.flatnonzero(np.array(object_optics(scene, settings.mode)) != "go")


def active(scene: Scene, settings: OpticsSettings) -> bool:
    """Whether any object of the scene gets physical optics."""
    return settings.mode != "none" or any(o.optics for o in scene.objects)


@dataclass
class SbrShot:
    """What one transmitter's links share: the objects by optics, and its SBR tubes."""

    po_objects: np.ndarray  # objects whose first bounce is a PO facet integral
    sbr_objects: np.ndarray  # objects that also get SBR-PO for later bounces
    max_bounces: int
    tubes: SbrTubes | None  # shoot_sbr's result, None without SBR objects


def prepare(geom: Geometry, tx: Radar, settings: OpticsSettings,
            receivers=None) -> SbrShot:
    """Sort the objects by optics and shoot tx's SBR tubes once for all its
    ``receivers`` (radars; default: tx alone, monostatic).  ``settings.max_bounces`` None
    means no SBR bounces (TraceSettings.optics_search fills it from the specular
    search)."""
    max_bounces = settings.max_bounces or 0
    modes = np.array(object_optics(geom.scene, settings.mode))
    po_objects = po_object_ids(geom.scene, settings)
    sbr_objects = np.flatnonzero(modes == "po")
    tubes = None
    if geom.caster is not None and len(sbr_objects) and max_bounces >= 2:
        tubes = shoot_sbr(geom, tx, sbr_objects, [tx] if receivers is None else receivers,
                          spacing_wavelengths=settings.sbr_spacing_wavelengths,
                          accuracy_db=settings.sbr_accuracy_db,
                          mirrors=settings.sbr_mirrors,
                          max_bounces=max_bounces)
    return SbrShot(po_objects=po_objects, sbr_objects=sbr_objects, max_bounces=max_bounces,
                   tubes=tubes)


def replaced_paths(paths: Paths, shot: SbrShot) -> np.ndarray:
    """Mask of the GO reflection paths that physical optics replaces: single reflections
    ending on a PO object, and multi-bounce ones ending on an SBR object that leave the
    transmitter in a direction the SBR tubes were shot in (:func:`~clradcom.mechanisms.
    sbr.launched`). A multi-bounce path outside every window (a facade, then the road,
    then a car: two mirrors before it, where the windows hold one) has no tube to stand
    for it, so its GO reflection stays."""
    drop = np.zeros(paths.n_paths, dtype=bool)
    if not (paths.k_max and paths.n_paths and len(shot.po_objects)):
        return drop
    nk = paths.n_interactions.astype(np.int64)
    last = np.maximum(nk - 1, 0)
    rows = np.arange(paths.n_paths)
    refl = int(InteractionType.REFLECTION)
    all_refl = np.all((paths.interaction == refl)
                      | (np.arange(paths.k_max)[None, :] >= nk[:, None]), axis=1)
    ends_on = np.where(nk > 0, paths.object_id[rows, last], -1)
    drop = (nk == 1) & np.isin(ends_on, shot.po_objects)
    multi = np.flatnonzero((nk > 1) & np.isin(ends_on, shot.sbr_objects) & all_refl)
    if len(multi) and shot.tubes is not None:
        leave = paths.points[multi, 1] - paths.points[multi, 0]
        drop[multi] = launched(shot.tubes.windows, leave)
    return drop & all_refl


def link_paths(geom: Geometry, shot: SbrShot, tx: Radar, rx: Radar,
               settings: OpticsSettings) -> list[Paths]:
    """PO facet returns and SBR-PO tube returns of one link (those that exist)."""
    if geom.caster is None or len(shot.po_objects) == 0:
        return []
    parts = [po_paths(geom, tx, rx, objects=shot.po_objects,
                      split=settings.po_split)]
    if shot.tubes is not None:
        parts.append(sbr_paths(geom, tx, rx, objects=shot.sbr_objects,
                               max_bounces=shot.max_bounces, shot=shot.tubes))
    return parts
