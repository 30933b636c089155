"""Dataset loaders on tiny fake official layouts built in tmp_path (no shared data needed).

Each fake frame k of a video is a 4x6 image filled with the value k (its 1-based file number),
so ``image(i)`` is checked against the file the layout says frame i is."""

from __future__ import annotations

import dataclasses
import pickle
import textwrap
from pathlib import Path

import cv2
import numpy as np
import pytest

from mata_eval.data.datasets.annotations import (AnnotationError, DatasetError, parse_config_seqs,
                                            read_attribute_flags, read_boxes)
from mata_eval.data.datasets.dtb70 import DTB70
from mata_eval.data.datasets.folder import FolderDataset
from mata_eval.data.datasets.uav123 import UAV20L, UAV123, UAV123_10fps
from mata_eval.data.datasets.uavdt import UAVDT
from mata_eval.data.datasets.vtuav import VTUAV
from mata_eval.params import build_params, describe
from mata_eval.core.sequence import FrameReadError


def make(cls, **values):
    return cls(build_params(cls.Params, values))


def write_frames(folder: Path, n: int, name=lambda k: f"{k:06d}.png", first: int = 1) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for k in range(first, first + n):
        cv2.imwrite(str(folder / name(k)), np.full((4, 6, 3), k % 256, np.uint8))


def write_gt(path: Path, rows, sep=",") -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(sep.join(str(v) for v in r) for r in rows) + "\n")


def boxes(n, x0=10):
    return [[x0 + k, 20, 5, 6] for k in range(n)]


CONFIG_SEQS = r"""function seqs=configSeqs

seqUAV20L = {struct('name','car1','path','d:\data_seq\UAV123\car1\','startFrame',1,'endFrame',9,'nz',6,'ext','png','init_rect', [0,0,0,0])};

seqUAV123={struct('name','car1_1','path','d:\data_seq\UAV123\car1\','startFrame',1,'endFrame',4,'nz',6,'ext','png','init_rect', [0,0,0,0]),...
    struct('name','car1_2','path','d:\data_seq\UAV123\car1\','startFrame',4,'endFrame',9,'nz',6,'ext','png','init_rect', [0,0,0,0]),...
    % struct('name','commented','path','d:\data_seq\UAV123\x\','startFrame',1,'endFrame',2,'nz',6,'ext','png','init_rect', [0,0,0,0]),...
    struct('name','boat1','path','d:\data_seq\UAV123\boat1\','startFrame',1,'endFrame',3,'nz',6,'ext','png','init_rect', [0,0,0,0])};

seqUAV123_10fps = {struct('name','car1_1','path','D:\data_seq\UAV123_10fps\car1\','startFrame',1,'endFrame',2,'nz',6,'ext','png','init_rect',[0,0,0,0])};

seqs = seqUAV123; %seqUAV123, seqUAV123_10fps, seqUAV20L
"""


@pytest.fixture
def uav_root(tmp_path):
    """data_seq/UAV123/{car1 (9 frames), boat1 (3), synth1 (5, not in the table)}, anno, att."""
    root = tmp_path / "UAV123root"
    write_frames(root / "data_seq/UAV123/car1", 9)
    write_frames(root / "data_seq/UAV123/boat1", 3)
    write_frames(root / "data_seq/UAV123/synth1", 5)
    anno = root / "anno/UAV123"
    car1 = boxes(9)
    write_gt(anno / "car1_1.txt", car1[0:4])
    write_gt(anno / "car1_2.txt", [car1[3], ["NaN"] * 4, ["NaN"] * 4] + car1[6:9])
    write_gt(anno / "boat1.txt", boxes(3, 50))
    write_gt(anno / "synth1.txt", boxes(5, 70))
    write_gt(anno / "car1.txt", car1)  # full-length annotation of a split video: not a sequence
    (anno / "att").mkdir()
    for name, flags in {"car1_1": "1,0,0,1,0,0,0,0,0,0,1,0", "car1_2": "0,0,0,0,1,1,0,0,0,0,0,1",
                        "boat1": "0,0,0,0,0,0,0,0,0,0,0,0", "synth1": "0,0,0,0,0,0,1,0,0,0,0,0",
                        "car1": "1,1,1,1,1,1,1,1,1,1,1,1"}.items():
        (anno / "att" / f"{name}.txt").write_text(flags + "\n")
    (root / "util").mkdir()
    (root / "util/configSeqs.m").write_text(CONFIG_SEQS)
    return root


