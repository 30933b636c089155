"""Parsing helpers shared by the dataset plugins: ground-truth box files, attribute flag files,
and the UAV123 frame-range tables (the benchmark kit's ``configSeqs.m`` and got10k's JSON).

Everything here reads text only; no image is ever opened. Bad input raises
:class:`AnnotationError` naming the file, the line and what was expected.
"""

from __future__ import annotations

import io
import json
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from ...core.errors import UserError
from ...core.sequence import FramePaths

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp")
#: frames of these types are listed only where a folder has none of IMAGE_EXTENSIONS (a preview
#: .webp or the raw .tif beside a sequence's JPEGs would change its frame count)
OTHER_IMAGE_EXTENSIONS = (".tif", ".tiff", ".webp")


class DatasetError(UserError, ValueError):
    """A dataset folder is missing something the loader needs; says which file and where."""


class AnnotationError(DatasetError):
    """An annotation file is malformed: names the file, the line and what was expected."""

    def __init__(self, path: str | Path, line: int | None, message: str):
        self.path = str(path)
        self.line = line
        where = f"{path}:{line}" if line is not None else str(path)
        super().__init__(f"{where}: {message}")


# --- ground-truth boxes ----------------------------------------------------------------------

_SPLIT = re.compile(r"[,\t ;]+")


#: a line of 4 numbers with decimal commas, separated by tabs or semicolons (a spreadsheet's export)
_DECIMAL_COMMAS = re.compile(r" *-?\d+,\d+(?: *[\t;] *-?\d+,\d+){3}\s*")


def _values(text: str) -> list[str]:
    return [v for v in _SPLIT.split(text.strip()) if v]


def polygon_to_box(corners: np.ndarray) -> np.ndarray:
    """Axis-aligned ``x, y, w, h`` of (N, 8) polygons ``x1, y1, ..., x4, y4`` (VOT): the min/max
    of the corner coordinates, as the VOT toolkit's ``Polygon.convert(RegionType.RECTANGLE)``."""
    xs, ys = corners[:, 0::2], corners[:, 1::2]
    x0, y0 = xs.min(axis=1), ys.min(axis=1)
    return np.stack([x0, y0, xs.max(axis=1) - x0, ys.max(axis=1) - y0], axis=1)


