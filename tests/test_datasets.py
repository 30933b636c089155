"""Dataset loaders on the real annotations and sequences of ../shared/data.

Independent facts used: the UAV123 paper's dataset table (Mueller et al., ECCV 2016, Table 1:
UAV123 123 sequences, 112578 frames, min 109 / max 3085; UAV20L 20 sequences, 58670 frames,
min 1717 / max 5527) and its attribute table; the benchmark kit's configSeqs.m read as text; the
UAVDT paper's single-object attribute counts; hand computations on single lines of the files."""

from __future__ import annotations

import collections
import re
import shutil

import cv2
import numpy as np
import pytest

from mata_eval.data.datasets.annotations import DatasetError
from mata_eval.data.datasets.dtb70 import DTB70
from mata_eval.data.datasets.folder import FolderDataset
from mata_eval.data.datasets.uav123 import ATTRIBUTES, UAV20L, UAV123, UAV123_10fps
from mata_eval.data.datasets.uavdt import UAVDT
from mata_eval.params import build_params
from mata_eval.core.errors import ConfigError
from mata_eval.core.sequence import FrameReadError
from mata_eval.run.config import load_experiment


def make(cls, **values):
    return cls(build_params(cls.Params, values))


@pytest.fixture(scope="module")
def uav_anno(shared_data):
    return shared_data / "annotations" / "UAV123"


@pytest.fixture(scope="module")
def uav123(uav_anno, tmp_path_factory):
    root = tmp_path_factory.mktemp("uav123_root")  # no data_seq: annotations only
    return {s.name: s for s in make(UAV123, root=str(root), annotations=str(uav_anno)).sequences()}


def test_uav123_and_uav20l_match_the_papers_dataset_table(uav123, uav_anno, tmp_path):
    lengths = [len(s) for s in uav123.values()]
    assert (len(lengths), sum(lengths), min(lengths), max(lengths)) == (123, 112578, 109, 3085)
    uav20l = make(UAV20L, root=str(tmp_path), annotations=str(uav_anno)).sequences()
    lengths = [len(s) for s in uav20l]
    assert (len(lengths), sum(lengths), min(lengths), max(lengths)) == (20, 58670, 1717, 5527)
    assert all(s.fps == 30.0 for s in uav20l) and all(s.fps == 30.0 for s in uav123.values())


def test_uav123_attribute_counts_equal_the_papers_table(uav123):
    # UAV123 paper, attribute table (number of sequences per attribute)
    published = {"SV": 109, "ARC": 68, "LR": 48, "FM": 28, "FOC": 33, "POC": 73, "OV": 30,
                 "BC": 21, "IV": 31, "VC": 60, "CM": 70, "SOB": 39}
    counts = collections.Counter(a for s in uav123.values() for a in s.attributes)
    assert dict(counts) == published
    assert set(ATTRIBUTES) == set(published)


def _config_struct(path, table, name):
    """startFrame/endFrame/path of one struct of configSeqs.m, read with a plain regex."""
    text = path.read_text()
    block = text[text.index(f"seq{table}"):]
    block = block[: block.index("};")]
    m = re.search(rf"'name','{name}','path','([^']*)','startFrame',(\d+),'endFrame',(\d+)", block)
    return m.group(1).rstrip("\\").split("\\")[-1], int(m.group(2)), int(m.group(3))


@pytest.mark.parametrize("name", ["bird1_2", "car1_3", "uav1_3", "group3_4", "person22"])
def test_uav123_frame_ranges_match_config_seqs(uav123, uav_anno, name):
    video, start, end = _config_struct(uav_anno / "configSeqs.m", "UAV123", name)
    seq = uav123[name]
    assert (seq.meta["video"], seq.meta["start_frame"], seq.meta["end_frame"]) == (video, start, end)
    assert len(seq) == end - start + 1
    assert seq.frame_paths[0].endswith(f"data_seq/UAV123/{video}/{start:06d}.jpg")
    assert seq.frame_paths[-1].endswith(f"data_seq/UAV123/{video}/{end:06d}.jpg")


