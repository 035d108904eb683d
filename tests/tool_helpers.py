"""Shared by the tests of the command-line tools in tools/: loading one as a module, and
the small scene their end-to-end tests run on."""

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def load_tool(name: str):
    """tools/<name>.py as a module (the tools are scripts, not part of the package)."""
    spec = importlib.util.spec_from_file_location(f"{name}_tool", ROOT / "tools" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


#: a 2 m PEC plate closing at 8 m/s on a sector radar 20 m away
CLOSING_PLATE_SCENE = """
[scene]
name = "closing_plate"
carrier_hz = 24e9

[[objects]]
name = "plate"
material = "metal"
shape = "plane"
size = [2.0, 2.0]
position = [20.0, 0.0, 1.0]
rotation_deg = [0.0, -90.0, 0.0]
velocity = [-8.0, 0.0, 0.0]

[[radars]]
name = "A"
position = [0.0, 0.0, 1.0]
pattern = "sector"
tx_power_w = 0.01
noise_figure_db = 10.0
"""


#: an FMCW [waveform] table for the closing plate (tests of the FMCW scene keys)
FMCW_TABLE = """
[waveform]
kind = "fmcw"
start_frequency_hz = 23.9e9
sweep_bandwidth_hz = 200e6
chirp_duration_s = 40e-6
idle_duration_s = 10e-6
chirps = 64
adc_sample_rate_hz = 5e6
samples_per_chirp = 128
"""

#: a TDM-MIMO radar's arrays for FMCW_TABLE's radar
FMCW_ARRAYS = """tx_array = { kind = "ula", count = 2, spacing_wavelengths = 2.0 }
rx_array = { kind = "ula", count = 4, spacing_wavelengths = 0.5 }
"""
