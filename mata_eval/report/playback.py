"""Playback of runs on their frames (``mata-eval play``): a video, or a PNG contact sheet, that
shows at each frame the ground truth, each run's scored box (MATA's estimate for a MATA run),
the tracker's own box and its search region where the run recorded them, the occluders of an
occlusion-augmented run, and which blocks published at that frame.

Everything drawn is read from the run folders (``<seq>.txt``, ``<seq>.frames.csv``,
``<seq>.trace.csv``, ``manifest.json``); the frames, with their occluders, are rebuilt from the
dataset and occlusion blocks of the first run's manifest, as that run saw them. Videos are
written with OpenCV's ``VideoWriter`` (MPEG-4 Part 2 in ``.mp4``, Motion JPEG in ``.avi``)."""

from __future__ import annotations

import csv
import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence as Seq

import cv2
import numpy as np

from ..core.sequence import Sequence
from ..run import results
from ..run.scheduler import read_trace_csv

GT_COLOUR = (80, 220, 80)  # BGR green: the ground truth
OCCLUDER_COLOUR = (255, 255, 255)
BLOCK_LETTERS = (("tracker", "A"), ("egomotion", "B"), ("estimator", "C"))  # paper section 2
FOURCC = {".mp4": "mp4v", ".avi": "MJPG"}


@dataclass(frozen=True, eq=False)
class RunTrack:
    """What one run recorded for one sequence, one row per frame (NaN where nothing).

    ``boxes``: the scored box (the held output); ``source_frame``: the frame the held output was
    computed from; ``published``: the blocks that published at each frame; ``tracker_box`` and
    ``search``: the box and the search window of the tracker's latest call at each frame (None
    when the run folder does not have them); ``mata``: the run has an estimator, so its scored
    box is MATA's estimate."""

    name: str
    boxes: np.ndarray
    source_frame: np.ndarray
    published: tuple[frozenset, ...]
    tracker_box: np.ndarray | None
    search: np.ndarray | None
    mata: bool


def _columns(path: Path) -> dict[str, np.ndarray]:
    """The numeric columns of a ``frames.csv`` by name ("nan" and empty cells are NaN)."""
    with open(path, newline="") as f:
        rows = [r for r in csv.reader(f) if r]
    if not rows:
        return {}
    head, body = rows[0], rows[1:]
    out = {}
    for j, name in enumerate(head):
        try:
            out[name] = np.array([float(r[j]) if r[j].strip() not in ("", "nan") else np.nan for r in body])
        except (ValueError, IndexError):
            raise ValueError(f"{path}: column {name!r}: expected numbers") from None
    return out


def read_run_track(run_dir: Path, seq: str, n_frames: int) -> RunTrack:
    """One run's record of sequence ``seq``; raises FileNotFoundError / ValueError naming the file."""
    run_dir = Path(run_dir)
    pred = results.predictions_path(run_dir, seq)
    if not pred.is_file():
        failed = run_dir / f"{seq}.failed.json"
        why = f"; it failed, see {failed}" if failed.is_file() else ""
        raise FileNotFoundError(f"{run_dir}: no results for sequence {seq!r}{why}")
    boxes = results.read_predictions(pred)
    if len(boxes) != n_frames:
        raise ValueError(f"{pred}: {len(boxes)} boxes for a sequence of {n_frames} frames")
    frames_csv = run_dir / f"{seq}.frames.csv"
    cols = _columns(frames_csv) if frames_csv.is_file() else {}
    source = np.nan_to_num(cols.get("source_frame", np.arange(n_frames)), nan=0).astype(int)
    published: list[set] = [set() for _ in range(n_frames)]
    trace = run_dir / f"{seq}.trace.csv"
    if trace.is_file():
        for e in read_trace_csv(trace.read_text()):
            if e.event == "publish" and e.block != "camera" and 0 <= e.frame < n_frames:
                published[e.frame].add(e.block)

    def quad(prefix: str) -> np.ndarray | None:
        """The ``<prefix>_x, _y, _w, _h`` columns, each row held until the next call."""
        keys = [f"{prefix}_{c}" for c in ("x", "y", "w", "h")]
        if not all(k in cols for k in keys):
            return None
        a = np.stack([cols[k] for k in keys], axis=1)
        last = np.maximum.accumulate(np.where(np.isfinite(a).all(axis=1), np.arange(len(a)), 0))
        return a[last]

    manifest = results.read_manifest(run_dir) or {}
    config = manifest.get("config") or {}
    return RunTrack(str(manifest.get("run", run_dir.name)), boxes, source,
                    tuple(frozenset(p) for p in published), quad("tracker"), quad("search"),
                    config.get("estimator") is not None)