def read_boxes(path: str | Path, *, allow_polygons: bool = True) -> np.ndarray:
    """Ground truth of one sequence as an (N, 4) float ``x, y, w, h`` array.

    One line per frame; values separated by commas, tabs or spaces (mixed is fine). A line holds
    4 values (``x, y, w, h``) or, when ``allow_polygons``, 8 values (a VOT polygon, converted to
    its axis-aligned bounding box). ``NaN`` tokens are accepted. Rows are kept as the file gives
    them, including the ones that are no box (a NaN, or the ``0,0,0,0`` DTB70 writes for an absent
    target): what such a frame counts as is the metric profile's call, and toolkits disagree
    (got10k scores DTB70's ``0,0,0,0`` rows as failures and removes UAV123's NaN rows; the
    ``default`` profile skips both). Blank lines at the end of the file are ignored; blank lines in
    the middle are an error (they would shift every later frame)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise DatasetError(f"ground-truth file not found: {path}") from None
    except UnicodeDecodeError as e:
        raise AnnotationError(path, None, f"not a text file ({e})") from None
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise AnnotationError(path, None, "empty ground-truth file: expected one 'x,y,w,h' line per frame")
    if allow_polygons and _DECIMAL_COMMAS.fullmatch(lines[0]):   # not a polygon: a spreadsheet's export
        raise AnnotationError(path, 1, f"4 numbers with decimal commas, it seems ({lines[0].strip()!r}: read as a "
                                       "polygon of 8 values); write decimal points, '51.64,47.27,25.04,62.02'")
    widths = (4, 8) if allow_polygons else (4,)
    arr = _fast_rows(lines)
    if arr is not None and arr.shape[1] in widths:
        return polygon_to_box(arr) if arr.shape[1] == 8 else arr
    expected = ("4 values 'x,y,w,h' or 8 polygon corners 'x1,y1,...,x4,y4'" if allow_polygons
                else "4 values 'x,y,w,h'")
    rows: list[list[float]] = []
    width = None
    for i, line in enumerate(lines, start=1):
        vals = _values(line)
        if not vals:
            raise AnnotationError(path, i, f"blank line inside the file; expected {expected} on every line")
        if len(vals) not in widths:
            raise AnnotationError(path, i, f"expected {expected} separated by comma, tab or space; "
                                           f"got {len(vals)} value(s): {line.strip()!r}")
        if width is None:
            width = len(vals)
        elif len(vals) != width:
            raise AnnotationError(path, i, f"expected {width} values like the first line, got {len(vals)}: "
                                           f"{line.strip()!r}")
        try:
            rows.append([float(v) for v in vals])
        except ValueError:
            raise AnnotationError(path, i, f"expected numbers (or NaN), got {line.strip()!r}") from None
    arr = np.asarray(rows, dtype=np.float64)
    return polygon_to_box(arr) if width == 8 else arr


def _fast_rows(lines: list[str]) -> np.ndarray | None:
    """The lines as an (N, k) array by numpy's parser (it rounds like ``float()``), or None when
    it rejects them or skips a blank line: the line-by-line reader then names the bad line."""
    text = "\n".join(lines).replace(",", " ").replace(";", " ").replace("\t", " ")
    try:
        arr = np.loadtxt(io.StringIO(text), dtype=np.float64, comments=None, ndmin=2)
    except ValueError:
        return None
    return arr if arr.shape[0] == len(lines) else None


# --- attribute flags -------------------------------------------------------------------------

def read_attribute_flags(path: str | Path, names: Iterable[str]) -> frozenset[str]:
    """The attribute names whose flag is 1 in a one-line ``0,1,...`` file (OTB-style ``att`` files).

    ``names`` gives the flag order (e.g. the dataset's ``ATTRIBUTE_ORDER.txt``)."""
    path = Path(path)
    names = tuple(names)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise DatasetError(f"attribute file not found: {path}") from None
    lines = [(i, ln) for i, ln in enumerate(text.splitlines(), start=1) if ln.strip()]
    if len(lines) != 1:
        raise AnnotationError(path, lines[1][0] if len(lines) > 1 else None,
                              f"expected exactly one line of {len(names)} 0/1 flags "
                              f"({', '.join(names)}), found {len(lines)} non-empty lines")
    lineno, line = lines[0]
    vals = _values(line)
    if len(vals) != len(names) or any(v not in ("0", "1") for v in vals):
        raise AnnotationError(path, lineno, f"expected {len(names)} flags 0 or 1 in the order "
                                            f"{', '.join(names)}; got {line.strip()!r}")
    return frozenset(n for n, v in zip(names, vals) if v == "1")


# --- UAV123 frame-range tables ---------------------------------------------------------------

@dataclass(frozen=True)
class FrameRange:
    """One sub-sequence of a longer video: frames ``start..end`` (1-based, inclusive) of the folder
    ``video``, named ``{start:0{digits}d}.{ext}``."""

    name: str
    video: str
    start: int
    end: int
    digits: int = 6
    ext: str = "jpg"

    def __len__(self) -> int:
        return self.end - self.start + 1

    def frame_names(self) -> list[str]:
        return [f"{k:0{self.digits}d}.{self.ext}" for k in range(self.start, self.end + 1)]


_TABLE = re.compile(r"^\s*seq(\w+)\s*=\s*\{", re.MULTILINE)
_FIELD = re.compile(r"'(\w+)'\s*,\s*('(?:[^']*)'|\[[^\]]*\]|[-+\d.eE]+)")


def parse_config_seqs(path: str | Path) -> dict[str, dict[str, FrameRange]]:
    """The tables of a MATLAB ``configSeqs.m`` (OTB / UAV123 benchmark kit syntax)::

        seqUAV123={struct('name','bird1_2','path','d:\\data_seq\\UAV123\\bird1\\',
                          'startFrame',775,'endFrame',1477,'nz',6,'ext','jpg',...),...

    Returns ``{table: {sequence: FrameRange}}`` with table names without the ``seq`` prefix
    (``UAV123``, ``UAV20L``, ``UAV123_10fps``, ...), sequences in file order. The video folder is
    the last component of each struct's ``path``. Written by hand because it is MATLAB source,
    not a data format any library reads; the grammar used is the kit's: one ``seqX = {...};``
    cell array of ``struct(...)`` literals per table."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        raise DatasetError(f"frame-range file not found: {path}") from None
    # drop MATLAB comments (to end of line), keeping line numbers
    text = "\n".join(re.sub(r"%.*$", "", ln) for ln in text.split("\n"))
    tables: dict[str, dict[str, FrameRange]] = {}
    starts = list(_TABLE.finditer(text))
    for i, m in enumerate(starts):
        end = text.find("};", m.end())
        if end < 0:
            end = starts[i + 1].start() if i + 1 < len(starts) else len(text)
        body = text[m.end() - 1:end + 1]
        table: dict[str, FrameRange] = {}
        for s in re.finditer(r"struct\s*\(", body):
            close = body.find(")", s.end())
            # init_rect '[0,0,0,0]' contains no ')', so the first ')' closes the struct
            fields_text = body[s.end():close]
            lineno = text.count("\n", 0, m.end() - 1 + s.start()) + 1
            fields = {k: v for k, v in _FIELD.findall(fields_text)}
            missing = [k for k in ("name", "path", "startFrame", "endFrame") if k not in fields]
            if missing:
                raise AnnotationError(path, lineno, f"struct without {', '.join(missing)}; expected "
                                                    "struct('name',...,'path',...,'startFrame',N,'endFrame',M,...)")
            try:
                name = fields["name"].strip("'")
                video = re.split(r"[\\/]+", fields["path"].strip("'").rstrip("\\/"))[-1]
                start, stop = int(fields["startFrame"]), int(fields["endFrame"])
                digits = int(fields.get("nz", "6"))
                ext = fields.get("ext", "'jpg'").strip("'")
            except ValueError:
                raise AnnotationError(path, lineno, "expected integer startFrame, endFrame and nz") from None
            if stop < start or start < 1:
                raise AnnotationError(path, lineno, f"sequence {name!r}: expected 1 <= startFrame <= endFrame, "
                                                    f"got {start}..{stop}")
            table[name] = FrameRange(name, video, start, stop, digits, ext)
        tables[m.group(1)] = table
    if not tables:
        raise AnnotationError(path, None, "no 'seqNAME = {struct(...), ...};' table found; expected the "
                                          "UAV123 benchmark kit's util/configSeqs.m")
    return tables


def parse_frame_range_json(path: str | Path) -> dict[str, dict[str, FrameRange]]:
    """got10k's ``uav123.json``: ``{"UAV123": {seq: {"start_frame", "end_frame", "folder_name"}},
    "UAV20L": {...}}``. Same return shape as :func:`parse_config_seqs`."""
    path = Path(path)
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DatasetError(f"frame-range file not found: {path}") from None
    except json.JSONDecodeError as e:
        raise AnnotationError(path, e.lineno, f"invalid JSON ({e.msg})") from None
    if not isinstance(data, Mapping):
        raise AnnotationError(path, None, "expected an object {table: {sequence: {start_frame, end_frame, "
                                          "folder_name}}} (got10k's uav123.json)")
    tables: dict[str, dict[str, FrameRange]] = {}
    for tname, seqs in data.items():
        if not isinstance(seqs, Mapping):
            raise AnnotationError(path, None, f"table {tname!r}: expected an object of sequences")
        table = {}
        for name, info in seqs.items():
            try:
                start, stop = int(info["start_frame"]), int(info["end_frame"])
                video = str(info.get("folder_name", name))
            except (KeyError, TypeError, ValueError):
                raise AnnotationError(path, None, f"{tname}.{name}: expected integer 'start_frame' and "
                                                  "'end_frame' and a 'folder_name'") from None
            if stop < start or start < 1:
                raise AnnotationError(path, None, f"{tname}.{name}: expected 1 <= start_frame <= end_frame, "
                                                  f"got {start}..{stop}")
            table[name] = FrameRange(name, video, start, stop)
        tables[tname] = table
    return tables


def read_frame_ranges(path: str | Path) -> dict[str, dict[str, FrameRange]]:
    """Frame-range tables from a ``configSeqs.m`` or a got10k-style ``.json`` (by extension)."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        return parse_frame_range_json(path)
    return parse_config_seqs(path)


