"""tools/bench_specular_sets.py on the street with few rays: a setting equal to the
reference misses none of its paths and adds none, a sparser one misses some and the tool
names them; options in error are one line and exit code 2. Nothing here asserts a speed."""

import re

import pytest
from tool_helpers import load_tool


def test_the_tool_matches_path_sets_one_to_one(capsys):
    tool = load_tool("bench_specular_sets")
    assert tool.main(["--settings", "2e4,2e3,2e4", "--reference", "2e4", "--times", "0",
                      "--repeats", "1"]) == 0
    out = capsys.readouterr().out
    n_ref = int(re.search(r"reference 2e\+04 finds (\d+) paths", out).group(1))
    rows = re.findall(r"^  (\de\+0\d) +(\d+) paths, misses (\d+) of the reference's and "
                      r"(\d+) of 2e\+04's, (\d+) beyond", out, re.M)
    assert [r[0] for r in rows] == ["2e+04", "2e+03", "2e+04"]
    same, sparse = rows[0], rows[1]
    assert same[1:] == (str(n_ref), "0", "0", "0") == rows[2][1:]
    assert int(sparse[2]) >= 1 and int(sparse[1]) + int(sparse[2]) - int(sparse[4]) == n_ref
    assert out.count("      misses ") == int(sparse[2])
    assert "(1.00 of the baseline)" in out


def test_options_in_error_are_one_line(capsys):
    tool = load_tool("bench_specular_sets")
    for bad in (["--settings", "3e5:x"], ["--settings", "0"], ["--times", "a"],
                ["--reference", "1e6:17"]):
        with pytest.raises(SystemExit) as exc:
            tool.main(bad)
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert err.strip().splitlines()[-1].startswith("bench_specular_sets.py: error: ")