def test_config_seqs_parser_reads_tables_and_skips_comments(uav_root):
    tables = parse_config_seqs(uav_root / "util/configSeqs.m")
    assert list(tables) == ["UAV20L", "UAV123", "UAV123_10fps"]
    assert list(tables["UAV123"]) == ["car1_1", "car1_2", "boat1"]
    r = tables["UAV123"]["car1_2"]
    assert (r.video, r.start, r.end, r.digits, r.ext, len(r)) == ("car1", 4, 9, 6, "png", 6)


def test_uav123_subsequences_are_frame_ranges_of_the_video(uav_root):
    seqs = {s.name: s for s in make(UAV123, root=str(uav_root)).sequences()}
    assert list(seqs) == ["car1_1", "car1_2", "boat1", "synth1"]
    c2 = seqs["car1_2"]
    assert len(c2) == 6 and c2.fps == 30.0
    assert [int(c2.image(i)[0, 0, 0]) for i in range(6)] == [4, 5, 6, 7, 8, 9]
    assert np.isnan(c2.groundtruth[1:3]).all() and c2.groundtruth[3].tolist() == [16, 20, 5, 6]
    assert c2.attributes == {"FOC", "POC", "SOB"} and seqs["car1_1"].attributes == {"SV", "FM", "CM"}
    assert seqs["boat1"].attributes == frozenset()


def test_uav123_sequence_missing_from_the_table_is_the_whole_video(uav_root):
    (s,) = make(UAV123, root=str(uav_root), sequences=["synth1"]).sequences()
    assert len(s) == 5 and [int(s.image(i)[0, 0, 0]) for i in range(5)] == [1, 2, 3, 4, 5]
    assert s.attributes == {"OV"}


def test_uav20l_reads_its_own_folder_and_table(uav_root):
    anno = uav_root / "anno/UAV20L"
    write_gt(anno / "car1.txt", boxes(9))
    (s,) = make(UAV20L, root=str(uav_root), frame_ranges=str(uav_root / "util/configSeqs.m")).sequences()
    # configSeqs' seqUAV20L points into data_seq/UAV123: the long videos are shared
    assert (s.name, len(s), int(s.image(8)[0, 0, 0])) == ("car1", 9, 9)
    assert "data_seq/UAV123/car1/" in s.frame_paths[0]


def test_uav123_10fps_fps_is_10(uav_root):
    write_frames(uav_root / "data_seq/UAV123_10fps/car1", 3)
    write_gt(uav_root / "anno/UAV123_10fps/car1_1.txt", boxes(2))
    (s,) = make(UAV123_10fps, root=str(uav_root)).sequences()
    assert (s.fps, len(s), int(s.image(1)[0, 0, 0])) == (10.0, 2, 2)


def test_first_frame_range_file_with_the_table_wins(uav_root):
    import json

    (uav_root / "uav123.json").write_text(json.dumps({"UAV123": {"boat1": {
        "start_frame": 1, "end_frame": 3, "folder_name": "boat1"}}}))
    write_frames(uav_root / "data_seq/UAV123_10fps/car1", 3)
    write_gt(uav_root / "anno/UAV123_10fps/car1_1.txt", boxes(2))
    (uav_root / "util/configSeqs.m").rename(uav_root / "anno/UAV123_10fps/configSeqs.m")
    # <root>/uav123.json is found first but has no UAV123_10fps table: the configSeqs.m next to
    # the annotations is used
    (s,) = make(UAV123_10fps, root=str(uav_root)).sequences()
    assert (s.name, len(s)) == ("car1_1", 2)
    # UAV123 takes the JSON's table (boat1); files it does not mention are whole videos
    assert [s.name for s in make(UAV123, root=str(uav_root), sequences=["boat1"]).sequences()] == ["boat1"]


