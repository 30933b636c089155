"""DTB70 (Li & Yeung, AAAI 2017): 70 drone sequences, official layout (github flyers/drone-tracking)::

    <root>/<seq>/img/00001.jpg
    <root>/<seq>/groundtruth_rect.txt          x,y,w,h per frame (0,0,0,0 when absent, kept as is)

Attributes (11 flags) are not part of the download but of the authors' MATLAB kit:
``experiments/anno/att/<seq>.txt``; looked for in ``<root>/anno/att`` and ``<root>/att``, or give
``attributes``. ``annotations`` reads an annotation-only folder (``<seq>.txt`` + ``att/``) instead.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ...core.hooks import hookimpl
from ...core.params import param
from ...core.sequence import Sequence
from .annotations import (DatasetError, annotation_files, check_fps, check_root, dataset_root, frame_paths,
                          read_attribute_flags, read_boxes, select, where)

#: Flag order of the kit's att files (ATTRIBUTE_ORDER): scale variation, aspect ratio variation,
#: occlusion, deformation, fast camera motion, in-plane rotation, out-of-plane rotation,
#: out of view, background clutter, similar objects around, motion blur.
ATTRIBUTES = ("SV", "ARV", "OCC", "DEF", "FCM", "IPR", "OPR", "OV", "BC", "SOA", "MB")


class DTB70:
    """DTB70: 70 drone sequences (<seq>/img/, <seq>/groundtruth_rect.txt), 11 attributes."""

    name = "dtb70"
    label = "DTB70"  # display name in reports

    @dataclass(frozen=True)
    class Params:
        root: str | None = param(
            None, "dataset folder holding one folder per sequence"
                  " (may be left out with annotations, to score results without the frames)")
        sequences: list[str] | None = param(None, "names of the sequences to load (default: all)")
        annotations: str | None = param(
            None, "annotation-only folder with <seq>.txt and att/<seq>.txt (default: <root>/<seq>/groundtruth_rect.txt)")
        attributes: str | None = param(
            None, "folder of <seq>.txt attribute flags (default: <annotations>/att, <root>/anno/att or <root>/att)")
        fps: float = param(30.0, "camera frame rate (frames per second)")

        def __post_init__(self) -> None:
            check_root("dtb70", self.root, self.annotations)
            check_fps("dtb70", self.fps)

    def __init__(self, params: Params):
        self.params = params
        self.root = dataset_root(params.root)

    def _gt_files(self) -> dict[str, Path]:
        if self.params.annotations:
            folder = Path(self.params.annotations).expanduser()
            if not folder.is_dir():
                raise DatasetError(f"annotations: folder not found: {folder}")
            files = {p.stem: p for p in annotation_files(folder)}
        else:
            if not self.root.is_dir():
                raise DatasetError(f"DTB70 root not found: {where(self.root)}; expected <root>/<seq>/groundtruth_rect.txt")
            files = {d.name: d / "groundtruth_rect.txt" for d in sorted(self.root.iterdir())
                     if (d / "groundtruth_rect.txt").is_file()}
        if not files:
            raise DatasetError(f"no DTB70 sequence found: expected {self.root}/<seq>/groundtruth_rect.txt "
                               "(or annotations: <folder of <seq>.txt>; mata-eval eval: --set annotations=<folder>)")
        return files

    def _att_dir(self) -> Path | None:
        if self.params.attributes:
            d = Path(self.params.attributes).expanduser()
            if not d.is_dir():
                raise DatasetError(f"attributes: folder not found: {d}")
            return d
        cands = ([Path(self.params.annotations).expanduser() / "att"] if self.params.annotations else []) + \
            [self.root / "anno" / "att", self.root / "att"]
        return next((d for d in cands if d.is_dir()), None)

    def sequences(self) -> list[Sequence]:
        files = self._gt_files()
        names = select(sorted(files), self.params.sequences, f"dataset dtb70 ({self.root})")
        att_dir = self._att_dir()
        out = []
        for name in names:
            gt = read_boxes(files[name], allow_polygons=False)
            attrs = read_attribute_flags(att_dir / f"{name}.txt", ATTRIBUTES) if att_dir else frozenset()
            # names of pysot's DTB70.json (img/00001.jpg) while the folder is absent
            frames = frame_paths(self.root / name / "img", len(gt), "{:05d}.jpg", files[name])
            out.append(Sequence(name=name, groundtruth=gt, fps=self.params.fps, attributes=attrs,
                                frame_paths=frames))
        return out


@hookimpl
def mata_eval_datasets() -> list[type]:
    return [DTB70]
