#!/usr/bin/env python3
"""The GPU check: clradcom on a bare machine with an NVIDIA GPU and Python, in one command.

    python3 tools/gpu_check.py --fetch-wheels     # once, where a package registry is reachable
    python3 tools/gpu_check.py                    # on the GPU machine: wheels from .whl/
    python3 tools/gpu_check.py --wheels DIR --out DIR --device nvidia --budget 480

What it does, each step under its own time limit so the whole stays within --budget
seconds (default 480, 8 minutes):

1. Installs what such a machine lacks (pyopencl, trimesh, shapely, finufft, dask, ... and
   clradcom itself) from the wheels carried with the tree (``--fetch-wheels`` downloads
   them into ``.whl/`` on a machine that reaches a package registry: the packages of
   :data:`GPU_WHEELS`, for the GPU machine's Python), with pip, offline, into a folder of
   its own (``--site``), unless they import already.
2. Makes NVIDIA's OpenCL visible without touching /etc: where no NVIDIA platform is
   listed, it looks for the driver's ``libnvidia-opencl.so.1`` and writes an ``.icd`` file
   for it into a vendors folder of its own, beside copies of the machine's own .icd files,
   and points ``OCL_ICD_VENDORS`` there for every later step.
3. ``clradcom devices``.
4. The conformance subset of the tests (``pytest -m conformance``) on the device.
5. ``tools/bench_raycast.py`` on the device: rays per second end to end and in the kernel
   alone, against Embree on all the machine's cores.
6. ``tools/bench_trace.py --device DEVICE[,pocl]``: the paper's street (the main job's
   settings) traced on the GPU and, where the machine has PoCL, on its CPU cores: per
   stage, whole, first trace with the kernel builds, share inside kernels, the channels
   against each other, radar A's detections.
7. Prints the rows for docs/performance.md ("GPU" section) and writes them, with every
   step's log, into ``--out``.

Only the standard library is imported before step 1. Exit code 0 when every step ran and
passed, 1 when a step failed (the rows are printed regardless, with what failed).
"""

from __future__ import annotations

import argparse
import glob
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
#: where drivers put NVIDIA's OpenCL library, in the order tried
NVIDIA_OPENCL = ("/usr/local/nvidia/lib64", "/usr/lib/x86_64-linux-gnu", "/usr/lib64",
                 "/usr/lib", "/usr/local/cuda/lib64")
#: What a GPU machine with a scientific Python (numpy, scipy, matplotlib, pytest,
#: hypothesis, tqdm, psutil, pyyaml, jinja2, msgpack, sortedcontainers) lacks of
#: clradcom's dependencies and theirs, and Embree for the ray-casting reference; PoCL's
#: wheel (58 MB) stays behind: such a machine usually has its own ICDs.
GPU_WHEELS = ("pyopencl", "pytools", "siphash24", "platformdirs", "typing_extensions",
              "trimesh", "lazy-importer", "shapely", "mapbox-earcut", "finufft",
              "distributed", "dask", "cloudpickle", "toolz", "tblib", "zict", "tornado",
              "partd", "locket", "embreex")
#: the platforms pip may take binary wheels for (x86-64 Linux, glibc 2.17 and later)
WHEEL_PLATFORMS = ("manylinux_2_28_x86_64", "manylinux_2_27_x86_64", "manylinux_2_24_x86_64",
                   "manylinux_2_17_x86_64", "manylinux2014_x86_64", "manylinux1_x86_64")
#: the share of the budget each step may use at most (the rest is left for the others)
STEP_SHARE = {"install": 0.15, "devices": 0.05, "conformance": 0.45, "raycast": 0.15,
              "trace": 0.35}


class Budget:
    """Seconds left of the whole run; each step gets the lesser of its share and what is
    left."""

    def __init__(self, seconds: float):
        self.total = float(seconds)
        self.start = time.monotonic()

    def left(self) -> float:
        return self.total - (time.monotonic() - self.start)

    def for_step(self, name: str) -> float:
        return max(1.0, min(self.total * STEP_SHARE[name], self.left() - 5.0))