def test_missing_frame_range_table_says_what_and_where(uav_root):
    (uav_root / "util/configSeqs.m").unlink()
    with pytest.raises(DatasetError) as e:
        make(UAV123, root=str(uav_root)).sequences()
    msg = str(e.value)
    assert "configSeqs.m" in msg and "uav123.json" in msg and "got10k" in msg
    assert str(uav_root / "configSeqs.m") in msg and "frame_ranges" in msg
    with pytest.raises(DatasetError, match="file not found"):
        make(UAV123, root=str(uav_root), frame_ranges=str(uav_root / "nope.m")).sequences()


def test_table_sequence_without_annotation_is_an_error(uav_root):
    (uav_root / "anno/UAV123/boat1.txt").unlink()
    with pytest.raises(DatasetError, match=r"no annotation file for 1 UAV123 sequence.*boat1\.txt"):
        make(UAV123, root=str(uav_root)).sequences()
    assert [s.name for s in make(UAV123, root=str(uav_root), sequences=["car1_2"]).sequences()] == ["car1_2"]


def test_ground_truth_length_must_match_the_frame_range(uav_root):
    write_gt(uav_root / "anno/UAV123/boat1.txt", boxes(4))
    with pytest.raises(DatasetError, match=r"boat1\.txt: 4 ground-truth lines.*1\.\.3"):
        make(UAV123, root=str(uav_root)).sequences()


def test_bad_annotation_line_names_file_and_line(uav_root):
    (uav_root / "anno/UAV123/boat1.txt").write_text("1,2,3,4\n1,2,3\n1,2,3,4\n")
    with pytest.raises(AnnotationError, match=r"boat1\.txt:2: expected 4 values"):
        make(UAV123, root=str(uav_root)).sequences()
    (uav_root / "anno/UAV123/boat1.txt").write_text("1,2,3,4\n1,2,3,4\n1,2,3,4\n")
    (uav_root / "anno/UAV123/att/boat1.txt").write_text("0,1,0\n")
    with pytest.raises(AnnotationError, match=r"att/boat1\.txt:1: expected 12 flags"):
        make(UAV123, root=str(uav_root), sequences=["car1_1", "boat1"]).sequences()


def test_decimal_commas_are_not_read_as_a_polygon(tmp_path):
    """QA pass 14: a spreadsheet's export, tab-separated with decimal commas, was read as a polygon of
    8 values, and the run started from a wrong box without a word."""
    gt = tmp_path / "groundtruth_rect.txt"
    for sep in ("\t", ";"):
        gt.write_text(sep.join(["51,64", "47,27", "25,04", "62,02"]) + "\n")
        with pytest.raises(AnnotationError, match=r"groundtruth_rect\.txt:1: 4 numbers with decimal commas, it seems"):
            read_boxes(gt)
    gt.write_text("51,64,47,27,25,04,62,02\n")   # a real polygon, comma-separated: read as one
    np.testing.assert_allclose(read_boxes(gt), [[25, 2, 62 - 25, 64 - 2]])   # x 51,47,25,62; y 64,27,4,2


def test_listing_reads_no_image(uav_root, monkeypatch):
    calls = []
    monkeypatch.setattr(cv2, "imread", lambda *a, **k: calls.append(a))
    for f in (uav_root / "data_seq/UAV123/car1").iterdir():
        f.write_bytes(b"not an image")  # listing must not notice
    seqs = make(UAV123, root=str(uav_root)).sequences()
    assert len(seqs) == 4 and calls == []


def test_sequences_pickle_for_worker_processes(uav_root, tmp_path):
    (tmp_path / "f" / "a").mkdir(parents=True)
    write_gt(tmp_path / "f" / "a" / "groundtruth.txt", boxes(2))
    for s in make(UAV123, root=str(uav_root)).sequences() + make(FolderDataset, root=str(tmp_path / "f")).sequences():
        back = pickle.loads(pickle.dumps(s))
        assert back.name == s.name and np.array_equal(back.groundtruth, s.groundtruth, equal_nan=True)


