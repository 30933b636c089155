"""Generic folder layout: one folder per sequence, its frames and a ground-truth file::

    <root>/<seq>/groundtruth_rect.txt   (or groundtruth.txt)  x,y,w,h or VOT 8-value polygons,
    <root>/<seq>/img/0001.jpg           (or imgs/, color/, or the frames in <seq>/ itself)

Values may be comma, tab or space separated; polygons become their axis-aligned bounding box.
``root`` may also be a single sequence folder. Frame folders are listed (never read) when the
sequences are listed; a missing frame folder is reported by ``Sequence.image``. A folder with only
a file named like a ground-truth file (``groundtruth_rect.1.txt``) is not a sequence; the
preflight names it (:meth:`FolderDataset.warnings`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ...core.hooks import hookimpl
from ...core.params import param
from ...core.sequence import Sequence
from .annotations import (DatasetError, MissingFrames, UnusableFrames, check_fps, list_images, numbering_gaps,
                          read_boxes, select, where)


class FolderDataset:
    """Generic layout: <root>/<seq>/ with frames and groundtruth(_rect).txt (4 values or VOT polygons)."""

    name = "folder"
    label = "Folder"  # display name in reports

    @dataclass(frozen=True)
    class Params:
        root: str = field(metadata={"doc": "folder holding one folder per sequence (or one sequence folder)"})
        sequences: list[str] | None = param(None, "names of the sequences to load (default: all)")
        groundtruth: list[str] = param(["groundtruth_rect.txt", "groundtruth.txt"],
                                       "ground-truth file names tried in each sequence folder, in order")
        frames: list[str] = param(["img", "imgs", "color", "."],
                                  "frame sub-folders tried in each sequence folder, in order ('.' = the folder itself)")
        fps: float = param(30.0, "camera frame rate (frames per second)")

        def __post_init__(self) -> None:
            check_fps("folder", self.fps)

    def __init__(self, params: Params):
        self.params = params
        self.root = Path(params.root).expanduser()

    def _gt_file(self, folder: Path) -> Path | None:
        return next((folder / g for g in self.params.groundtruth if (folder / g).is_file()), None)

    @staticmethod
    def _lookalikes(folder: Path) -> list[str]:
        """Files named like a ground-truth file that the ``groundtruth`` names do not match
        (``groundtruth_rect.1.txt``, ``Groundtruth_Rect.txt``, ``groundtruth_rect.txt.txt``)."""
        return sorted(f.name for f in folder.iterdir() if f.name.lower().startswith("groundtruth") and f.is_file())

    def _sequence_folders(self) -> dict[str, Path]:
        if not self.root.is_dir():
            raise DatasetError(f"folder dataset root not found: {where(self.root)}")
        found = {d.name: d for d in sorted(self.root.iterdir()) if d.is_dir() and self._gt_file(d)}
        if not found and self._gt_file(self.root):
            found = {self.root.name: self.root}
        if not found:
            raise DatasetError(f"{self.root}: no sequence folder with a ground-truth file "
                               f"({' or '.join(self.params.groundtruth)}); expected <root>/<seq>/groundtruth_rect.txt"
                               + "".join(f"; {w}" for w in self.warnings()[:3]))
        return found

    def warnings(self) -> list[str]:
        """The folders under root with only a file named like a ground-truth file: not sequences
        of this dataset, said by the preflight (QA pass: left out of the means without a word).
        None when ``sequences`` names the ones to load."""
        if not self.root.is_dir() or self.params.sequences:
            return []
        names = ", ".join(self.params.groundtruth)
        return [f"{d}: {', '.join(found)} but no {' or '.join(self.params.groundtruth)}: not a sequence of this "
                f"dataset (to read it, add its file to the dataset's groundtruth: [{names}, FILE])"
                for d in sorted(self.root.iterdir())
                if d.is_dir() and not self._gt_file(d) and (found := self._lookalikes(d))]

    def sequences(self) -> list[Sequence]:
        folders = self._sequence_folders()
        names = select(list(folders), self.params.sequences, f"dataset folder ({self.root})")
        out = []
        for name in names:
            d = folders[name]
            gt_path = self._gt_file(d)
            gt = read_boxes(gt_path)
            cands = [d / f for f in self.params.frames]
            frames: list[str] = []
            for c in cands:
                frames = list_images(c)
                if frames:
                    break
            if frames and len(frames) != len(gt):   # this sequence cannot run; the others can
                out.append(Sequence(name=name, groundtruth=gt, fps=self.params.fps, loader=UnusableFrames(
                    f"{gt_path}: {len(gt)} ground-truth lines but {len(frames)} frames in {Path(frames[0]).parent}"
                    f"{numbering_gaps([Path(f).name for f in frames])}; expected one line per frame")))
                continue
            out.append(Sequence(name=name, groundtruth=gt, fps=self.params.fps, frame_paths=tuple(frames),
                                loader=None if frames else MissingFrames(name, cands)))
        return out


@hookimpl
def mata_eval_datasets() -> list[type]:
    return [FolderDataset]
