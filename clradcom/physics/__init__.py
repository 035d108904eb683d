"""Field physics on plain arrays: Fresnel and roughness reflection dyads, path transfer,
gains, delay and Doppler (em), UTD wedge coefficients (utd), PO radiation integrals (po)."""
