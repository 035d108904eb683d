"""Radar image plot (paper Fig. 3 style): files, limits, detection markers."""

import re
from pathlib import Path

import numpy as np
import pytest
from dsp_helpers import small_waveform

from clradcom.radar import (
    detect,
    radar_image,
    random_symbols,
    spectral_estimate,
    synthesize_frequency_domain,
)
from clradcom.radar.plots import IMAGE_CMAP, plot_radar_image, save_radar_image


def _scene():
    wf = small_waveform(n=256, m=64)
    d = random_symbols(wf, 0)
    r, v = np.array([16.1, 34.4]), np.array([25.7, -10.0])
    dr = synthesize_frequency_domain(d, [1.0, 0.5], wf.range_to_delay(r),
                                     wf.velocity_to_doppler(v), wf)
    img = radar_image(spectral_estimate(dr, d), wf)
    return img, detect(img, p_fa=1e-6)


def test_png_and_svg_written(tmp_path):
    img, det = _scene()
    png, svg = save_radar_image(img, tmp_path / "fig3", det)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = svg.read_text()
    assert "<svg" in text and "relative velocity" in text


def test_default_and_custom_limits_and_markers():
    img, det = _scene()
    fig = plot_radar_image(img, det)
    ax = fig.axes[0]
    assert ax.get_xlim() == (0.0, 100.0) and ax.get_ylim() == (-30.0, 30.0)
    xs, ys = ax.lines[0].get_data()
    np.testing.assert_allclose(np.sort(xs), np.sort(det["range_m"]))
    fig = plot_radar_image(img, None, range_lim_m=(10, 40), velocity_lim_mps=(-5, 50))
    assert fig.axes[0].get_xlim() == (10.0, 40.0) and fig.axes[0].get_ylim() == (-5.0, 50.0)
    with pytest.raises(ValueError, match="range_lim_m"):
        plot_radar_image(img, range_lim_m=(50, 10))


def test_radar_images_use_a_perceptually_uniform_colour_map():
    img, det = _scene()
    for fig in (plot_radar_image(img, det),):
        assert [im.get_cmap().name for im in fig.axes[0].images] == ["viridis"]


def test_no_figure_of_the_package_uses_jet():
    """Issue #31: perceptually uniform colour maps throughout; every radar image takes
    clradcom.radar.plots.IMAGE_CMAP, and no plotting code names jet (or its kin)."""
    assert IMAGE_CMAP in ("viridis", "cividis", "magma", "inferno", "plasma")
    package = Path(__file__).resolve().parents[1] / "clradcom"
    offenders = [f"{path.relative_to(package)}:{n}"
                 for path in sorted(package.rglob("*.py"))
                 for n, line in enumerate(path.read_text().splitlines(), 1)
                 if re.search(r"""cmap\s*=\s*["'](jet|rainbow|hsv|gist_rainbow)["']""", line)]
    assert not offenders, offenders
