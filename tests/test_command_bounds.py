"""Options whose values the machine or the arithmetic cannot honour are refused at the
command line, in one line (issue #28)."""

from __future__ import annotations

from pathlib import Path

import pytest

from clradcom.cli import main as clradcom_main
from clradcom.distributed import max_local_workers

STREET = Path(__file__).resolve().parents[1] / "scenes" / "street" / "street.toml"


def _refused(argv, capsys) -> str:
    with pytest.raises(SystemExit) as info:
        clradcom_main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    return err[-1]


@pytest.mark.parametrize("snr", ["-1e308", "1e308", "201", "-100.5"])
def test_comms_refuses_an_snr_beyond_float_range(tmp_path, capsys, snr):
    line = _refused(["comms", str(STREET), f"--snr-db={snr}", "--out", str(tmp_path / "c")],
                    capsys)
    assert "--snr-db" in line and "[-100, 200]" in line
    assert not (tmp_path / "c").exists()


@pytest.mark.parametrize("command", ["sweep", "drive"])
def test_workers_beyond_the_machine_are_refused(tmp_path, capsys, command):
    n = max_local_workers() + 1
    line = _refused([command, str(STREET), "--workers", str(n), "--out", str(tmp_path / "o")],
                    capsys)
    assert "--workers" in line and f"at most {n - 1}" in line
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("command", ["sweep", "drive"])
def test_a_scheduler_of_the_wrong_form_is_refused(tmp_path, capsys, command):
    line = _refused([command, str(STREET), "--scheduler", "not-a-url",
                     "--out", str(tmp_path / "o")], capsys)
    assert "--scheduler" in line and "is not a Dask scheduler address" in line
