"""UAVDT single-object benchmark (Du et al., ECCV 2018), "UAV-benchmark-S" and the SOT kit::

    <root>/UAV-benchmark-S/<seq>/img000001.jpg
    <root>/anno/<seq>_gt.txt                    x,y,w,h per frame
    <root>/anno/att/<seq>_att.txt               9 flags (ATTRIBUTE_ORDER below)

(the kit's ``main_running.m`` reads ``UAV-benchmark-S/<seq>/img%06d.jpg`` and ``anno/<seq>_gt.txt``;
``perfPlot.m`` reads ``anno/att/<seq>_att.txt``). ``anno`` may also sit in
``<root>/UAV-benchmark-SOT_v1.0/``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ...core.hooks import hookimpl
from ...core.params import param
from ...core.sequence import Sequence
from .annotations import (DatasetError, check_fps, check_root, dataset_root, frame_paths, read_attribute_flags,
                          read_boxes, select, where)

#: Flag order of ``att/<seq>_att.txt``: background clutter, camera motion, object motion, small
#: object, illumination variations, object blur, scale variations, long-term tracking, large occlusion.
ATTRIBUTES = ("BC", "CM", "OM", "SO", "IV", "OB", "SV", "LT", "LO")

ANNO_CANDIDATES = ("anno", "UAV-benchmark-SOT_v1.0/anno", "UAV-benchmark-SOT/anno")
FRAME_CANDIDATES = ("UAV-benchmark-S", "UAV-benchmark-S/UAV-benchmark-S")


class UAVDT:
    """UAVDT single-object tracking: 50 sequences (UAV-benchmark-S, anno/<seq>_gt.txt), 9 attributes."""

    name = "uavdt"
    label = "UAVDT"  # display name in reports

    @dataclass(frozen=True)
    class Params:
        root: str | None = param(
            None, "dataset folder holding UAV-benchmark-S/ and anno/"
                  " (may be left out with annotations, to score results without the frames)")
        sequences: list[str] | None = param(None, "names of the sequences to load (default: all)")
        annotations: str | None = param(
            None, "folder with <seq>_gt.txt and att/<seq>_att.txt (default: <root>/anno)")
        frames: str | None = param(None, "folder with one <seq>/ folder of frames (default: <root>/UAV-benchmark-S)")
        fps: float = param(30.0, "camera frame rate (frames per second)")

        def __post_init__(self) -> None:
            check_root("uavdt", self.root, self.annotations)
            check_fps("uavdt", self.fps)

    def __init__(self, params: Params):
        self.params = params
        self.root = dataset_root(params.root)

    def anno_dir(self) -> Path:
        if self.params.annotations:
            d = Path(self.params.annotations).expanduser()
            if not d.is_dir():
                raise DatasetError(f"annotations: folder not found: {where(d)}")
            return d
        for rel in ANNO_CANDIDATES:
            if (self.root / rel).is_dir():
                return self.root / rel
        raise DatasetError(f"UAVDT annotations not found: expected <seq>_gt.txt files in "
                           f"{' or '.join(f'<root>/{r}' for r in ANNO_CANDIDATES)} under root {where(self.root)} "
                           "(or annotations: <folder>; mata-eval eval: --set annotations=<folder>)")

    def frames_dir(self) -> Path:
        if self.params.frames:
            return Path(self.params.frames).expanduser()
        for rel in reversed(FRAME_CANDIDATES):  # the nested copy the kit's perfPlot.m uses, if present
            if (self.root / rel).is_dir() and any((self.root / rel).glob("S*")):
                return self.root / rel
        return self.root / FRAME_CANDIDATES[0]

    def sequences(self) -> list[Sequence]:
        anno = self.anno_dir()
        files = {p.name[: -len("_gt.txt")]: p for p in sorted(anno.glob("*_gt.txt")) if p.is_file()}
        if not files:
            raise DatasetError(f"{anno}: no <seq>_gt.txt file (UAVDT single-object annotations)")
        names = select(sorted(files), self.params.sequences, f"dataset uavdt ({anno})")
        att_dir = anno / "att"
        frames_root = self.frames_dir()
        out = []
        for name in names:
            gt = read_boxes(files[name], allow_polygons=False)
            frames = frame_paths(frames_root / name, len(gt), "img{:06d}.jpg", files[name])
            attrs = (read_attribute_flags(att_dir / f"{name}_att.txt", ATTRIBUTES)
                     if att_dir.is_dir() else frozenset())
            out.append(Sequence(name=name, groundtruth=gt, fps=self.params.fps, attributes=attrs,
                                frame_paths=frames))
        return out


@hookimpl
def mata_eval_datasets() -> list[type]:
    return [UAVDT]
