"""Experiment files cannot write outside the output folder, cannot exhaust memory, and cannot
hide a mistake behind a duplicate key."""

from __future__ import annotations

import textwrap
import time
import tracemalloc

import pytest

from mata_eval.run.config import load_experiment
from mata_eval.core.errors import ConfigError

BASE = "dataset: {name: synthetic}\ntracker: {name: kcf}\n"


def _load(tmp_path, text, name="exp.yaml"):
    p = tmp_path / name
    p.write_text(text)
    return load_experiment(p)


@pytest.mark.parametrize("name", ["../../../d/anno/UAV123_10fps", "/tmp/abs", "a/b", "..", ".", ""])
def test_a_run_name_is_one_folder_name(tmp_path, name):
    with pytest.raises(ConfigError, match=r"exp\.yaml:1: name: .*one folder name"):
        _load(tmp_path, f"name: {name!r}\n" + BASE)


def test_a_matrix_label_is_one_folder_name(tmp_path):
    text = BASE + textwrap.dedent("""\
        matrix:
          tracker:
            ok: {name: kcf}
            "../../../x": {name: kcf}
        """)
    with pytest.raises(ConfigError, match=r"exp\.yaml:6: matrix\.tracker\.\.\./\.\./\.\./x: .*one folder name"):
        _load(tmp_path, text)


def test_duplicate_keys_name_both_lines(tmp_path):
    text = "dataset: {name: synthetic}\ntracker: {name: kcf}\nseed: 1\nseed: 2\n"
    with pytest.raises(ConfigError, match=r"exp\.yaml:4: .*duplicate key 'seed'.*line 3"):
        _load(tmp_path, text)
    nested = "dataset: {name: synthetic}\ntracker:\n  name: kcf\n  name: vittrack\n"
    with pytest.raises(ConfigError, match=r"exp\.yaml:4: .*duplicate key 'name'.*line 3"):
        _load(tmp_path, nested)


def test_merge_keys_still_override(tmp_path):
    """`<<: *base` then a key of its own is an override, not a duplicate."""
    text = textwrap.dedent("""\
        dataset: {name: synthetic}
        tracker: &kcf {name: kcf, padding: 2.5}
        matrix:
          tracker:
            a: {<<: *kcf, padding: 2.0}
            b: *kcf
        """)
    exp = _load(tmp_path, text)
    assert [r.tracker.params.padding for r in exp.runs] == [2.0, 2.5]


def test_an_alias_bomb_fails_fast_in_bounded_memory(tmp_path):
    """9 levels of 9 aliases expand to 9**9 = 387 million strings (the classic 'billion laughs')."""
    lines = ['a0: &a0 ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for i in range(1, 9):
        lines.append(f"a{i}: &a{i} [" + ",".join([f"*a{i - 1}"] * 9) + "]")
    text = BASE + "description: *a8\n"
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        with pytest.raises(ConfigError, match=r"exp\.yaml.*aliases expand to more than"):
            _load(tmp_path, "\n".join(lines) + "\n" + text)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert time.perf_counter() - t0 < 5
    assert peak < 50e6


def test_a_huge_file_is_refused_before_parsing(tmp_path):
    text = BASE + "description: '" + "x" * 2_000_000 + "'\n"
    t0 = time.perf_counter()
    with pytest.raises(ConfigError, match=r"exp\.yaml: .*2\.0 MB.*limit"):
        _load(tmp_path, text)
    assert time.perf_counter() - t0 < 1