# --- DTB70 -----------------------------------------------------------------------------------

def test_dtb70_official_layout(tmp_path):
    root = tmp_path / "DTB70"
    write_frames(root / "Gull1/img", 4, name=lambda k: f"{k:05d}.jpg")
    write_gt(root / "Gull1/groundtruth_rect.txt", [[1, 2, 3, 4], [0, 0, 0, 0], [2, 3, 4, 5], [3, 4, 5, 6]])
    write_gt(root / "Yacht2/groundtruth_rect.txt", boxes(3))  # frames not downloaded
    (root / "anno/att").mkdir(parents=True)
    (root / "anno/att/Gull1.txt").write_text("1,0,1,0,0,0,0,0,0,0,1\n")
    (root / "anno/att/Yacht2.txt").write_text("0,0,0,0,0,0,0,1,0,0,0\n")
    seqs = {s.name: s for s in make(DTB70, root=str(root)).sequences()}
    gull = seqs["Gull1"]
    assert len(gull) == 4 and gull.groundtruth[1].tolist() == [0, 0, 0, 0] and gull.groundtruth[2].tolist() == [2, 3, 4, 5]
    assert gull.attributes == {"SV", "OCC", "MB"} and seqs["Yacht2"].attributes == {"OV"}
    assert [int(gull.image(i)[0, 0, 0]) for i in range(4)] == [1, 2, 3, 4]
    with pytest.raises(FrameReadError, match=r"Yacht2/img/00002\.jpg"):
        seqs["Yacht2"].image(1)


# --- UAVDT -----------------------------------------------------------------------------------

def test_uavdt_official_layout(tmp_path):
    root = tmp_path / "UAVDT"
    write_frames(root / "UAV-benchmark-S/S0101", 3, name=lambda k: f"img{k:06d}.jpg")
    write_gt(root / "anno/S0101_gt.txt", boxes(3))
    write_gt(root / "anno/S0202_gt.txt", boxes(2))
    (root / "anno/att").mkdir()
    (root / "anno/att/S0101_att.txt").write_text("0,1,1,1,0,0,1,1,0\n")
    (root / "anno/att/S0202_att.txt").write_text("1,0,0,0,0,0,0,0,1\n")
    seqs = {s.name: s for s in make(UAVDT, root=str(root)).sequences()}
    assert list(seqs) == ["S0101", "S0202"]
    s = seqs["S0101"]
    assert s.attributes == {"CM", "OM", "SO", "SV", "LT"} and seqs["S0202"].attributes == {"BC", "LO"}
    assert [int(s.image(i)[0, 0, 0]) for i in range(3)] == [1, 2, 3]
    with pytest.raises(FrameReadError, match=r"UAV-benchmark-S/S0202/img000001\.jpg"):
        seqs["S0202"].image(0)


def test_uavdt_without_annotations_says_where(tmp_path):
    with pytest.raises(DatasetError, match=r"<seq>_gt\.txt.*anno"):
        make(UAVDT, root=str(tmp_path)).sequences()


# --- VTUAV -----------------------------------------------------------------------------------

def test_vtuav_sparse_ground_truth_every_10th_frame(tmp_path):
    seq = tmp_path / "VTUAV/test_ST/bike_001"
    write_frames(seq / "rgb", 25, name=lambda k: f"{k:06d}.jpg", first=0)
    write_frames(seq / "ir", 1)
    write_gt(seq / "rgb.txt", [[1, 2, 3, 4], [5, 6, 7, 8], [9, 10, 11, 12]], sep=" ")
    (s,) = make(VTUAV, root=str(tmp_path / "VTUAV")).sequences()
    assert len(s) == 25 and s.fps == 30.0
    assert np.flatnonzero(s.annotated).tolist() == [0, 10, 20]
    assert s.groundtruth[10].tolist() == [5, 6, 7, 8] and s.groundtruth[20].tolist() == [9, 10, 11, 12]
    assert np.isnan(s.groundtruth[~s.annotated]).all()
    assert int(s.image(13)[0, 0, 0]) == 13  # rgb/000013.jpg, not ir/
    assert s.init_box.w == 3


