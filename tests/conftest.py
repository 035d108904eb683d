"""The suite's device: ``--device NAME`` (or ``CLRADCOM_DEVICE``) runs the kernel tests
on any OpenCL device, ``--fp64=off`` in the mode of a device without fp64; the
``conformance`` and ``oclgrind`` markers name the tests tests/test_device_matrix.py
runs on the other implementations (docs/devices.md)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from device_helpers import entry_device, oclgrind_reports, start_subset_runs

from clradcom.device.runtime import ENV_DEVICE, ENV_FP64, OpenCLError, get_runtime, list_devices

#: The kernel tests (issue #26): ray casting, reflection keys, image points, visibility,
#: edges, silhouette rasters, SBR, scattering, precision, the radio maps' kernels, the
#: runtime, and the whole trace against the host reference. They hold device results to
#: the host's, so they hold on every implementation; tests/test_device_matrix.py runs them
#: on the others.
CONFORMANCE_MODULES = frozenset({
    "test_opencl",
    "test_kernel_time",
    "test_raycast",
    "test_instances",
    "test_lattice_sequences",
    "test_image_points",
    "test_visibility",
    "test_visibility_device",
    "test_diffraction_edges_device",
    "test_sbr_windows",
    "test_sbr_launch",
    "test_sbr_shot_paths",
    "test_sbr_engines",
    "test_scatter_device",
    "test_phase_precision",
    "test_golden_snapshot",
    "test_engines_whole_trace",
    "test_tiny_scenes",
    "test_maps",
    "test_maps_coherent",
    "test_maps_po",
    "test_map_walk",
})

#: What Oclgrind runs with all its checks on (a simulator, unoptimised: ~10^4 times slower
#: than PoCL; about two minutes in all on two busy cores): whole traces of the plate and
#: the dihedral at 2000 rays (every mechanism of the paper preset), and kernel unit tests
#: of a few triangles and at most a few thousand rays, one or more for every kernel file.
#: Each entry is a module or one test (module::name, all its parameters) of a conformance
#: module; tests that make a build fail on purpose are left out (Oclgrind's API check
#: reports the failure).
OCLGRIND_TESTS = frozenset({
    "test_tiny_scenes",
    "test_opencl::test_device_list_and_default_is_gpu_or_pocl",
    "test_opencl::test_device_spec_by_index_name_and_env",
    "test_opencl::test_cli_lists_devices",
    "test_opencl::test_programs_are_cached_per_runtime",
    "test_opencl::test_kernels_see_the_hosts_numbers",
    "test_opencl::test_host_dtypes_match_kernel_structs",
    "test_opencl::test_empty_buffers_and_oclgrinds_host_written_ones",
    "test_raycast::test_random_soup_matches_brute_force",
    "test_raycast::test_grazing_rays_hit_on_the_surface",
    "test_raycast::test_packets_on_a_few_rays",
    "test_image_points",
    "test_visibility_device::test_surface_sight_lines_decide_alike",
    "test_phase_precision::test_scalar_ops_within_published_bounds",
    "test_phase_precision::test_polyline_phase_within_one_degree",
    "test_scatter_device::test_sight_flags_and_lambertian_power_against_host_casts",
    "test_maps::test_device_accumulation_matches_the_float64_reference",
    "test_maps_coherent::test_segment_records_add_up_to_the_accumulated_cells",
    "test_maps_po::test_device_po_fields_on_a_few_cells",
    "test_map_walk::test_device_walk_on_a_few_rays",
    "test_map_walk::test_device_walk_drops_sbr_exits_on_a_few_rays",
    "test_maps_po::test_one_launch_po_stage_on_a_few_cells",
})

def pytest_addoption(parser):
    group = parser.getgroup("clradcom", "clradcom's OpenCL device")
    group.addoption(
        "--device", default=None, metavar="NAME",
        help="run the kernel tests on this OpenCL device: pocl, intel, nvidia, amd, "
             "oclgrind, P:D or part of a name (clradcom devices lists them); sets "
             f"{ENV_DEVICE} for the session. Default: {ENV_DEVICE}, else clradcom's "
             "default device.")
    group.addoption(
        "--fp64", choices=("auto", "off"), default="auto",
        help="off: run every kernel as on a device without fp64 (sets "
             f"{ENV_FP64}=0 for the session); auto: fp64 where the device has it.")


def pytest_configure(config):
    # the environment, not only the fixture: code that calls get_runtime() itself, and
    # the commands tests start in subprocesses, must agree with the runtime fixture
    device = config.getoption("--device")
    if device:
        os.environ[ENV_DEVICE] = device
    if config.getoption("--fp64") == "off":
        os.environ[ENV_FP64] = "0"
    config.addinivalue_line(
        "markers", "conformance: a kernel test that holds on every OpenCL implementation "
                   "(run on each by tests/test_device_matrix.py)")
    config.addinivalue_line(
        "markers", "oclgrind: small enough for Oclgrind with its checks on "
                   "(tests/test_device_matrix.py runs these there)")


def _module(item) -> str:
    return Path(str(item.fspath)).stem


def pytest_collection_modifyitems(config, items):
    for item in items:
        module = _module(item)
        if module in CONFORMANCE_MODULES:
            item.add_marker(pytest.mark.conformance)
        name = f"{module}::{item.name}"
        base = f"{module}::{item.originalname}" if getattr(item, "originalname", None) \
            else name
        if module in OCLGRIND_TESTS or name in OCLGRIND_TESTS or base in OCLGRIND_TESTS:
            item.add_marker(pytest.mark.oclgrind)
    # the device matrix last: its subprocesses, started when collection is done, run
    # while the rest of the suite does
    items.sort(key=lambda item: _module(item) == "test_device_matrix")


def pytest_collection_finish(session):
    if session.config.option.collectonly:
        return
    names = [item.callspec.params.get("name") for item in session.items
             if _module(item) == "test_device_matrix"
             and getattr(item, "originalname", "") == "test_kernel_tests_pass_on"
             and hasattr(item, "callspec")]
    present = {info.vendor for info in list_devices()}
    start_subset_runs([n for n in names if entry_device(n)[0] in present])


@pytest.fixture(scope="session")
def runtime():
    """The session's OpenCL runtime: --device / CLRADCOM_DEVICE, else the default device
    (PoCL's CPU device in CI); --fp64=off / CLRADCOM_FP64=0 runs it without fp64."""
    return get_runtime()


def no_fp64_devices() -> list[str]:
    """The implementations the no-fp64 mode is forced on: PoCL, and Intel's CPU runtime
    where list_devices() shows it (CI installs it)."""
    names = ["pocl"]
    try:
        if any(d.vendor == "intel" for d in list_devices()):
            names.append("intel")
    except OpenCLError:
        pass
    return names


@pytest.fixture(scope="session", params=no_fp64_devices())
def no_fp64(request):
    """A runtime in the forced no-fp64 mode (Runtime(name, fp64=False): -D
    CLRADCOM_NO_FP64=1, precise.h's double-float), on PoCL and on Intel's runtime."""
    return get_runtime(request.param, fp64=False)


def _on_oclgrind() -> bool:
    try:
        return get_runtime().info.simulator
    except Exception:  # noqa: BLE001 - no device at all: other tests say so
        return False


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """On Oclgrind a test that passes but made Oclgrind report something (in its captured
    stderr: an API error, an out-of-bounds access, a data race, an uninitialised value)
    fails, with the reports."""
    outcome = yield
    report = outcome.get_result()
    if not report.passed or not os.environ.get(ENV_DEVICE) or not _on_oclgrind():
        return
    # this phase's own output (capstderr holds the earlier phases' too)
    text = "".join(content for title, content in report.sections
                   if title == f"Captured stderr {report.when}")
    found = oclgrind_reports(text)
    if found:
        report.outcome = "failed"
        shown = "\n  ".join(found[:20])
        more = f"\n  ... and {len(found) - 20} more" if len(found) > 20 else ""
        report.longrepr = (f"Oclgrind reported {len(found)} problem(s) during "
                           f"{report.when}:\n  {shown}{more}\n\n{text[-4000:]}")