# --- frames ----------------------------------------------------------------------------------

def _natural_key(name: str) -> tuple:
    return tuple(int(t) if t.isdigit() else t for t in re.split(r"(\d+)", name))


def image_names(folder: str | Path) -> list[str]:
    """Names of the image files of ``folder`` in natural order (``2.jpg`` before ``10.jpg``);
    [] if absent. One directory read, no stat per file."""
    try:
        with os.scandir(folder) as it:
            entries = [(e.name, ext) for e in it
                       if (ext := os.path.splitext(e.name)[1].lower()) in IMAGE_EXTENSIONS + OTHER_IMAGE_EXTENSIONS
                       and e.is_file()]
    except (FileNotFoundError, NotADirectoryError):
        return []
    names = [n for n, ext in entries if ext in IMAGE_EXTENSIONS] or \
        [n for n, ext in entries if ext in OTHER_IMAGE_EXTENSIONS]
    return sorted(names, key=_natural_key)


def list_images(folder: str | Path) -> list[str]:
    """Paths of the image files of ``folder`` in natural order; [] if absent."""
    return [os.path.join(folder, n) for n in image_names(folder)]


def frame_paths(folder: Path, n: int, numbered: str, where: Path, hint: str = "") -> FramePaths:
    """The ``n`` frames of a sequence: the images of ``folder`` when it exists (their count is
    checked now, against the ``n`` ground-truth lines of ``where``), otherwise the names
    ``numbered.format(k)``, k = 1..n, that the dataset's own tools give them (pysot's json).
    Paths are joined on first access (scoring never asks)."""
    names = image_names(folder)
    if names and len(names) != n:
        raise DatasetError(f"{where}: {n} ground-truth lines but {len(names)} frames in {folder}"
                           f"{numbering_gaps(names)}{hint}")
    root = str(folder)
    if names:
        return FramePaths(lambda: [os.path.join(root, x) for x in names], n)
    return FramePaths(lambda: [os.path.join(root, numbered.format(k)) for k in range(1, n + 1)], n)