def test_got10k_json_gives_the_same_ranges_as_config_seqs(uav123, uav_anno, tmp_path):
    via_json = make(UAV123, root=str(tmp_path), annotations=str(uav_anno),
                    frame_ranges=str(uav_anno / "got10k_uav123_frame_ranges.json")).sequences()
    assert [s.name for s in via_json] == list(uav123)
    for s in via_json:
        assert s.meta == uav123[s.name].meta
        assert [p.split("data_seq/")[1] for p in s.frame_paths] == \
            [p.split("data_seq/")[1] for p in uav123[s.name].frame_paths]


def test_nan_rows_are_preserved(uav123, uav_anno):
    with_nan = 0
    for name, seq in uav123.items():
        lines = (uav_anno / f"{name}.txt").read_text().splitlines()
        nan_lines = [i for i, ln in enumerate(lines) if "nan" in ln.lower()]
        assert np.flatnonzero(np.isnan(seq.groundtruth).any(axis=1)).tolist() == nan_lines
        with_nan += bool(nan_lines)
    assert with_nan == 33  # README: 33 of the 123 UAV123 files hold NaN rows
    first = (uav_anno / "bike1.txt").read_text().splitlines()[0]
    assert uav123["bike1"].groundtruth[0].tolist() == [float(v) for v in first.split(",")]


def test_sequence_subset_and_unknown_name(uav_anno, tmp_path):
    seqs = make(UAV123, root=str(tmp_path), annotations=str(uav_anno), sequences=["uav2", "bike1"]).sequences()
    assert [s.name for s in seqs] == ["uav2", "bike1"]
    with pytest.raises(DatasetError, match="unknown sequence.*'bike99'"):
        make(UAV123, root=str(tmp_path), annotations=str(uav_anno), sequences=["bike99"]).sequences()


def test_uav123_10fps_official_layout_with_real_frames(shared_data, uav_anno, tmp_path):
    """data_seq/UAV123_10fps/wakeboard7 (the real frames) + anno/UAV123_10fps/wakeboard7.txt."""
    src = shared_data / "sequences" / "uav123_10fps" / "wakeboard7"
    (tmp_path / "data_seq" / "UAV123_10fps").mkdir(parents=True)
    (tmp_path / "data_seq" / "UAV123_10fps" / "wakeboard7").symlink_to(src / "img")
    anno = tmp_path / "anno" / "UAV123_10fps"
    anno.mkdir(parents=True)
    shutil.copy(src / "groundtruth_rect.txt", anno / "wakeboard7.txt")
    shutil.copy(uav_anno / "configSeqs.m", tmp_path / "configSeqs.m")  # found under root
    with pytest.raises(DatasetError, match="no annotation file for 122 UAV123_10fps sequence"):
        make(UAV123_10fps, root=str(tmp_path)).sequences()
    (seq,) = make(UAV123_10fps, root=str(tmp_path), sequences=["wakeboard7"]).sequences()
    assert (seq.name, len(seq), seq.fps) == ("wakeboard7", 67, 10.0)
    assert seq.attributes == frozenset()  # no att/ folder here
    ref = cv2.imread(str(src / "img" / "000067.jpg"))
    assert np.array_equal(seq.image(66), ref)
    assert [f.t for f in list(seq.frames())[:3]] == pytest.approx([0.0, 0.1, 0.2])


def test_json_has_no_10fps_table(uav_anno, tmp_path):
    (tmp_path / "anno" / "UAV123_10fps").mkdir(parents=True)
    ds = make(UAV123_10fps, root=str(tmp_path), frame_ranges=str(uav_anno / "got10k_uav123_frame_ranges.json"))
    with pytest.raises(DatasetError, match="no seqUAV123_10fps table.*JSON has no UAV123_10fps.*configSeqs.m"):
        ds.sequences()


# --- generic folder layout on the real sequences ---------------------------------------------