def run_step(name: str, cmd: list[str], env: dict, out: Path, timeout: float) -> tuple[int, str]:
    """Run ``cmd``, its output echoed and kept in ``out/<name>.log``; (exit code, text).
    A step past its time is stopped and counts as failed (exit code 124)."""
    print(f"\n=== {name}: {' '.join(cmd)}  (at most {timeout:.0f} s)", flush=True)
    t0 = time.monotonic()
    try:
        proc = subprocess.run(cmd, env=env, cwd=REPO, capture_output=True, text=True,
                              timeout=timeout)
        code, text = proc.returncode, proc.stdout + proc.stderr
    except subprocess.TimeoutExpired as exc:
        text = ((exc.stdout or b"").decode(errors="replace") if isinstance(exc.stdout, bytes)
                else (exc.stdout or "")) + f"\n{name}: stopped after {timeout:.0f} s\n"
        code = 124
    (out / f"{name}.log").write_text(text)
    print(text[-6000:], flush=True)
    print(f"=== {name}: exit {code} in {time.monotonic() - t0:.1f} s", flush=True)
    return code, text


def importable(names, env) -> bool:
    probe = "import importlib, sys\nfor n in sys.argv[1:]: importlib.import_module(n)"
    return subprocess.run([sys.executable, "-c", probe, *names], env=env, cwd="/",
                          capture_output=True).returncode == 0


def install(wheels: Path, site: Path, env: dict, out: Path, timeout: float) -> bool:
    """pyopencl and the rest from ``wheels``, and clradcom itself, into ``site``."""
    needed = ["pyopencl", "trimesh", "shapely", "finufft", "distributed", "clradcom.kernels"]
    if importable(needed, env):
        print("every package imports already: nothing to install")
        return True
    files = sorted(glob.glob(str(wheels / "*.whl")))
    if not files:
        print(f"no wheels in {wheels}: run 'python3 tools/gpu_check.py --fetch-wheels' on a "
              f"machine with a package registry and carry .whl/ with the tree",
              file=sys.stderr)
        return False
    pip = [sys.executable, "-m", "pip", "install", "-q", "--no-index", "--no-deps",
           "--no-compile", "--no-cache-dir", "--upgrade", "--target", str(site)]
    code, _ = run_step("install-wheels", pip + files, env, out, timeout)
    if code == 0:
        # the project itself, so its kernels are found as package data (clradcom.kernels)
        code, _ = run_step("install-clradcom", pip + ["--no-build-isolation", str(REPO)],
                           env, out, timeout)
    return code == 0 and importable(needed, env)


def fetch_wheels(dest: Path, python_version: str) -> int:
    """Download :data:`GPU_WHEELS` for CPython ``python_version`` on x86-64 Linux into
    ``dest`` (binary wheels only, no dependencies resolved: the list is complete)."""
    dest.mkdir(parents=True, exist_ok=True)
    platforms = [a for p in WHEEL_PLATFORMS for a in ("--platform", p)]
    missing = []
    for package in GPU_WHEELS:
        code = subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--no-deps",
                               "--only-binary=:all:", "--python-version", python_version,
                               "--implementation", "cp", *platforms, "--platform", "any",
                               "-d", str(dest), package]).returncode
        if code != 0:
            missing.append(package)
    size = sum(f.stat().st_size for f in dest.glob("*.whl")) / 2**20
    print(f"{len(list(dest.glob('*.whl')))} wheels, {size:.0f} MiB in {dest}")
    if missing:
        print(f"could not fetch: {', '.join(missing)}", file=sys.stderr)
    return 1 if missing else 0


