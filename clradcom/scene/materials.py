"""Radio materials: the paper's Table II, ITU-R P.2040-3 Table 3, user-defined.

Conventions (see docs/materials.md):

* time factor e^{+jwt}; a lossy relative permittivity is ``eps_r = eps' - j eps''``
  with ``eps'' >= 0``, so its imaginary part is **negative or zero**;
* ``roughness_m`` is the RMS surface height (m) used by the Ament / Boithias
  factor on the specular reflection coefficients -- it is *not* a conductivity;
* ``scattering_coefficient`` S in [0, 1]: the share S^2 of the reflected power
  that is scattered diffusely (effective-roughness model);
* ``cross_pol_share`` K_x in [0, 1]: share of the diffusely scattered power that
  goes into the cross polarisation (XPD_s = 10 log10((1 - K_x) / K_x));
* a PEC material has ``pec = True`` and ``eps_r = inf``; consumers must branch on
  ``pec`` (r_perp = -1, r_par = +1) and never use ``eps_r`` of a PEC.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace

from clradcom.errors import SceneError, SceneWarning

__all__ = [
    "EPS0",
    "C0",
    "Material",
    "ITU_P2040_TABLE3",
    "PAPER_MATERIALS",
    "ROUGHNESS_MODELS",
    "builtin_material_names",
    "builtin_material",
    "itu_permittivity",
    "itu_conductivity",
    "conductivity_to_eps_imag",
    "xpd_db_to_cross_pol_share",
]

#: Vacuum permittivity (F/m), CODATA 2018.
EPS0 = 8.8541878128e-12
#: Speed of light in vacuum (m/s).
C0 = 299_792_458.0

#: Names of the rough-surface reflection factors a material may ask for.
ROUGHNESS_MODELS = ("ament", "boithias")


@dataclass(frozen=True)
class Material:
    """One radio material evaluated at the scene's carrier frequency.

    Attributes
    ----------
    name : str
        Name the scene refers to it by.
    eps_r : complex
        Relative permittivity ``eps' - j eps''`` at the carrier (imag <= 0);
        ``complex(inf, 0)`` for a PEC.
    pec : bool
        Perfect electric conductor (r_perp = -1, r_par = +1 in the project's basis).
    roughness_m : float
        RMS surface height sigma_h in metres (>= 0).
    roughness_model : str
        ``"ament"`` (default) or ``"boithias"``.
    scattering_coefficient : float
        S in [0, 1]; S^2 of the reflected power is scattered diffusely.
    cross_pol_share : float
        K_x in [0, 1]: cross-polarised share of the diffusely scattered power.
    conductivity_s_m : float
        Conductivity sigma (S/m) behind the imaginary part, when the material was
        defined by one (ITU-R P.2040 or ``conductivity_s_m``); else ``nan``.
    source : str
        Where the numbers come from: ``"paper:table2"``, ``"itu-r p.2040-3:<name>"``,
        ``"user"``.
    """

    name: str
    eps_r: complex
    pec: bool = False
    roughness_m: float = 0.0
    roughness_model: str = "ament"
    scattering_coefficient: float = 0.0
    cross_pol_share: float = 0.0
    conductivity_s_m: float = math.nan
    source: str = "user"

    def hash_params(self) -> list:
        """Plain, JSON-serialisable parameters (for content hashes)."""
        eps = self.eps_r
        return [
            self.name,
            [repr(float(eps.real)), repr(float(eps.imag))],
            bool(self.pec),
            repr(float(self.roughness_m)),
            self.roughness_model,
            repr(float(self.scattering_coefficient)),
            repr(float(self.cross_pol_share)),
        ]


# ---------------------------------------------------------------------------
# ITU-R P.2040-3 Table 3:  eps' = a f^b,  sigma = c f^d  (f in GHz)
# name: ((a, b, c, d), (f_min_GHz, f_max_GHz))
# Values as tabulated in ITU-R P.2040-3 Table 3 (cross-checked against
# NVlabs/sionna-rt src/sionna/rt/radio_materials/itu.py, the 1-100 GHz rows).
ITU_P2040_TABLE3: dict[str, tuple[tuple[float, float, float, float], tuple[float, float]]] = {
    "vacuum": ((1.0, 0.0, 0.0, 0.0), (0.001, 100.0)),
    "concrete": ((5.24, 0.0, 0.0462, 0.7822), (1.0, 100.0)),
    "brick": ((3.91, 0.0, 0.0238, 0.16), (1.0, 40.0)),
    "plasterboard": ((2.73, 0.0, 0.0085, 0.9395), (1.0, 100.0)),
    "wood": ((1.99, 0.0, 0.0047, 1.0718), (0.001, 100.0)),
    "glass": ((6.31, 0.0, 0.0036, 1.3394), (0.1, 100.0)),
    "ceiling_board": ((1.48, 0.0, 0.0011, 1.075), (1.0, 100.0)),
    "chipboard": ((2.58, 0.0, 0.0217, 0.78), (1.0, 100.0)),
    "plywood": ((2.71, 0.0, 0.33, 0.0), (1.0, 40.0)),
    "marble": ((7.074, 0.0, 0.0055, 0.9262), (1.0, 60.0)),
    "floorboard": ((3.66, 0.0, 0.0044, 1.3515), (50.0, 100.0)),
    "metal": ((1.0, 0.0, 1.0e7, 0.0), (1.0, 100.0)),
    "very_dry_ground": ((3.0, 0.0, 0.00015, 2.52), (1.0, 10.0)),
    "medium_dry_ground": ((15.0, -0.1, 0.035, 1.63), (1.0, 10.0)),
    "wet_ground": ((30.0, -0.4, 0.15, 1.30), (1.0, 10.0)),
}

#: Diffuse scattering coefficient given to the paper's trees.  The paper scatters
#: diffusely only from trees (Lambertian tiles) but gives no S; 0.5 is this
#: project's assumption (it is the worked example in the physics reference §3).
TREES_SCATTERING_COEFFICIENT = 0.5

#: The paper's Table II (sigma there is the RMS roughness height, in mm).
PAPER_MATERIALS: dict[str, Material] = {
    "concrete_building": Material(
        "concrete_building", complex(5.0, -0.1), roughness_m=1.0e-3, source="paper:table2"
    ),
    "concrete_road": Material(
        "concrete_road", complex(5.0, -0.1), roughness_m=0.4e-3, source="paper:table2"
    ),
    "metal": Material("metal", complex(math.inf, 0.0), pec=True, source="paper:table2"),
    "trees": Material(
        "trees",
        complex(10.0, -6.0),
        scattering_coefficient=TREES_SCATTERING_COEFFICIENT,
        source="paper:table2",
    ),
}

ITU_PREFIX = "itu_"


def builtin_material_names() -> list[str]:
    """All names usable without defining them: the paper's and ``itu_<name>``."""
    return list(PAPER_MATERIALS) + [ITU_PREFIX + n for n in ITU_P2040_TABLE3]


def _itu_row(name: str, *, file=None, key=None):
    try:
        return ITU_P2040_TABLE3[name]
    except KeyError:
        raise SceneError(
            f"unknown ITU-R P.2040 material; known: {', '.join(ITU_P2040_TABLE3)}",
            file=file,
            key=key,
            value=name,
        ) from None


def _check_range(name, freq_hz, extrapolate, file, key):
    (_, (fmin, fmax)) = _itu_row(name, file=file, key=key)
    f_ghz = freq_hz / 1e9
    if fmin <= f_ghz <= fmax:
        return
    msg = (
        f"ITU-R P.2040-3 material '{name}' is valid only for {fmin:g}-{fmax:g} GHz, "
        f"the carrier is {f_ghz:g} GHz"
    )
    if not extrapolate:
        raise SceneError(
            msg + "; define a material with itu = '" + name + "' and "
            "allow_extrapolation = true to extrapolate the power law anyway",
            file=file,
            key=key,
            value=name,
        )
    where = f"{file}: {key}: " if file is not None else ""
    warnings.warn(where + msg + "; extrapolating the power law", SceneWarning, stacklevel=4)


def itu_conductivity(name: str, freq_hz: float, *, extrapolate: bool = False,
                     file=None, key=None) -> float:
    """Conductivity sigma = c f_GHz^d (S/m) of an ITU-R P.2040-3 Table 3 material."""
    _check_range(name, freq_hz, extrapolate, file, key)
    (_, _, c, d), _ = ITU_P2040_TABLE3[name]
    return c * (freq_hz / 1e9) ** d


def itu_permittivity(name: str, freq_hz: float, *, extrapolate: bool = False,
                     file=None, key=None) -> complex:
    """Complex relative permittivity eps' - j eps'' of an ITU-R P.2040-3 material.

    eps' = a f^b, sigma = c f^d (f in GHz), eps'' = sigma / (2 pi f eps0).
    Outside the table's frequency range this raises :class:`SceneError` unless
    ``extrapolate`` is true, in which case it warns (:class:`SceneWarning`).
    """
    if not (freq_hz > 0 and math.isfinite(freq_hz)):
        raise SceneError("frequency must be a finite positive number of Hz",
                         file=file, key=key, value=freq_hz)
    _check_range(name, freq_hz, extrapolate, file, key)
    (a, b, c, d), _ = ITU_P2040_TABLE3[name]
    f_ghz = freq_hz / 1e9
    eps_real = a * f_ghz**b
    sigma = c * f_ghz**d
    return complex(eps_real, -conductivity_to_eps_imag(sigma, freq_hz))


def conductivity_to_eps_imag(sigma_s_m: float, freq_hz: float) -> float:
    """eps'' = sigma / (2 pi f eps0) (a positive number; eps_r = eps' - j eps'')."""
    return sigma_s_m / (2.0 * math.pi * freq_hz * EPS0)


def xpd_db_to_cross_pol_share(xpd_db: float) -> float:
    """K_x from the scattering cross-polar discrimination: XPD = 10 log10((1-K)/K).

    No finite XPD overflows: beyond +-3000 dB (10^300) K is its limit, 0 or 1."""
    if abs(xpd_db) > 3000.0:
        return 0.0 if xpd_db > 0 else 1.0
    return 1.0 / (1.0 + 10.0 ** (xpd_db / 10.0))


def builtin_material(name: str, freq_hz: float, *, file=None, key=None) -> Material:
    """A built-in material evaluated at ``freq_hz``.

    ``name`` is one of the paper's (``concrete_building``, ``concrete_road``,
    ``metal`` (PEC), ``trees``) or ``itu_<table 3 name>`` (e.g. ``itu_concrete``).
    ITU materials outside their frequency range are refused.
    """
    if name in PAPER_MATERIALS:
        return PAPER_MATERIALS[name]
    if name.startswith(ITU_PREFIX) and name[len(ITU_PREFIX):] in ITU_P2040_TABLE3:
        itu = name[len(ITU_PREFIX):]
        try:
            eps = itu_permittivity(itu, freq_hz, file=file, key=key)
        except SceneError as exc:  # report the name as the user wrote it
            raise SceneError(exc.reason, file=file, key=key, value=name) from None
        sigma = itu_conductivity(itu, freq_hz)
        return Material(name, eps, conductivity_s_m=sigma, source=f"itu-r p.2040-3:{itu}")
    raise KeyError(name)


def with_overrides(base: Material, **changes) -> Material:
    """A copy of ``base`` with some fields replaced (thin wrapper on dataclasses.replace)."""
    return replace(base, **changes)