def test_vtuav_annotations_only_and_mismatch(tmp_path):
    seq = tmp_path / "VTUAV/test_ST/car_002"
    write_gt(seq / "rgb.txt", boxes(4), sep=" ")
    (s,) = make(VTUAV, root=str(tmp_path / "VTUAV")).sequences()
    assert len(s) == 31 and np.flatnonzero(s.annotated).tolist() == [0, 10, 20, 30]
    with pytest.raises(FrameReadError, match="car_002/rgb"):
        s.image(0)
    write_frames(seq / "rgb", 5)  # 4 annotations cannot cover 5 frames at one per 10
    with pytest.raises(AnnotationError, match=r"rgb\.txt: 4 annotation lines do not fit 5 frames"):
        make(VTUAV, root=str(tmp_path / "VTUAV")).sequences()
    with pytest.raises(DatasetError, match="test_LT"):
        make(VTUAV, root=str(tmp_path / "VTUAV"), split="test_LT").sequences()


# --- generic folder layout -------------------------------------------------------------------

def test_folder_layout_frames_in_sequence_folder_and_mixed_separators(tmp_path):
    seq = tmp_path / "data/s1"
    write_frames(seq, 3, name=lambda k: f"{k}.png")
    (seq / "groundtruth.txt").write_text("1, 2, 3, 4\n5\t6\t7\t8\n9 10 11 12\n\n")
    (s,) = make(FolderDataset, root=str(tmp_path / "data"), fps=25.0).sequences()
    assert s.groundtruth.tolist() == [[1, 2, 3, 4], [5, 6, 7, 8], [9, 10, 11, 12]] and s.fps == 25.0
    assert [int(s.image(i)[0, 0, 0]) for i in range(3)] == [1, 2, 3]
    write_frames(tmp_path / "tif/t1/img", 3, name=lambda k: f"{k:04d}.tif")   # TIFF frames (QA pass 14: not found)
    (tmp_path / "tif/t1/groundtruth_rect.txt").write_text("1,2,3,4\n" * 3)
    (t,) = make(FolderDataset, root=str(tmp_path / "tif")).sequences()
    assert [int(t.image(i)[0, 0, 0]) for i in range(3)] == [1, 2, 3]
    write_frames(seq, 1, name=lambda k: "preview.webp")   # beside PNG frames: not a frame (review)
    (s,) = make(FolderDataset, root=str(tmp_path / "data"), fps=25.0).sequences()
    assert len(s) == 3 and not any(p.endswith(".webp") for p in s.frame_paths)


def test_folder_layout_frame_count_mismatch(tmp_path):
    seq = tmp_path / "data/s1"
    write_frames(seq / "img", 3)
    write_gt(seq / "groundtruth_rect.txt", boxes(4))
    # the sequence loads (its annotations can be scored) and cannot run: reading a frame says why
    (s1,) = make(FolderDataset, root=str(tmp_path / "data")).sequences()
    with pytest.raises(FrameReadError, match="4 ground-truth lines but 3 frames"):
        s1.image(0)
    # a frame missing in the middle is named (QA pass: only the counts were)
    write_frames(seq / "img", 4)
    missing = sorted((seq / "img").iterdir())[2]
    missing.unlink()
    (s1,) = make(FolderDataset, root=str(tmp_path / "data")).sequences()
    with pytest.raises(FrameReadError, match=rf"4 ground-truth lines but 3 frames in .* \(missing: {missing.name}\)"):
        s1.image(0)


# --- parsers ---------------------------------------------------------------------------------

