"""Propagation mechanisms, each with its own settings and one shape (prepare once per
transmitter, then paths for a link): specular reflection, UTD diffraction, physical
optics (PO facets and SBR-PO), diffuse scattering. See :mod:`.common`."""