def opencl_vendors(env: dict, folder: Path) -> None:
    """Where no NVIDIA platform is listed, an .icd file for the driver's OpenCL library
    in ``folder`` beside copies of the machine's own, and OCL_ICD_VENDORS pointing
    there."""
    probe = ("import pyopencl as cl\n"
             "print(any('nvidia' in p.name.lower() for p in cl.get_platforms()))")
    seen = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True,
                          text=True)
    if seen.stdout.strip() == "True":
        print("NVIDIA's OpenCL platform is listed already")
        return
    lib = next((p for d in NVIDIA_OPENCL for p in sorted(glob.glob(f"{d}/libnvidia-opencl.so*"))
                if os.path.isfile(p)), None)
    folder.mkdir(parents=True, exist_ok=True)
    for icd in glob.glob(os.path.join(env.get("OCL_ICD_VENDORS", "/etc/OpenCL/vendors"),
                                      "*.icd")):
        shutil.copy(icd, folder)
    if lib is None:
        print("no libnvidia-opencl.so found in " + ", ".join(NVIDIA_OPENCL), file=sys.stderr)
    else:
        (folder / "nvidia-clradcom.icd").write_text(lib + "\n")
        print(f"NVIDIA's OpenCL: {lib} (vendors folder {folder})")
    env["OCL_ICD_VENDORS"] = str(folder)


def parse_raycast(text: str) -> dict:
    out = {}
    for kind in ("primary", "bounce"):
        m = re.search(rf"^{kind}\s+(\d+)\s+([\d.]+) Mr/s\s+([\d.]+) Mr/s(?:\s+([\d.]+) Mr/s"
                      rf"\s+([\d.]+))?", text, re.M)
        if m:
            out[kind] = {"rays": int(m.group(1)), "mrays": float(m.group(2)),
                         "kernel_mrays": float(m.group(3)),
                         "embree_mrays": float(m.group(4)) if m.group(4) else None}
    return out


def parse_trace(text: str) -> dict:
    """The columns of bench_trace's device table: device -> {whole, kernels, first, ratio}."""
    lines = text.splitlines()
    head = next((i for i, ln in enumerate(lines) if ln.strip().startswith("median seconds")),
                None)
    if head is None:
        return {}
    names = lines[head].split()[2:]
    table = {}
    for ln in lines[head + 1:]:
        m = re.match(r"\s{2}(\S.*?)\s{2,}(\S.*)$", ln)
        if not m:
            break
        table[m.group(1).strip()] = m.group(2).split()
    def col(key: str, k: int) -> str:
        vals = next((v for label, v in table.items() if label.startswith(key)), None)
        return vals[k] if vals and k < len(vals) else ""

    out = {}
    for k, name in enumerate(names):
        out[name] = {"whole": col("whole trace", k), "kernels": col("inside kernels", k),
                     "first": col("first trace (builds)", k), "paths": col("paths", k),
                     "ratio": col("time /", k)}
    for ln in lines:
        m = re.match(r"\s+(\S+) radar A detections \(R m, v m/s\): (.*)$", ln)
        if m and m.group(1) in out:
            out[m.group(1)]["detections"] = m.group(2)
        m = re.match(r"\s+(\S+) channel against (\S+) \(NMSE\): (.*)$", ln)
        if m and m.group(1) in out:
            out[m.group(1)]["nmse"] = f"against {m.group(2)}: {m.group(3)}"
    return out