def test_read_boxes_errors_and_polygons(tmp_path):
    p = tmp_path / "gt.txt"
    p.write_text("0,0,4,0,4,2,0,2\n1,1,3,1,3,5,1,5\n")  # axis-aligned rectangles as polygons
    assert read_boxes(p).tolist() == [[0, 0, 4, 2], [1, 1, 2, 4]]
    with pytest.raises(AnnotationError, match=r"gt\.txt:1: expected 4 values 'x,y,w,h'"):
        read_boxes(p, allow_polygons=False)
    p.write_text("1,2,3,4\n\n1,2,3,4\n")
    with pytest.raises(AnnotationError, match=r"gt\.txt:2: blank line"):
        read_boxes(p)
    p.write_text("1,2,3,4\n1,2,x,4\n")
    with pytest.raises(AnnotationError, match=r"gt\.txt:2: expected numbers"):
        read_boxes(p)
    p.write_text("1,2,3,4\n1,2,3,4,5,6,7,8\n")
    with pytest.raises(AnnotationError, match=r"gt\.txt:2: expected 4 values like the first line"):
        read_boxes(p)
    p.write_text("")
    with pytest.raises(AnnotationError, match="empty"):
        read_boxes(p)
    with pytest.raises(DatasetError, match="not found"):
        read_boxes(tmp_path / "absent.txt")


def test_read_attribute_flags_rejects_non_flags(tmp_path):
    p = tmp_path / "att.txt"
    p.write_text("1,0,2\n")
    with pytest.raises(AnnotationError, match=r"att\.txt:1: expected 3 flags 0 or 1"):
        read_attribute_flags(p, ["A", "B", "C"])
    p.write_text("1 0 1\n")
    assert read_attribute_flags(p, ["A", "B", "C"]) == {"A", "C"}


# --- plugin contract -------------------------------------------------------------------------

@pytest.mark.parametrize("cls, name", [(UAV123, "uav123"), (UAV123_10fps, "uav123_10fps"), (UAV20L, "uav20l"),
                                       (DTB70, "dtb70"), (UAVDT, "uavdt"), (VTUAV, "vtuav"),
                                       (FolderDataset, "folder")])
def test_plugin_contract(cls, name):
    assert cls.name == name
    assert cls.__doc__ and cls.__doc__.strip().splitlines()[0]
    fields = {f.name: f for f in dataclasses.fields(cls.Params)}
    assert "root" in fields and "sequences" in fields
    assert all(i.doc for i in describe(cls.Params))
    with pytest.raises(Exception, match="root: required|missing required parameter.*root"):
        build_params(cls.Params, {})
    assert build_params(cls.Params, {"root": "/x", "sequences": ["a"]}).sequences == ["a"]
    if "annotations" in fields:   # scoring needs no frames: root may be left out (QA pass)
        assert build_params(cls.Params, {"annotations": "/a"}).root is None


def test_official_annotations_score_without_a_root(tmp_path):
    """DTB70 from its annotation folder alone: the sequences load for scoring, and a run says
    which frame it looked for under the root that is not set."""
    from mata_eval.run.preflight import check_dataset
    from mata_eval.run.config import PluginBlock

    anno = tmp_path / "anno"
    (anno / "att").mkdir(parents=True)
    (anno / "Bird1.txt").write_text("10,20,30,40\n11,21,30,40\n")
    (anno / "att" / "Bird1.txt").write_text(",".join(["1"] + ["0"] * 10) + "\n")
    seq, = DTB70(build_params(DTB70.Params, {"annotations": str(anno)})).sequences()
    assert seq.name == "Bird1" and seq.groundtruth.shape == (2, 4) and "SV" in seq.attributes
    params = build_params(DTB70.Params, {"annotations": str(anno)})
    problem = check_dataset(PluginBlock("dataset", "dtb70", DTB70, params))
    assert "1 of 1 sequences have no frames: Bird1 (looked for <root not set>" in str(problem)


def test_uav123_frame_ranges_param_declared():
    p = build_params(UAV123.Params, {"root": "/x", "frame_ranges": "/x/configSeqs.m"})
    assert p.frame_ranges == "/x/configSeqs.m"
    assert textwrap.dedent(UAV123.__doc__).startswith("UAV123")