def test_folder_layout_comma_tab_and_polygons(shared_data):
    seqs = {s.name: s for s in make(FolderDataset, root=str(shared_data / "sequences")).sequences()}
    assert set(seqs) == {"otb_Couple", "vot15_bag"}  # uav123_10fps/ holds sequences one level down
    couple = seqs["otb_Couple"]
    assert len(couple) == 140 and couple.groundtruth[0].tolist() == [51, 47, 25, 62]  # "51\t47\t25\t62"
    bag = seqs["vot15_bag"]
    # row 1: 291.827,203.603,396.382,264.289,442.173,185.397,337.618,124.711
    # x: min 291.827 max 442.173 -> w 150.346; y: min 124.711 max 264.289 -> h 139.578
    assert bag.groundtruth[0] == pytest.approx([291.827, 124.711, 150.346, 139.578], abs=1e-9)
    assert len(bag) == 196
    assert np.array_equal(bag.image(10), cv2.imread(str(shared_data / "sequences/vot15_bag/imgs/00000011.jpg")))
    assert np.array_equal(couple.image(139), cv2.imread(str(shared_data / "sequences/otb_Couple/img/0140.jpg")))
    wake = {s.name: s for s in make(FolderDataset, root=str(shared_data / "sequences" / "uav123_10fps"),
                                    fps=10.0).sequences()}
    w7 = wake["wakeboard7"]
    assert len(w7) == 67 and w7.groundtruth[0].tolist() == [623, 299, 11, 38] and w7.fps == 10.0
    assert np.array_equal(w7.image(5), cv2.imread(str(shared_data / "sequences/uav123_10fps/wakeboard7/img/000006.jpg")))


def test_folder_single_sequence_root(shared_data):
    (bag,) = make(FolderDataset, root=str(shared_data / "sequences" / "vot15_bag")).sequences()
    assert bag.name == "vot15_bag" and len(bag) == 196


def test_missing_frame_folder_fails_at_image_not_listing(shared_data, tmp_path):
    seq_dir = tmp_path / "couple"
    seq_dir.mkdir()
    shutil.copy(shared_data / "sequences/otb_Couple/groundtruth_rect.txt", seq_dir)
    (seq,) = make(FolderDataset, root=str(tmp_path)).sequences()
    assert len(seq) == 140
    with pytest.raises(FrameReadError, match=r"frame 3 of sequence 'couple'.*couple/img"):
        seq.image(3)
    # official layout without data_seq: the computed path is named
    uav = make(UAV123, root=str(tmp_path), annotations=str(shared_data / "annotations/UAV123"),
               sequences=["bird1_2"]).sequences()[0]
    with pytest.raises(FrameReadError, match=r"data_seq/UAV123/bird1/000775\.jpg"):
        uav.image(0)


# --- DTB70 and UAVDT annotations -------------------------------------------------------------

def test_dtb70_annotations(shared_data, tmp_path):
    seqs = {s.name: s for s in make(DTB70, root=str(tmp_path),
                                    annotations=str(shared_data / "annotations/DTB70")).sequences()}
    assert len(seqs) == 70
    car6 = seqs["Car6"]
    zero = [i for i, ln in enumerate((shared_data / "annotations/DTB70/Car6.txt").read_text().splitlines())
            if [float(v) for v in ln.split(",")] == [0, 0, 0, 0]]
    assert len(zero) == 19 and (car6.groundtruth[zero] == 0).all()  # 0,0,0,0 = absent, kept as written
    flags = (shared_data / "annotations/DTB70/att/Animal1.txt").read_text().strip().split(",")
    order = ["SV", "ARV", "OCC", "DEF", "FCM", "IPR", "OPR", "OV", "BC", "SOA", "MB"]
    assert seqs["Animal1"].attributes == {a for a, f in zip(order, flags) if f == "1"}


