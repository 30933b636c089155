"""UAV123, UAV123_10fps and UAV20L in the benchmark's official layout (Mueller et al., ECCV 2016)::

    <root>/data_seq/UAV123/<video>/000001.jpg        frames of the long videos
    <root>/anno/UAV123/<seq>.txt                     x,y,w,h per frame, NaN rows when absent
    <root>/anno/UAV123/att/<seq>.txt                 12 flags, order of ATTRIBUTE_ORDER.txt

(``UAV20L``: ``anno/UAV20L/``, frames shared with UAV123 in ``data_seq/UAV123/``; ``UAV123_10fps``: ``data_seq/UAV123_10fps/``,
``anno/UAV123_10fps/``.) Sequences are frame ranges of the videos, from the benchmark kit's
``configSeqs.m`` table (or got10k's ``uav123.json``), which is read from the user's dataset folder.
Listing sequences reads annotations only; frames are read by ``Sequence.image(k)``.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

from ...core.hooks import hookimpl
from ...core.params import param
from ...core.sequence import FramePaths, Sequence
from ..occlusion import ATTRIBUTE as OCCLUSION_ATTRIBUTE, read_occlusion_metadata
from .annotations import (DatasetError, FrameRange, check_root, dataset_root, frame_paths, read_attribute_flags,
                          read_boxes, read_frame_ranges, select, where)

#: Flag order of ``anno/UAV123/att/*.txt`` (the dataset's ATTRIBUTE_ORDER.txt).
ATTRIBUTES = ("SV", "ARC", "LR", "FM", "FOC", "POC", "OV", "BC", "IV", "VC", "CM", "SOB")

#: Where a frame-range table is looked for when ``frame_ranges`` is not given, relative to root
#: and then to the annotation folder.
FRAME_RANGE_CANDIDATES = ("configSeqs.m", "util/configSeqs.m", "anno/configSeqs.m",
                          "uav123.json", "got10k_uav123_frame_ranges.json")


def _frame_range_help(subset: str, tried: list[Path]) -> str:
    return (f"no frame-range table for {subset}: expected the UAV123 benchmark kit's configSeqs.m "
            f"(util/configSeqs.m in the kit downloaded with the dataset from "
            f"https://cemse.kaust.edu.sa/ivul/uav123; it holds the seqUAV123, seqUAV20L and "
            f"seqUAV123_10fps tables) or got10k's uav123.json (got10k/datasets/uav123.json in the "
            f"got10k toolkit; UAV123 and UAV20L only). Copy it to <root>/configSeqs.m or next to the "
            f"annotations, or pass frame_ranges: <path>. Looked for: {', '.join(map(str, tried))}")


class _UAV123Layout:
    """Shared loader; subclasses fix the subset folder, the configSeqs table and the fps."""

    name = ""
    subset = "UAV123"  # anno/<subset>/ and the configSeqs table seq<subset>
    frames_subset = "UAV123"  # data_seq/<frames_subset>/
    fps = 30.0

    @dataclass(frozen=True)
    class Params:
        root: str | None = param(
            None, "dataset folder holding data_seq/ and anno/"
                  " (may be left out with annotations, to score results without the frames)")
        sequences: list[str] | None = param(None, "names of the sequences to load (default: all)")
        frame_ranges: str | None = param(
            None, "configSeqs.m of the UAV123 benchmark kit, or got10k's uav123.json "
                  "(default: found under root or next to the annotations)")
        annotations: str | None = param(
            None, "folder with <seq>.txt and att/ (default: <root>/anno/<subset>)")

        def __post_init__(self) -> None:
            check_root("uav123 / uav123_10fps / uav20l", self.root, self.annotations)

    def __init__(self, params: Params):
        self.params = params
        self.root = dataset_root(params.root)
        self._fps_by_name: dict[str, float] | None = None

    # -- folders --
    @property
    def anno_dir(self) -> Path:
        if self.params.annotations:
            return Path(self.params.annotations).expanduser()
        return self.root / "anno" / self.subset

    @property
    def frames_dir(self) -> Path:
        return self.root / "data_seq" / self.frames_subset

    def frame_range_files(self) -> list[Path]:
        """``frame_ranges``, or every candidate file found under root / next to the annotations."""
        if self.params.frame_ranges:
            path = Path(self.params.frame_ranges).expanduser()
            if not path.is_file():
                raise DatasetError(f"frame_ranges: file not found: {path}. "
                                   + _frame_range_help(self.subset, [path]))
            return [path]
        tried = [base / rel for base in dict.fromkeys([self.root, self.anno_dir, self.anno_dir.parent])
                 for rel in FRAME_RANGE_CANDIDATES]
        found = [p for p in dict.fromkeys(tried) if p.is_file()]
        if not found and self.params.annotations and not self.anno_dir.is_dir():
            raise DatasetError(f"annotations: folder not found: {self.anno_dir}")
        if not found and not self.root.is_dir() and not self.params.annotations:
            raise DatasetError(f"{self.name} dataset root not found: {where(self.root)}; expected the official layout "
                               f"<root>/data_seq/{self.frames_subset}/ and <root>/anno/{self.subset}/ (set root: <folder>)")
        if not found:
            raise DatasetError(_frame_range_help(self.subset, tried))
        return found

    def frame_table(self) -> tuple[dict[str, FrameRange], set[str]]:
        """This subset's table (from the first file that has one), and every sequence or video
        name any table of that file mentions."""
        files = self.frame_range_files()
        for path in files:
            tables = read_frame_ranges(path)
            if self.subset in tables:
                mentioned = {n for t in tables.values() for r in t.values() for n in (r.name, r.video)}
                return tables[self.subset], mentioned
        json_note = ("got10k's JSON has no UAV123_10fps table; use the benchmark kit's configSeqs.m. "
                     if any(p.suffix == ".json" for p in files) and self.subset == "UAV123_10fps" else "")
        raise DatasetError(f"no seq{self.subset} table in {', '.join(map(str, files))}. " + json_note
                           + _frame_range_help(self.subset, files))

    # -- listing --
    def _annotation_names(self) -> list[str]:
        d = self.anno_dir
        if not d.is_dir():
            raise DatasetError(f"annotation folder not found: {d}; expected the official layout "
                               f"<root>/anno/{self.subset}/<seq>.txt (or set annotations: <folder>; mata-eval eval: --set annotations=<folder>)")
        return sorted(p.stem for p in d.glob("*.txt")
                      if p.is_file() and p.stem not in ("ATTRIBUTE_ORDER", "README") and not p.stem.startswith("README"))

    def sequence_names(self) -> list[str]:
        """Table sequences in table order, then annotation files that no table mentions (neither
        as a sequence nor as a video it splits): those are whole videos."""
        return self._names(*self.frame_table())

    def _names(self, table: dict[str, FrameRange], mentioned: set[str]) -> list[str]:
        have = set(self._annotation_names())
        wanted = table if self.params.sequences is None else [n for n in self.params.sequences if n in table]
        missing = [n for n in wanted if n not in have]
        if missing:
            raise DatasetError(f"{self.anno_dir}: no annotation file for {len(missing)} {self.subset} sequence(s) "
                               f"of the frame-range table: {', '.join(missing[:5])}{', ...' if len(missing) > 5 else ''} "
                               f"(expected {missing[0]}.txt; select a subset with sequences: [...])")
        extra = [n for n in sorted(have) if n not in mentioned]
        return select(list(table) + extra, self.params.sequences, f"dataset {self.name} ({self.anno_dir})")

    def sequences(self) -> list[Sequence]:
        table, mentioned = self.frame_table()
        return [self._load(n, table.get(n)) for n in self._names(table, mentioned)]

    def _load(self, name: str, rng: FrameRange | None) -> Sequence:
        gt_path = self.anno_dir / f"{name}.txt"
        gt = read_boxes(gt_path, allow_polygons=False)
        if rng is not None:
            if len(rng) != len(gt):
                raise DatasetError(f"{gt_path}: {len(gt)} ground-truth lines, but the frame-range table gives "
                                   f"{name} frames {rng.start}..{rng.end} of {rng.video} ({len(rng)} frames)")
            folder = str(self.frames_dir / rng.video)
            frames = FramePaths(lambda: [os.path.join(folder, f) for f in rng.frame_names()], len(rng))
            meta = {"video": rng.video, "start_frame": rng.start, "end_frame": rng.end}
        else:
            frames = frame_paths(self.frames_dir / name, len(gt), "{:06d}.jpg", gt_path,
                                 " (a sequence missing from the frame-range table is read as the whole video)")
            meta = {"video": name, "start_frame": 1, "end_frame": len(gt)}
        att_dir = self.anno_dir / "att"
        attrs = read_attribute_flags(att_dir / f"{name}.txt", ATTRIBUTES) if att_dir.is_dir() else frozenset()
        occluded = read_occlusion_metadata(self.anno_dir / "occlusion", name)
        if occluded is not None:   # a copy written by `mata-eval augment`: its occluders, as a run saw them
            meta["occlusion"] = occluded[0]
            attrs = attrs | ({OCCLUSION_ATTRIBUTE} if occluded[1] else frozenset())
        return Sequence(name=name, groundtruth=gt, fps=self._augmented_fps().get(name, self.fps), attributes=attrs,
                        frame_paths=frames, meta=meta)

    def _augmented_fps(self) -> dict[str, float]:
        """Sequence -> frame rate of a copy written by ``mata-eval augment`` (``augment.json``: its
        source's, e.g. 10 fps footage; it was read at 30); empty for the benchmark's own folders."""
        if self._fps_by_name is None:
            path = self.root / "augment.json"
            try:
                fps = json.loads(path.read_text()).get("fps")
            except (OSError, ValueError, AttributeError):
                fps = None
            self._fps_by_name = {}
            for name, value in (fps.items() if isinstance(fps, dict) else ()):
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < math.inf:
                    raise DatasetError(f"{path}: fps.{name}: expected a positive number of frames a second, "
                                       f"got {value!r}")
                self._fps_by_name[name] = float(value)
        return self._fps_by_name


class UAV123(_UAV123Layout):
    """UAV123 (123 aerial sequences, 30 fps) in the official layout, frame ranges from configSeqs."""

    name = "uav123"
    label = "UAV123"  # display name in reports
    subset = "UAV123"
    fps = 30.0


class UAV123_10fps(_UAV123Layout):
    """UAV123 temporally down-sampled to 10 fps (data_seq/UAV123_10fps, anno/UAV123_10fps)."""

    name = "uav123_10fps"
    label = "UAV123@10fps"  # display name in reports
    subset = "UAV123_10fps"
    frames_subset = "UAV123_10fps"
    fps = 10.0


class UAV20L(_UAV123Layout):
    """UAV20L: the 20 long-term UAV123 videos, whole (anno/UAV20L, frames in data_seq/UAV123), 30 fps."""

    name = "uav20l"
    label = "UAV20L"  # display name in reports
    subset = "UAV20L"
    frames_subset = "UAV123"  # configSeqs' seqUAV20L points into data_seq/UAV123
    fps = 30.0


@hookimpl
def mata_eval_datasets() -> list[type]:
    return [UAV123, UAV123_10fps, UAV20L]
