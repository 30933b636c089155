"""The per-frame image cache (FrameImage / derived): one computation per frame shared by the
blocks, invisible to plugins that do not use it, and identical results for grid_lk."""

from __future__ import annotations

import numpy as np
import pytest

from mata_eval.core.sequence import Sequence
from mata_eval.run.scheduler import every_frame, run_sequence
from mata_eval.types import Frame, FrameImage, Motion, TrackerOutput, derived
from mata_eval_plugins.egomotion.grid_lk import GridLK, prepare_gray


def _image(seed: int = 0, shape=(120, 160, 3)) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)


def test_derived_computes_once_per_frame_and_is_read_only():
    calls = []
    img = FrameImage(_image())

    def make(a):
        calls.append(type(a))
        return a.sum(axis=2)

    first = derived(img, "sum", make)
    second = derived(img, "sum", make)
    assert first is second and len(calls) == 1
    assert calls[0] is np.ndarray  # make sees a plain array, so its result is plain too
    assert not first.flags.writeable
    with pytest.raises(ValueError):
        first[0, 0] = 1


def test_plain_arrays_and_slices_are_computed_each_time():
    calls = []
    make = lambda a: calls.append(1) or a.mean()  # noqa: E731
    plain = _image()
    derived(plain, "m", make)
    derived(plain, "m", make)
    crop = FrameImage(_image())[10:20, 10:20]  # a slice is not the frame: no cache
    derived(crop, "m", make)
    derived(crop, "m", make)
    assert len(calls) == 4


def test_frame_image_is_an_ordinary_image_to_plugins():
    raw = _image()
    img = FrameImage(raw)
    assert isinstance(img, np.ndarray) and img.shape == raw.shape and img.dtype == np.uint8
    assert np.shares_memory(img, raw) and np.array_equal(img, raw)


def test_frame_decodes_once():
    reads = []
    frame = Frame(3, 0.1, lambda: reads.append(1) or _image())
    assert frame.image is frame.image and len(reads) == 1
    assert isinstance(frame.image, FrameImage)


def test_prepare_gray_shares_products_and_matches_the_plain_path():
    raw = _image(1, (90, 130, 3))
    img = FrameImage(raw)
    a = prepare_gray(img, 2.0, True)
    b = prepare_gray(img, 2.0, True)
    assert a is b
    assert np.array_equal(a, prepare_gray(raw, 2.0, True))
    assert prepare_gray(img, 1.0, False) is prepare_gray(img, 1.0, False)


def test_grid_lk_gives_the_same_motion_on_frame_images():
    """Two frames of a textured scene shifted by (3, 2) px: identical motions either way."""
    base = np.kron(_image(2, (60, 80, 1))[..., 0], np.ones((4, 4), np.uint8))
    frames = [np.dstack([np.roll(base, (2 * i, 3 * i), (0, 1))] * 3) for i in range(3)]
    plain, shared = GridLK(), GridLK()
    plain.initialize(frames[0])
    shared.initialize(FrameImage(frames[0]))
    for f in frames[1:]:
        m1, m2 = plain.estimate(f), shared.estimate(FrameImage(f))
        assert m1.valid and m2.valid
        assert np.array_equal(m1.H, m2.H) and np.array_equal(m1.cov, m2.cov)
        assert abs(m1.H[0, 2] - 3.0) < 0.1 and abs(m1.H[1, 2] - 2.0) < 0.1


def test_scheduler_hands_both_blocks_one_shared_frame():
    """The egomotion block and the tracker receive the same FrameImage at a frame, so a grey
    image the first one derives is reused by the second; each frame is read once."""
    reads, grey_calls, seen = [], [], []

    def gray_of(image):
        return derived(image, "gray", lambda a: grey_calls.append(1) or a[..., 0].copy())

    class Ego:
        def initialize(self, image):
            gray_of(image)

        def estimate(self, image):
            seen.append(("ego", id(image)))
            gray_of(image)
            return Motion.identity()

    class Trk:
        def initialize(self, image, box):
            self.box = box

        def track(self, image, prior=None):
            seen.append(("trk", id(image)))
            gray_of(image)
            return TrackerOutput(self.box, 1.0)

    n = 5
    seq = Sequence("s", np.tile([10.0, 10.0, 20.0, 20.0], (n, 1)), fps=30.0,
                   loader=lambda k: reads.append(k) or _image(k, (40, 50, 3)))
    class LTP:
        def timing(self, fps):
            return every_frame(fps)

    run_sequence(seq, Trk(), Ego(), None, LTP(), np.random.default_rng(0))
    assert reads == list(range(n))
    assert len(grey_calls) == n
    ids = [i for _, i in seen]
    assert [ids[2 * j] == ids[2 * j + 1] for j in range(n - 1)] == [True] * (n - 1)


def test_runs_of_a_task_share_one_frame_and_its_products():
    """Two runs of one sequence advanced in lockstep on a task's shared sequence (one decode per
    frame, mata_eval.run.tasks): a grey image derived by one run's block is reused by the other's."""
    from mata_eval.run.scheduler import sequence_steps
    from mata_eval.run.tasks import shared

    reads, grey_calls = [], []

    class Ego:
        def initialize(self, image):
            self.estimate(image)

        def estimate(self, image):
            derived(image, "gray", lambda a: grey_calls.append(1) or a[..., 0].copy())
            return Motion.identity()

    class Trk:
        def initialize(self, image, box):
            self.box = box

        def track(self, image, prior=None):
            return TrackerOutput(self.box, 1.0)

    class LTP:
        def timing(self, fps):
            return every_frame(fps)

    n = 4
    seq = shared(Sequence("s", np.tile([10.0, 10.0, 20.0, 20.0], (n, 1)), fps=30.0,
                          loader=lambda k: reads.append(k) or _image(k, (40, 50, 3))))
    runs = [sequence_steps(seq, Trk(), Ego(), None, LTP(), np.random.default_rng(0)) for _ in range(2)]
    done = 0
    while done < len(runs):
        done = 0
        for r in runs:
            try:
                next(r)
            except StopIteration:
                done += 1
    assert reads == list(range(n)) and len(grey_calls) == n