def sequence_of_run(run_dir: Path, seq: str) -> Sequence:
    """Sequence ``seq`` as the run saw it: its dataset block (and occlusion augmentation, with
    the run's seed) from the run's manifest."""
    from ..core.params import build_params
    from ..core.registry import load_registry
    from ..data.occlusion import OcclusionParams, augment_sequence

    manifest = results.read_manifest(Path(run_dir))
    if not manifest or not isinstance(manifest.get("config"), dict):
        raise FileNotFoundError(f"{run_dir}: no manifest.json (not a mata-eval run folder)")
    config = manifest["config"]
    block = dict(config["dataset"])
    entry = load_registry().get("dataset", block.pop("name"))
    if "sequences" in {f.name for f in dataclasses.fields(entry.cls.Params)}:
        block["sequences"] = [seq]     # only that one is loaded (a video or a bag holds one)
    sequences = [s for s in entry.cls(build_params(entry.cls.Params, block, ("dataset",))).sequences()
                 if s.name == seq]
    if not sequences:
        raise ValueError(f"{run_dir}: the run's dataset has no sequence {seq!r}")
    sequence = sequences[0]
    if config.get("occlusion") is not None:
        sequence = augment_sequence(sequence, OcclusionParams(**config["occlusion"]), int(manifest["seed"]))
    return sequence


def run_colours(n: int) -> list[tuple[int, int, int]]:
    """BGR colours of runs 0..n-1: matplotlib's tab10 cycle in order, as the plots give them (a
    run has the same colour everywhere), green skipped (the ground truth's)."""
    from .plots import run_colour

    return [tuple(int(round(255 * v)) for v in reversed(run_colour(i))) for i in range(n)]