def numbering_gaps(names: list[str]) -> str:
    """For numbered frame files (``00001.jpg``...): the numbers missing between the first and
    the last, as a clause of the frame-count error; empty when the names are not numbers."""
    stems = [os.path.splitext(x)[0] for x in names]
    if not all(st.isdigit() for st in stems):
        return ""
    have = {int(st) for st in stems}
    gaps = [k for k in range(min(have), max(have) + 1) if k not in have]
    if not gaps:
        return ""
    width, ext = len(stems[0]), os.path.splitext(names[0])[1]
    shown = ", ".join(f"{k:0{width}d}{ext}" for k in gaps[:5]) + (f" and {len(gaps) - 5} more" if len(gaps) > 5 else "")
    return f" (missing: {shown})"


#: a dataset's root when only its annotations are given (``root`` left out, to score results
#: without the frames): nothing is found under it, and a frame read names this path
NO_ROOT = Path("<root not set>")


def check_root(plugin: str, root: str | None, annotations: str | None) -> None:
    """A dataset's ``root``, checked when the experiment is loaded: required unless the
    ``annotations`` folder is given (then the frames, which live under root, are not found)."""
    if root is None and annotations is None:
        raise ValueError(f"{plugin}: root: required (the dataset folder), or annotations: <folder> "
                         "to score results without the frames")


def dataset_root(root: str | None) -> Path:
    """``root`` as a path, or NO_ROOT when it is left out (:func:`check_root`)."""
    return NO_ROOT if root is None else Path(root).expanduser()


def where(path: Path) -> str:
    """``path`` as an error names it: a relative one with the folder it is relative to (a shipped
    experiment run from another folder looked for its ../shared/data there)."""
    return str(path) if path.is_absolute() else f"{path} (relative to the current folder {Path.cwd()})"


def check_fps(plugin: str, fps: float | None) -> None:
    """A dataset's ``fps`` parameter, checked when the experiment is loaded (a ValueError there
    names the file, line and key): a positive finite number, or None where the plugin reads it
    from the data."""
    if fps is not None and not 0 < fps < math.inf:
        raise ValueError(f"{plugin}: fps: expected a positive number, got {fps!r}")


def select(names: list[str], wanted: list[str] | None, where: str) -> list[str]:
    """``names`` restricted to ``wanted`` (in ``wanted``'s order); unknown names are an error."""
    if wanted is None:
        return names
    known = set(names)
    unknown = [w for w in wanted if w not in known]
    if unknown:
        sample = ", ".join(names[:8]) + (", ..." if len(names) > 8 else "")
        raise DatasetError(f"{where}: unknown sequence(s) {', '.join(map(repr, unknown))}; "
                           f"available ({len(names)}): {sample}")
    return list(dict.fromkeys(wanted))


class MissingFrames:
    """``Sequence.loader`` for a sequence whose frame folder is absent: listing works (annotations
    only) and :meth:`Sequence.image` raises a :class:`FrameReadError` saying where frames were
    expected. A class rather than a closure so sequences stay picklable for worker processes."""

    def __init__(self, sequence: str, looked_in: Iterable[str | Path]):
        self.sequence = sequence
        self.looked_in = tuple(str(p) for p in looked_in)

    def __call__(self, k: int) -> np.ndarray:
        from ...core.sequence import FrameReadError

        raise FrameReadError(f"cannot read frame {k} of sequence {self.sequence!r}: no image files found "
                             f"in {' or '.join(self.looked_in)} (only the annotations are present)")


class UnusableFrames:
    """``Sequence.loader`` for a sequence whose frames do not fit its annotations (e.g. a line
    missing from its ground-truth file): the dataset still loads, its annotations can be scored,
    the preflight names ``reason`` (``--sequences`` runs the others) and a run of it fails with
    it. Picklable, like :class:`MissingFrames`."""

    def __init__(self, reason: str):
        self.reason = reason

    def __call__(self, k: int) -> np.ndarray:
        from ...core.sequence import FrameReadError

        raise FrameReadError(self.reason)


def annotation_files(folder: Path, suffix: str = ".txt") -> list[Path]:
    """``*<suffix>`` files of an annotation folder, without the kits' README / ATTRIBUTE_ORDER."""
    return sorted(p for p in folder.glob(f"*{suffix}") if p.is_file()
                  and not p.name.upper().startswith(("README", "ATTRIBUTE_ORDER")))
