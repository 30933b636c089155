"""Compatibility profiles against the toolkits' own code on real results (the five trackers of
../shared/data/results/DTB70.zip): `got10k` against the got10k toolkit (PyPI `got10k`, a test
dependency; its ExperimentDTB70.report() runs here), `pysot-toolkit` against pysot-toolkit's
statistics functions from a checkout ($MATA_PYSOT_TOOLKIT_REPO; not on PyPI). DTB70's Car6 holds
19 ground-truth rows `0,0,0,0` (target out of view) that got10k scores as failures."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

from mata_eval.data.datasets.dtb70 import DTB70
from mata_eval.params import build_params
from mata_eval.score import evaluate

def dtb70(shared: Path) -> list:
    """The 70 DTB70 sequences, annotations only (our loader)."""
    ann = shared / "annotations" / "DTB70"
    return DTB70(build_params(DTB70.Params, {"root": str(ann), "annotations": str(ann)})).sequences()


got10k_dtb70 = pytest.importorskip("got10k.experiments.dtb70", reason="the got10k toolkit is not installed")

TRACKERS = ("LightTrack", "NanoTrack", "SiamAPN", "SiamAPN++", "SiamTPN")


@pytest.fixture(scope="module")
def got10k_report(shared_data, tmp_path_factory):
    """got10k's own report: its DTB70 layout (<root>/<seq>/groundtruth_rect.txt, img/ with one
    file per frame; the report reads no image, so empty files do) and results/DTB70/<tracker>/."""
    tmp = tmp_path_factory.mktemp("got10k")
    ann = shared_data / "annotations" / "DTB70"
    root = tmp / "DTB70"
    for gt in sorted(ann.glob("*.txt")):
        if gt.name.startswith(("ATTRIBUTE", "README")):
            continue
        seq = root / gt.stem
        (seq / "img").mkdir(parents=True)
        text = gt.read_text()
        (seq / "groundtruth_rect.txt").write_text(text)
        for k in range(1, len(text.strip().splitlines()) + 1):
            (seq / "img" / f"{k:05d}.jpg").touch()
    with zipfile.ZipFile(shared_data / "results" / "DTB70.zip") as z:
        z.extractall(tmp / "results")
    import matplotlib

    matplotlib.use("Agg")
    exp = got10k_dtb70.ExperimentDTB70(str(root), result_dir=str(tmp / "results"), report_dir=str(tmp / "reports"))
    return tmp, exp.report(list(TRACKERS))


@pytest.mark.parametrize("tracker", TRACKERS)
def test_got10k_profile_reproduces_the_got10k_toolkit_on_dtb70(tracker, got10k_report, shared_data):
    tmp, perf = got10k_report
    seqs = dtb70(shared_data)
    _, found = evaluate.read_results(tmp / "results" / "DTB70" / tracker)
    per_seq, _, summary, missing, _ = evaluate.score_results(found, seqs, profile="got10k")
    assert not missing
    theirs = perf[tracker]
    for name, s in per_seq.items():
        ref = theirs["seq_wise"][name]
        assert s.msr == pytest.approx(ref["success_score"], abs=1e-12), name
        assert s.precision20 == pytest.approx(ref["precision_score"], abs=1e-12), name
        assert s.sr == pytest.approx(ref["success_rate"], abs=1e-12), name
    overall = theirs["overall"]
    for ours, key in ((summary.overall.msr, "success_score"), (summary.overall.precision20, "precision_score"),
                      (summary.overall.sr, "success_rate")):
        assert round(ours, 4) == round(overall[key], 4)
        assert ours == pytest.approx(overall[key], abs=1e-12)


def test_car6_zero_rows_count_for_got10k_and_are_skipped_by_default(got10k_report, shared_data):
    """The 19 `0,0,0,0` rows of Car6 stay in got10k's denominator (as failures: IoU 0) and are
    skipped by the default profile; this is what moved SiamAPN's P@20 in the third decimal."""
    tmp, perf = got10k_report
    car6 = [s for s in dtb70(shared_data) if s.name == "Car6"]
    _, found = evaluate.read_results(tmp / "results" / "DTB70" / "SiamAPN")
    got10k = evaluate.score_results(found, car6, profile="got10k")[0]["Car6"]
    default = evaluate.score_results(found, car6, profile="default")[0]["Car6"]
    assert got10k.n_invalid_gt == default.n_invalid_gt == default.n_excluded == 19
    assert got10k.n_excluded == 0
    n = got10k.n_frames
    # success at IoU > 0 (first threshold): the zero rows fail in got10k, are absent by default
    assert got10k.success_curve[0] * n == pytest.approx(default.success_curve[0] * (n - 19))
    assert got10k.msr == pytest.approx(perf["SiamAPN"]["seq_wise"]["Car6"]["success_score"], abs=1e-12)


# --- pysot-toolkit's own code (not on PyPI: a checkout, like mmtracking's golden test) -----------

def _pysot_toolkit_statistics() -> dict:
    """success_overlap / success_error / overlap_ratio from a pysot-toolkit checkout
    ($MATA_PYSOT_TOOLKIT_REPO), read from git so no build of its Cython module is needed; the
    numba decorators are dropped (they only compile the same numpy code)."""
    import os
    import subprocess

    root = os.environ.get("MATA_PYSOT_TOOLKIT_REPO")
    if not root:
        pytest.skip("set MATA_PYSOT_TOOLKIT_REPO to a StrangerZhang/pysot-toolkit checkout (or mirror)")
    src = subprocess.run(["git", "-C", root, "show", "HEAD:pysot/utils/statistics.py"],
                         check=True, capture_output=True, text=True).stdout
    src = "\n".join(line for line in src.splitlines()
                    if line.strip() not in ("from numba import jit", "from . import region", "@jit(nopython=True)"))
    namespace: dict = {}
    exec(compile(src, "pysot/utils/statistics.py", "exec"), namespace)  # noqa: S102 (a reference toolkit)
    return namespace


def test_pysot_toolkit_profile_equals_pysot_toolkit_code_on_dtb70(shared_data, tmp_path):
    """OPEBenchmark's per-sequence success (AUC) and precision at 20 px, computed by the
    toolkit's own functions on the raw ground truth, for all five trackers of DTB70.zip."""
    stats = _pysot_toolkit_statistics()
    ann = shared_data / "annotations" / "DTB70"
    seqs = dtb70(shared_data)
    with zipfile.ZipFile(shared_data / "results" / "DTB70.zip") as z:
        z.extractall(tmp_path)

    def center(b):  # OPEBenchmark.convert_bb_to_center
        return np.array([b[:, 0] + (b[:, 2] - 1) / 2, b[:, 1] + (b[:, 3] - 1) / 2]).T

    for tracker in TRACKERS:
        _, found = evaluate.read_results(tmp_path / "DTB70" / tracker)
        per_seq = evaluate.score_results(found, seqs, profile="pysot-toolkit")[0]
        for seq in seqs:
            gt = np.loadtxt(ann / f"{seq.name}.txt", delimiter=",")
            pred = found[seq.name].boxes
            auc = np.mean(stats["success_overlap"](gt, pred, len(gt)))
            p20 = stats["success_error"](center(gt), center(pred), np.arange(0, 51, 1), len(gt))[20]
            assert per_seq[seq.name].msr == pytest.approx(auc, abs=1e-12), (tracker, seq.name)
            assert per_seq[seq.name].precision20 == pytest.approx(p20, abs=1e-12), (tracker, seq.name)