def _rect(img: np.ndarray, box: np.ndarray | None, colour, thickness: int = 2, dashed: bool = False) -> None:
    if box is None or not np.all(np.isfinite(box)) or box[2] <= 0 or box[3] <= 0:
        return
    x, y, w, h = (int(round(v)) for v in box)
    if not dashed:
        cv2.rectangle(img, (x, y), (x + w, y + h), colour, thickness, cv2.LINE_AA)
        return
    corners = [(x, y), (x + w, y), (x + w, y + h), (x, y + h)]
    for (ax, ay), (bx, by) in zip(corners, corners[1:] + corners[:1]):
        n = max(1, max(abs(bx - ax), abs(by - ay)) // 8)
        for i in range(0, n, 2):  # every other 8-pixel dash
            p0 = (ax + (bx - ax) * i // n, ay + (by - ay) * i // n)
            p1 = (ax + (bx - ax) * (i + 1) // n, ay + (by - ay) * (i + 1) // n)
            cv2.line(img, p0, p1, colour, 1, cv2.LINE_8)


def _text(img: np.ndarray, text: str, org: tuple[int, int], colour=(255, 255, 255), scale: float = 0.5) -> None:
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)


def _wrap(parts: Seq[str], width: int, scale: float) -> list[str]:
    """``parts`` joined by three spaces into lines no wider than ``width`` px at ``scale``: a
    part that does not fit on the line starts the next one, a part wider than a line is broken
    between words."""
    def fits(text: str) -> bool:
        return cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 3)[0][0] <= width

    lines: list[str] = []
    for part in parts:
        if lines and fits(f"{lines[-1]}   {part}"):
            lines[-1] = f"{lines[-1]}   {part}"
            continue
        lines.append("")
        for word in part.split(" "):
            if lines[-1] and not fits(f"{lines[-1]} {word}"):
                lines.append("")
            lines[-1] = f"{lines[-1]} {word}" if lines[-1] else word
    return lines


def _caption_rows(k: int, n: int, absent: bool, states: Seq[tuple], width: int,
                  scale: float) -> list[tuple[tuple[int, int, int] | None, str, bool]]:
    """The caption strip's lines, (colour or None for the legend, text, whether it is the first
    line of its caption): the legend, then a caption per run ``(colour, name, mata, frame of
    what it holds, blocks published)``, each on as many lines as ``width`` needs."""
    captions = [(None, [f"frame {k} of 0-{n - 1}", f"ground truth (green): {'target absent' if absent else 'box'}",
                        "occluders: white", "dashed: search region", "thin: tracker box in MATA"])]
    for colour, name, mata, held, pub in states:
        what = "MATA estimate" if mata else "tracker box"
        captions.append((colour, [f"{name}: {what} of frame {held} (held {k - held} frames)", f"published now: {pub}"]))
    return [(c, text, i == 0) for c, parts in captions for i, text in enumerate(_wrap(parts, width, scale))]


def draw_frame(image: np.ndarray, k: int, groundtruth: np.ndarray, tracks: Seq[RunTrack],
               colours: Seq[tuple[int, int, int]], occluders: Iterable[np.ndarray] = ()) -> np.ndarray:
    """Frame ``k`` with everything drawn on it and a caption strip below: one line for the
    frame and the ground truth, one per run (its colour, what it holds, from which frame, and
    which of blocks A, B, C published at this frame)."""
    img = image.copy()
    for poly in occluders:
        cv2.polylines(img, [np.round(poly).astype(np.int32)], True, OCCLUDER_COLOUR, 1, cv2.LINE_AA)
    _rect(img, groundtruth[k], GT_COLOUR, 2)
    for t, c in zip(tracks, colours):
        if t.search is not None:
            _rect(img, t.search[k], c, dashed=True)
        if t.tracker_box is not None and t.mata:
            _rect(img, t.tracker_box[k], c, 1)
        _rect(img, t.boxes[k], c, 2)
    scale = max(0.45, min(0.8, img.shape[1] / 1600))
    line = int(40 * scale)
    absent = not np.all(np.isfinite(groundtruth[k]))
    states = [(c, t.name, t.mata, int(t.source_frame[k]),
               " ".join(letter for b, letter in BLOCK_LETTERS if b in t.published[k]) or "-")
              for t, c in zip(tracks, colours)]
    rows = _caption_rows(k, len(groundtruth), absent, states, img.shape[1] - (line + 12), scale)
    # the strip is as high as the longest caption of the sequence needs, so that every frame of
    # a video has one size: the last frame, the target absent, every block publishing
    longest = _caption_rows(len(groundtruth) - 1, len(groundtruth), True, [(c, n, m, 0, "A B C") for c, n, m, _, _ in states],
                            img.shape[1] - (line + 12), scale)
    strip = np.zeros((line * max(len(rows), len(longest)) + line // 3, img.shape[1], 3), np.uint8)
    for i, (c, text, first) in enumerate(rows):
        y = line * (i + 1) - 6
        if c is None:
            _text(strip, text, (8, y), scale=scale)
            continue
        if first:
            cv2.rectangle(strip, (8, y - line + 12), (8 + line - 12, y), c, -1)
        _text(strip, text, (line + 4, y), c, scale=scale)
    return np.vstack([img, strip])


def _frames(tracks: Seq[RunTrack], sequence: Sequence, frames: range, colours) -> Iterable[np.ndarray]:
    events = sequence.meta.get("occlusion_events", []) if sequence.meta else []
    for k in frames:
        occluders = [e.outline(k) for e in events if e.active(k)]
        yield draw_frame(sequence.image(k), k, sequence.groundtruth, tracks, colours, occluders)


def write_video(path: Path, images: Iterable[np.ndarray], fps: float) -> int:
    """Write ``images`` (BGR, all one size) as a video; returns the number of frames written."""
    path = Path(path)
    if path.suffix.lower() not in FOURCC:
        raise ValueError(f"{path}: expected a .mp4 or .avi file name")
    path.parent.mkdir(parents=True, exist_ok=True)
    writer, n = None, 0
    try:
        for img in images:
            if writer is None:
                writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*FOURCC[path.suffix.lower()]), float(fps),
                                         (img.shape[1], img.shape[0]))
                if not writer.isOpened():
                    raise OSError(f"{path}: OpenCV cannot open a video writer for this file")
            writer.write(img)
            n += 1
    finally:
        if writer is not None:
            writer.release()
    return n


def contact_sheet(images: Seq[np.ndarray], columns: int = 3, width: int = 1800) -> np.ndarray:
    """The images in a grid ``columns`` wide (fewer for fewer images), each resized to
    ``width / columns``."""
    columns = max(1, min(columns, len(images)))
    tile_w = width // columns
    tiles = [cv2.resize(im, (tile_w, int(round(im.shape[0] * tile_w / im.shape[1]))), interpolation=cv2.INTER_AREA)
             for im in images]
    tile_h = max(t.shape[0] for t in tiles)
    tiles = [np.vstack([t, np.zeros((tile_h - t.shape[0], tile_w, 3), np.uint8)]) for t in tiles]
    tiles += [np.zeros((tile_h, tile_w, 3), np.uint8)] * (-len(tiles) % columns)
    return np.vstack([np.hstack(tiles[r:r + columns]) for r in range(0, len(tiles), columns)])


def play(run_dirs: Seq[str | Path], seq: str, out: str | Path, frames: tuple[int, int] | None = None,
         sheet: int = 0) -> tuple[Path, int]:
    """Draw runs ``run_dirs`` on sequence ``seq`` into ``out``: a video of the frames ``A:B``
    (half-open; default all), or with ``sheet`` > 0 a PNG contact sheet of that many frames
    spread evenly over the range. Returns the file and the number of frames drawn."""
    out = Path(out).resolve()
    run_dirs = [Path(d).resolve() for d in run_dirs]
    with results.in_run_cwd(results.read_manifest(run_dirs[0])):   # the run's relative paths, as it ran
        return _play(run_dirs, seq, out, frames, sheet)


def _play(run_dirs: Seq[Path], seq: str, out: Path, frames: tuple[int, int] | None, sheet: int) -> tuple[Path, int]:
    if sheet < 0:
        raise ValueError(f"--sheet {sheet}: expected a number of frames >= 1")
    if sheet and out.suffix.lower() not in (".png", ".jpg", ".jpeg"):   # checked before any frame is drawn
        raise ValueError(f"{out}: a contact sheet is an image; expected a .png or .jpg name")
    if not sheet and out.suffix.lower() not in FOURCC:
        raise ValueError(f"{out}: expected a .mp4 or .avi file name (or --sheet N and a .png name)")
    sequence = sequence_of_run(run_dirs[0], seq)
    n = len(sequence)
    tracks = [read_run_track(d, seq, n) for d in run_dirs]
    a, b = frames if frames is not None else (0, n)
    if not 0 <= a < b <= n:
        raise ValueError(f"--frames {a}:{b}: sequence {seq!r} has frames 0:{n}")
    colours = run_colours(len(tracks))
    if sheet:
        picks = sorted(set(np.linspace(a, b - 1, num=min(sheet, b - a)).round().astype(int).tolist()))
        grid = contact_sheet(list(_frames(tracks, sequence, picks, colours)))
        out.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(out), grid):
            raise OSError(f"{out}: cannot write the contact sheet (expected a .png or .jpg name)")
        return out, len(picks)
    return out, write_video(out, _frames(tracks, sequence, range(a, b), colours), sequence.fps)
