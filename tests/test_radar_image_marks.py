"""Range–Doppler images as a reader of a radar paper expects them: the title names the
radar and the scene, the true objects are marked where they are, and the radar's own
mounting return (a strong echo at 0.5 m, zero velocity) is labelled and not the 0 dB
reference."""

import numpy as np
from dsp_helpers import small_waveform
from test_snapshot import make_paths

from clradcom.physics.em import C0
from clradcom.radar import (
    radar_image,
    random_symbols,
    spectral_estimate,
    synthesize_frequency_domain,
)
from clradcom.radar.plots import (
    MOUNTING_RETURN_M,
    image_title,
    mounting_paths,
    mounting_range_m,
    mounting_return_range_m,
    plot_radar_image,
)

GAINS = np.array([100.0, 1.0, 0.3])  # mounting return 40 dB over the first target
RANGES = np.array([0.5, 16.1, 34.4])
VELOCITIES = np.array([0.0, 25.7, -10.0])


def _image():
    wf = small_waveform(n=256, m=64)
    d = random_symbols(wf, 0)
    dr = synthesize_frequency_domain(d, GAINS, wf.range_to_delay(RANGES),
                                     wf.velocity_to_doppler(VELOCITIES), wf)
    return wf, radar_image(spectral_estimate(dr, d), wf)


TRUTH = [{"name": "carB", "range_centre_m": 16.4, "v_rel_m_s": 25.6},
         {"name": "carD", "range_centre_m": 34.6, "v_rel_m_s": -10.0}]


def _plot(mount):
    wf, img = _image()
    fig = plot_radar_image(img, title=image_title("A", "street"), truth=TRUTH,
                           mount_range_m=mounting_range_m(wf.range_resolution) if mount
                           else None)
    return wf, img, fig.axes[0]


def test_title_names_radar_and_scene():
    _, _, ax = _plot(True)
    assert ax.get_title() == "Radar A, scene street: range–Doppler image"


def test_truth_markers_sit_at_the_truth_and_carry_the_names():
    _, _, ax = _plot(True)
    marks = {ln.get_gid(): (ln.get_xdata()[0], ln.get_ydata()[0]) for ln in ax.lines
             if (ln.get_gid() or "").startswith("truth:")}
    assert marks == {"truth:carB": (16.4, 25.6), "truth:carD": (34.6, -10.0)}
    texts = {t.get_text(): t.xy for t in ax.texts}
    assert texts["carB"] == (16.4, 25.6) and texts["carD"] == (34.6, -10.0)


def test_mounting_return_is_labelled_and_not_the_reference():
    wf, img, ax = _plot(True)
    limit = mounting_range_m(wf.range_resolution)
    assert limit == MOUNTING_RETURN_M + 2 * wf.range_resolution
    data = np.asarray(ax.images[0].get_array())  # (velocity, range) in dB re the reference
    r = img.range_m[(img.range_m >= 0) & (img.range_m <= 100)]
    beyond = data[:, r >= limit]
    # 0 dB is the strongest cell beyond the mounting return: the first target's peak
    assert np.nanmax(beyond) == 0.0
    # the mounting return (40 dB stronger) stands ~40 dB above it, saturating the colours
    assert 35.0 < np.nanmax(data[:, r < limit]) < 45.0
    mark = [ln for ln in ax.lines if ln.get_gid() == "mounting_return"]
    assert len(mark) == 1
    assert abs(mark[0].get_xdata()[0] - 0.5) <= wf.range_resolution
    assert abs(mark[0].get_ydata()[0]) <= wf.velocity_resolution
    assert any("mounting return" in t.get_text() for t in ax.texts)


def test_without_the_mounting_range_the_strongest_cell_is_the_reference():
    _, _, ax = _plot(False)
    data = np.asarray(ax.images[0].get_array())
    assert np.nanmax(data) == 0.0
    assert not [ln for ln in ax.lines if ln.get_gid() == "mounting_return"]


def test_the_mounting_return_needs_a_path_from_the_mounting():
    """Issue 27, item 6: the label and the 0 dB rule hold only where the radar's own echoes
    have a path from within MOUNTING_RETURN_M of it. A radar over the road of an imported
    canyon (its nearest echo the road 1.5 m below) has none: no cell is its mounting
    return, not even a noise cell at 3.4 m."""
    res = small_waveform(n=256, m=64).range_resolution
    street = make_paths([1, 2, 1], delays=2 * np.array([0.5, 16.1, 34.4]) / C0)
    canyon = make_paths([1, 2, 0], delays=2 * np.array([1.5, 16.1, 0.3]) / C0)
    assert mounting_paths(street).tolist() == [True, False, False]
    assert mounting_return_range_m(street, res) == mounting_range_m(res)
    # the road 1.5 m under the radar is no mounting; a 0.3 m line of sight is no echo
    assert not mounting_paths(canyon).any()
    assert mounting_return_range_m(canyon, res) is None
    _, img = _image()
    ax = plot_radar_image(img, mount_range_m=mounting_return_range_m(canyon, res)).axes[0]
    assert not [ln for ln in ax.lines if ln.get_gid() == "mounting_return"]
    ax = plot_radar_image(img, mount_range_m=mounting_return_range_m(street, res)).axes[0]
    assert len([ln for ln in ax.lines if ln.get_gid() == "mounting_return"]) == 1
