"""benchmarks/mata_gain.py --jitter: the shifted copies of a folder dataset and the table of
changes over the starts, checked against a hand-built dataset and hand-computed means."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import benchmark
from mata_eval.data.datasets.folder import FolderDataset


@pytest.fixture(scope="module")
def mata_gain():
    return benchmark("mata_gain")


def folder_sequences(root: Path):
    return {s.name: s for s in FolderDataset(FolderDataset.Params(root=str(root), fps=30)).sequences()}


def test_shifted_copy_moves_only_the_first_box_and_links_the_frames(tmp_path, mata_gain):
    src = tmp_path / "src"
    for name, sep in (("a", ","), ("b", "\t")):
        (src / name / "img").mkdir(parents=True)
        for k in range(3):
            (src / name / "img" / f"{k + 1:04d}.jpg").write_bytes(b"x")
        (src / name / "groundtruth_rect.txt").write_text(
            "\n".join(sep.join(v) for v in (["10", "20", "30", "40"], ["11", "21", "31", "41"],
                                              ["NaN", "NaN", "NaN", "NaN"])) + "\n")
    mata_gain.shifted_copy(src, tmp_path / "dst", 0.5, -0.5)
    before, after = folder_sequences(src), folder_sequences(tmp_path / "dst")
    assert sorted(after) == ["a", "b"]
    for name in after:
        gt0, gt1 = before[name].groundtruth, after[name].groundtruth
        np.testing.assert_array_equal(gt1[0], gt0[0] + [0.5, -0.5, 0.0, 0.0])
        np.testing.assert_array_equal(gt1[1:], gt0[1:])   # NaN rows stay NaN
        assert [Path(p).resolve() for p in after[name].frame_paths] == \
               [Path(p).resolve() for p in before[name].frame_paths]
    assert (src / "a" / "groundtruth_rect.txt").read_text().startswith("10,20,30,40")  # source untouched


def test_jitter_table_gives_the_mean_and_range_over_the_starts(mata_gain):
    def scores(base, mata):
        return {f"kcf-{d}-{p}-{c}": {"nt2f": v, "sr": v}
                for d in ("clean", "occ") for p in ("ltp", "eop") for c, v in (("base", base), ("mata", mata))}
    # changes of the five starts: -2, -2, -2, +3, -2 (mean -1.0, not below -1; below on 4 of 5)
    starts = [scores(50.0, 48.0)] * 3 + [scores(50.0, 53.0)]
    rows = mata_gain.jitter_table({"set": scores(60.0, 58.0)}, {"set": starts}, ["kcf"])
    assert rows[2] == "| set clean | LTP | -1.0 [-2.0, +3.0] | -1.0 [-2.0, +3.0] |"
    assert rows[-1] == "values below -1 point: 0 on average over the 5 starts, 0 on every start"
    worse = [scores(50.0, 48.0)] * 4
    rows = mata_gain.jitter_table({"set": scores(60.0, 58.0)}, {"set": worse}, ["kcf"])
    assert rows[-1] == "values below -1 point: 8 on average over the 5 starts, 8 on every start"
