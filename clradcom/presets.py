"""Named tracer presets: one physics for the ``clradcom`` command, the tools and the API.

A preset is a set of changes to :class:`clradcom.trace.TraceSettings`'s dataclass
defaults, written as ``mechanism__field`` names (the form of ``TraceSettings.replace``),
so this module needs nothing from the rest of the package. ``TraceSettings.preset(name)``
builds one; ``trace_scene(scene)`` without settings traces with :data:`DEFAULT_PRESET`,
which is also what ``clradcom trace`` and ``tools/trace.py`` use when no option changes
it.

=========  ==================================================================================
paper      the paper's street as published: up to 5 specular reflections from 3e5 rays
           per transmitter and 4 rounds of candidate expansion (on the street's four
           links at 21 instants every specular path a 1e6-ray launch finds, and two of
           the three it misses that 1e7 rays find, in about half the time:
           docs/performance.md, "The main job's specular paths from 3e5 rays"), 1 UTD
           edge diffraction, physical optics
           with SBR-PO for conductors and bodies (PEC, metals of any conductivity,
           skin: |Gamma(0)|^2 >= -4 dB, docs/po.md; multi-bounce corner returns),
           single Lambertian scattering from the trees. Finds cars B, C and D of the
           street (Table III).
fast       a quick look: 1e5 rays, up to 3 reflections, 1 diffraction, PO facets without
           SBR, no scattering. Misses multi-bounce returns (car D on the street).
accurate   more than the paper: 4e6 rays, 5 reflections, up to 2 diffractions with one
           reflection beside them, SBR at the finest tube grid (0.25 dB), scattering with
           one reflection before or after the tile.
go         pure geometrical optics with diffraction (the dataclass defaults): no physical
           optics, no scattering. What ``trace_scene`` did before presets existed.
=========  ==================================================================================
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["DEFAULT_PRESET", "PRESETS", "Preset", "preset_names"]


@dataclass(frozen=True)
class Preset:
    """A named set of changes to TraceSettings' defaults, with a one-line summary."""

    name: str
    summary: str
    changes: dict = field(default_factory=dict)


PRESETS: dict[str, Preset] = {p.name: p for p in (
    Preset("paper", "the paper's physics: 5 reflections (3e5 rays + 4 rounds of "
                    "candidate expansion: on the street, the paths of 1e6 rays and more), "
                    "1 diffraction, "
                    "PO + SBR for conductors and bodies, scattering from the trees",
           {"specular__rays": 300_000, "specular__expand_rounds": 4,
            "specular__max_reflections": 5,
            "diffraction__max_diffractions": 1, "diffraction__max_reflections": 0,
            "optics__mode": "sbr", "scattering__enabled": True,
            "scattering__max_reflections": 0}),
    Preset("fast", "a quick look: 1e5 rays, 3 reflections, 1 diffraction, PO facets "
                   "without SBR, no scattering",
           {"specular__rays": 100_000, "specular__max_reflections": 3,
            "diffraction__max_diffractions": 1, "diffraction__max_reflections": 0,
            "optics__mode": "pec", "scattering__enabled": False}),
    Preset("accurate", "more than the paper: 4e6 rays, 5 reflections, 2 diffractions "
                       "with a reflection beside, finest SBR grid, scattering with a "
                       "reflection",
           {"specular__rays": 4_000_000, "specular__max_reflections": 5,
            "diffraction__max_diffractions": 2, "diffraction__max_reflections": 1,
            "optics__mode": "sbr", "optics__sbr_accuracy_db": 0.25,
            "scattering__enabled": True, "scattering__max_reflections": 1}),
    Preset("go", "pure geometrical optics with 1 diffraction: no physical optics, no "
                 "scattering (the settings' dataclass defaults)", {}),
)}

#: the preset of ``trace_scene(scene)`` without settings and of ``clradcom trace``
DEFAULT_PRESET = "paper"


def preset_names() -> tuple[str, ...]:
    """The presets' names, in the order of :data:`PRESETS`."""
    return tuple(PRESETS)