def test_uavdt_annotations_match_the_papers_attribute_counts(shared_data, tmp_path):
    seqs = make(UAVDT, root=str(tmp_path), annotations=str(shared_data / "annotations/UAVDT")).sequences()
    assert len(seqs) == 50
    counts = collections.Counter(a for s in seqs for a in s.attributes)
    # UAVDT paper (Du et al., ECCV 2018), SOT attributes: BC 29, CR 30, OR 32, SO 23, IV 28, OB 23,
    # SV 29, LO 20 (the kit names CR "camera motion" and OR "object motion"; LT is the kit's extra flag)
    assert {k: counts[k] for k in ("BC", "CM", "OM", "SO", "IV", "OB", "SV", "LO")} == \
        {"BC": 29, "CM": 30, "OM": 32, "SO": 23, "IV": 28, "OB": 23, "SV": 29, "LO": 20}
    s0101 = next(s for s in seqs if s.name == "S0101")
    assert s0101.groundtruth[0].tolist() == [622, 348, 190, 191]
    assert s0101.frame_paths[0].endswith("UAV-benchmark-S/S0101/img000001.jpg")


def test_scoring_published_dtb70_results_needs_annotations_only(shared_data, tmp_path, monkeypatch):
    """SiamAPN++ results scored through the DTB70 loader reproduce its authors' published
    DTB70 numbers (success AUC 0.594, precision 0.790), and no image is read."""
    import zipfile

    from mata_eval.score.evaluate import evaluate_results

    with zipfile.ZipFile(shared_data / "results" / "DTB70.zip") as z:
        z.extractall(tmp_path, members=[n for n in z.namelist() if "/SiamAPN++/" in n])
    (results,) = list(tmp_path.rglob("SiamAPN++"))
    reads = []
    monkeypatch.setattr(cv2, "imread", lambda *a, **k: reads.append(a))
    seqs = make(DTB70, root=str(tmp_path / "no_frames"), annotations=str(shared_data / "annotations/DTB70")).sequences()
    overall = evaluate_results(results, seqs).summary.overall
    assert overall.n_sequences == 70
    assert overall.msr == pytest.approx(0.594, abs=0.001)
    assert overall.precision20 == pytest.approx(0.790, abs=0.0015)
    assert reads == []


@pytest.mark.parametrize("plugin", ["folder", "dtb70", "uavdt", "vtuav", "video", "rosbag"])
@pytest.mark.parametrize("fps", ["0", "-30", ".nan", ".inf"])  # YAML spellings
def test_a_frame_rate_that_is_not_a_positive_number_is_refused_when_the_experiment_is_loaded(
        plugin, fps, tmp_path):
    """``fps: 0`` passed ``validate`` and then divided by zero in the EOP plan (a traceback) or
    failed every sequence at run time: each dataset with an ``fps`` key refuses it at load time,
    with the file, line and key (QA pass, round 2)."""
    path = tmp_path / "exp.yaml"
    extra = {"video": "  path: clip.mp4\n  init_box: [1, 1, 5, 5]\n",
             "rosbag": "  path: flight.bag\n  image_topic: /cam\n  init_box: [1, 1, 5, 5]\n"}.get(plugin, "  root: data\n")
    path.write_text(f"name: e\ndataset:\n  name: {plugin}\n{extra}  fps: {fps}\n"
                    "tracker: {name: kcf}\nprotocol: {name: ltp}\n")
    with pytest.raises(ConfigError, match=rf"exp.yaml:2: dataset: {plugin}: fps: expected a positive number"):
        load_experiment(path)


def test_a_missing_uav123_root_says_so(tmp_path):
    """Not "no frame-range table ... Looked for: 15 paths", which sends a user looking for a
    file when the folder itself is missing (QA pass)."""
    for cls in (UAV123, UAV123_10fps, UAV20L):
        with pytest.raises(DatasetError, match=rf"{cls.name} dataset root not found: {tmp_path / 'nowhere'}"):
            make(cls, root=str(tmp_path / "nowhere")).sequences()
        with pytest.raises(DatasetError, match=rf"annotations: folder not found: {tmp_path / 'nope'}"):
            make(cls, root=str(tmp_path), annotations=str(tmp_path / "nope")).sequences()