def device_line(text: str, name: str) -> str:
    m = re.search(rf"^\s*\*?\s*\[\d+:\d+\]\s+{re.escape(name)}\s+\S+\s+(.*)$", text, re.M)
    return m.group(1).strip() if m else name


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--wheels", type=Path, default=REPO / ".whl",
                    help="folder of the wheels to install (default .whl/ in the tree)")
    ap.add_argument("--site", type=Path, default=Path(tempfile.gettempdir()) / "clradcom-site",
                    help="folder the wheels are installed into")
    ap.add_argument("--out", type=Path, default=None,
                    help="folder for the logs and rows (default $OUT, else a new temp dir)")
    ap.add_argument("--device", default="nvidia", help="the device to check (default nvidia)")
    ap.add_argument("--budget", type=float, default=480.0,
                    help="seconds the whole check may take (default 480)")
    ap.add_argument("--rays", type=int, default=4_000_000,
                    help="primary rays of the ray-casting benchmark (default 4e6)")
    ap.add_argument("--fetch-wheels", action="store_true",
                    help="only download the wheels into --wheels (needs a package registry)")
    ap.add_argument("--python-version", default="3.12",
                    help="the GPU machine's Python, for --fetch-wheels (default 3.12)")
    args = ap.parse_args(argv)
    if args.fetch_wheels:
        return fetch_wheels(args.wheels, args.python_version)
    budget = Budget(args.budget)
    out = args.out or (Path(os.environ["OUT"]) if os.environ.get("OUT")
                       else Path(tempfile.mkdtemp(prefix="gpu_check-")))
    out.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, PYTHONUNBUFFERED="1", PYOPENCL_COMPILER_OUTPUT="0")
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(args.site), env.get("PYTHONPATH"))
                                        if p)
    failed: list[str] = []

    if not install(args.wheels, args.site, env, out, budget.for_step("install")):
        print("gpu_check: the packages could not be installed; nothing else can run",
              file=sys.stderr)
        return 1
    opencl_vendors(env, args.site / "opencl-vendors")
    py = [sys.executable]
    # -P: no working directory on sys.path, so the installed clradcom (whose kernels are
    # package data) is imported, not the tree's own folder of that name
    py_m = [sys.executable, "-P"]
    code, devices = run_step("devices", py_m + ["-m", "clradcom", "devices"], env, out,
                             budget.for_step("devices"))
    if code != 0 or not re.search(rf"\]\s+{re.escape(args.device)}\s", devices):
        print(f"gpu_check: no {args.device} device is listed", file=sys.stderr)
        failed.append("devices")
    has_pocl = bool(re.search(r"\]\s+pocl\s", devices))

    # the tests import their helpers as tests.*: the tree after the installed package
    test_env = dict(env, PYTHONPATH=os.pathsep.join([env["PYTHONPATH"], str(REPO)]))
    code, conf = run_step("conformance", py_m + [
        "-m", "pytest", "-m", "conformance", "-q", "-p", "no:cacheprovider", "-rf",
        "--device", args.device], test_env, out, budget.for_step("conformance"))
    if code != 0:
        failed.append("conformance")
    summary = re.findall(r"^=*\s*(\d+ passed.*?)\s*=*$", conf, re.M)
    conformance = summary[-1] if summary else f"exit {code}"

    code, ray_text = run_step("raycast", py + [
        "tools/bench_raycast.py", "--device", args.device, "--rays", str(args.rays),
        "--repeat", "3"], env, out, budget.for_step("raycast"))
    if code != 0:
        failed.append("raycast")
    rays = parse_raycast(ray_text)

    devs = args.device + (",pocl" if has_pocl and args.device != "pocl" else "")
    code, trace_text = run_step("trace", py + [
        "tools/bench_trace.py", "--device", devs + ("," if "," not in devs else ""),
        "--repeats", "3", "--extra", "none", "--out", str(out)], env, out,
        budget.for_step("trace"))
    if code != 0:
        failed.append("trace")
    street = parse_trace(trace_text)

    rows = [f"GPU check ({time.strftime('%Y-%m-%d')}, tools/gpu_check.py, "
            f"{budget.total - budget.left():.0f} s of {budget.total:.0f}):", "",
            "| device | conformance | rays/s primary / bounce (end to end; kernel alone; "
            "Embree on the host's cores) | street trace (median) | first trace (builds) "
            "| inside kernels | time / PoCL |",
            "|---|---|---|---|---|---|---|"]
    for name in street or {args.device: {}}:
        s = street.get(name, {})
        ray = ""
        if name == args.device and rays:
            ray = "; ".join(
                f"{k} {v['mrays']:.1f} M ({v['kernel_mrays']:.1f} M"
                + (f"; Embree {v['embree_mrays']:.1f} M)" if v["embree_mrays"] else ")")
                for k, v in rays.items())
        rows.append(f"| {device_line(devices, name)} | "
                    f"{conformance if name == args.device else ''} | {ray} | "
                    f"{s.get('whole', '')} s | {s.get('first', '')} s | {s.get('kernels', '')}"
                    f" | {s.get('ratio', '')} |")
    for name, s in street.items():
        if s.get("detections"):
            rows.append(f"\n{name}: radar A detections {s['detections']}")
        if s.get("nmse"):
            rows.append(f"{name}: channels {s['nmse']}")
    if failed:
        rows.append(f"\nfailed steps: {', '.join(failed)} (logs in {out})")
    text = "\n".join(rows)
    (out / "gpu_rows.md").write_text(text + "\n")
    print("\n" + text)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
