"""A complete third-party tracker plugin (the README's example)."""

from dataclasses import dataclass

import cv2
import numpy as np

from mata_eval.hooks import hookimpl
from mata_eval.params import param
from mata_eval.types import Box, TrackerOutput


class TemplateTracker:
    """Normalised cross-correlation against the first-frame template (OpenCV matchTemplate)."""

    name = "template_tracker"

    @dataclass(frozen=True)
    class Params:
        search: float = param(2.0, "search window size relative to the target size")

    def __init__(self, params: Params):
        self.params = params

    def initialize(self, image: np.ndarray, box: Box) -> None:
        x, y, w, h = (int(round(v)) for v in (box.x, box.y, box.w, box.h))
        self.template = cv2.cvtColor(image[y:y + h, x:x + w], cv2.COLOR_BGR2GRAY)
        self.box = box

    def track(self, image: np.ndarray, prior=None) -> TrackerOutput:
        cx, cy = prior if prior is not None else self.box.center
        w, h = self.box.w, self.box.h
        sw, sh = w * self.params.search, h * self.params.search
        x0, y0 = int(max(0, cx - sw / 2)), int(max(0, cy - sh / 2))
        x1 = int(min(image.shape[1], cx + sw / 2)) + 1
        y1 = int(min(image.shape[0], cy + sh / 2)) + 1
        window = cv2.cvtColor(image[y0:y1, x0:x1], cv2.COLOR_BGR2GRAY)
        if window.shape[0] < self.template.shape[0] or window.shape[1] < self.template.shape[1]:
            return TrackerOutput(self.box, 0.0)
        scores = cv2.matchTemplate(window, self.template, cv2.TM_CCOEFF_NORMED)
        _, peak, _, (px, py) = cv2.minMaxLoc(scores)
        self.box = Box(float(x0 + px), float(y0 + py), w, h)
        return TrackerOutput(self.box, float(np.clip(peak, 0.0, 1.0)))


@hookimpl
def mata_eval_trackers():
    return [TemplateTracker]
