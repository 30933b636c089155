"""MATA block C: the homography EKF (paper section 2.3), with measurement gating, partial
asynchronous updates and optional compensation of delayed measurements.

Two presets (docs/mata.md): ``paper`` is block C as the paper describes it (EWMA confidence
gate with absolute thresholds, corners through H, fixed R, delayed boxes applied on arrival);
``mata``, the default, is the filter that does not make its tracker worse (delays compensated,
rotation-safe propagation, noise scaled with the target, a gate relative to the tracker's own
confidence statistics that keeps following a tracker whose boxes agree with the prediction,
innovation gating, R growing as confidence falls, corner process noise matched to the
innovations, no search centre handed over on a repeated picture). A parameter left unset
takes its preset's value; any parameter set in YAML overrides the preset.

Decisions (see docs/decisions/estimator.md): within a tick the homography measured for the
interval ending at this tick updates the H state *before* the corners are propagated (the
literal reading, H held from the previous tick, is ``h_update: after_predict``); ``dt`` is in
seconds so velocities are px/s; Q entries are variance rates per second (Q = q dt).
"""

from __future__ import annotations

import bisect
import dataclasses
import math
import os
import statistics
import struct
from dataclasses import dataclass
from typing import Any, Literal, Mapping, NamedTuple, Sequence

import numpy as np

from mata_eval.hooks import hookimpl
from mata_eval.params import param
from mata_eval.types import Box, Estimate, Motion, Stamped, TrackerOutput

from . import ekf_math as em

BACKENDS = ("auto", "numpy", "numba")
BACKEND_ENV = "MATA_EVAL_EKF_BACKEND"  # overrides ``auto``: numpy or numba for every preset
# the methods of a tick that the compiled kernel does itself: a subclass overriding one runs numpy
TICK_METHODS = ("_tick_state", "_velocity_prior", "_process_noise", "_update_motion", "_motion_measurement",
                "_update_detection", "_innovation_average", "_gate_detection", "_box_noise")
N_DERIV = {"cv": 1, "ca": 2, "cj": 3}
EPS_T = 1e-6  # seconds: two times closer than this are the same camera frame
CONFIDENCE_HISTORY = 100  # accepted confidences behind the relative gate's median (10 s at 10 Hz)
#: feedback_hold, repeat_hold and fresh_output trust a box used at half the tracker's typical confidence or
#: more: its R is at most 4 times nominal (r_confidence), the level of the relative gate's drop
#: test (tau_diff 0.5)
HOLD_CONFIDENCE = 0.5
#: feedback_hold holds a box at most this old (seconds; docs/mata.md): on the 30 fps tuning footage
#: every LTP box is 1/30 s old when the tracker next starts, every EOP box 0.1 s or more, and
#: holding a 0.1 s old box lost MountainBike6 at EOP, so any bound in [1/30, 0.1) gives the same
#: tuning result; 0.05 s, the frame period of 20 fps video, lies inside
HOLD_AGE_S = 0.05

# Defaults for the homography entries (row-major h11..h33; units 1, 1, px, 1, 1, px, 1/px, 1/px, 1).
_Q_H = [3e-3, 3e-3, 3e2, 3e-3, 3e-3, 3e2, 3e-9, 3e-9, 3e-9]
_P0_H = [1e-3, 1e-3, 1e2, 1e-3, 1e-3, 1e2, 1e-8, 1e-8, 1e-8]
_R_H_FLOOR = [1e-8, 1e-8, 1e-4, 1e-8, 1e-8, 1e-4, 1e-14, 1e-14, 1e-10]


# --- presets (docs/mata.md gives the measured evidence for each "mata" value) -------------------

# the ablation row of the unmodified paper preset (paper Table 3, configuration 2: "MATA")
PAPER_BLOCK_C = "MATA, the paper's block C (preset paper)"

PRESETS: dict[str, dict[str, Any]] = {
    "paper": dict(gate="absolute", tau_ewma=0.25, tau_diff=0.25, chi2_gate=0.0, follow_consistent=False,
                  delay="ignore", box_motion="corners", r_box=4.0, r_box_rel=0.0, r_confidence=False,
                  q_box=30.0, q_box_rel=0.0, q_v=1e3, follow_prior=0.0, velocity_decay_s=0.0, q_adapt=False,
                  repeat_hold=False, feedback_hold=False, fresh_output=False),
    "mata": dict(gate="relative", tau_ewma=0.25, tau_diff=0.5, chi2_gate=18.47, follow_consistent=True,
                 delay="compensate", box_motion="centre", r_box=1.0, r_box_rel=0.05, r_confidence=True,
                 q_box=0.0, q_box_rel=0.2, q_v=1e2, follow_prior=1.0, velocity_decay_s=1.0, q_adapt=True,
                 repeat_hold=True, feedback_hold=True, fresh_output=True),
}


def _preset_param(key: str, doc: str) -> Any:
    """A parameter whose default depends on ``preset`` (shown by ``mata-eval list -v``)."""
    values = "; ".join(f"{name}: {vals[key]!r}" for name, vals in PRESETS.items())
    return param(None, f"{doc} [unset = preset value, {values}]")


# --- block A gating (eq. ewma_score) ---------------------------------------------------------

def confidence_gate(ewma: float | None, confidence: float, alpha: float, tau_ewma: float,
                    tau_diff: float, consistent: bool = False) -> tuple[float | None, bool]:
    """Update the EWMA S_k = alpha P_k + (1 - alpha) S_{k-1} with the tracker confidence P_k and
    decide: accept unless S_k < tau_ewma (the level test, skipped for a ``consistent`` box:
    ``follow_consistent``) or P_k dropped below S_k by more than tau_diff (the drop test).
    The first confidence seeds the average (S_1 = P_1). Returns (S_k, accept)."""
    if not math.isfinite(confidence):
        return ewma, False
    s = confidence if ewma is None else alpha * confidence + (1.0 - alpha) * ewma
    return s, bool((s >= tau_ewma or consistent) and s - confidence <= tau_diff)


def relative_confidence(history: tuple[float, ...], confidence: float, ranked: bool = False) -> float:
    """The confidence relative to the tracker's own typical value on this sequence: P_k divided
    by the median of the confidences it gave on the last accepted boxes (``history``, at most
    CONFIDENCE_HISTORY), capped at 1 (1 for the first output). Makes the paper's gate
    thresholds tracker-independent: absolute ones suit one tracker's confidence scale only.
    ``ranked``: ``history`` is in increasing order, so its median is read off without a sort."""
    if not math.isfinite(confidence) or confidence <= 0:
        return 0.0
    if not history:
        return 1.0
    # statistics.median: the same value as np.median, without numpy's overhead on 100 floats
    median = _median_of_ranked(history) if ranked else statistics.median(history)
    if median <= 0:  # gating off accepts zero-confidence boxes: any positive one is at least typical
        return 1.0
    return float(min(1.0, confidence / median))


def _median_of_ranked(r: tuple[float, ...]) -> float:
    """statistics.median of values already in increasing order (its formula, without the sort)."""
    i = len(r) // 2
    return r[i] if len(r) % 2 else (r[i - 1] + r[i]) / 2


# GateState and FilterState are built on every tick: immutable named tuples rather than frozen
# dataclasses, which take twice as long to build (issue 18: the tick's bookkeeping).

class GateState(NamedTuple):
    """Block A's gate memory: the EWMA S_k and the confidences of the accepted boxes."""

    ewma: float | None = None
    accepted: tuple[float, ...] = ()
    n_used: int = 0  # boxes used since init
    ranked: tuple[float, ...] = ()  # ``accepted`` in increasing order (a cheap median)
    nis: float = 1.0  # q_adapt: average normalised innovation squared of the used boxes
    following: bool = False  # the filter used the tracker's previous box (``follow_consistent``)
    # the relative confidence at which the filter used this tick's last box (against the
    # accepted ones before it; 0: not used, or no box): what feedback_hold, repeat_hold and
    # fresh_output trust
    used_relative: float = 0.0


class FilterState(NamedTuple):
    """Everything a tick changes: state, covariance and the gate's memory. The compiled path
    keeps an ``ekf_kernels.PackedState`` instead: the same fields, the gate packed in a vector."""

    x: np.ndarray
    P: np.ndarray
    gate: GateState

    @property
    def ewma(self) -> float | None:
        return self.gate.ewma

    @property
    def n_used(self) -> int:
        return self.gate.n_used

    @property
    def used_relative(self) -> float:
        return self.gate.used_relative


class _Tick:
    """One estimator tick: its time, dt since the previous one, the states before and after,
    and the measurements assigned to it (replayed when a delayed one arrives)."""

    __slots__ = ("t", "dt", "before", "after", "motions", "detections")

    def __init__(self, t: float, dt: float, before: FilterState, after: FilterState | None = None):
        self.t, self.dt, self.before, self.after = t, dt, before, after
        self.motions: list[Stamped[Motion]] = []
        self.detections: list[Stamped[TrackerOutput]] = []


class HomographyEKF:
    """Homography EKF (MATA block C): box corners carried by the camera homography, gated updates."""

    name = "homography_ekf"

    @classmethod
    def ablation(cls, params: Mapping[str, Any], egomotion: bool) -> tuple[bool, bool, str]:
        """Reports (paper Table 3): (ego-motion used, EKF used, what differs from the paper's
        configuration) of a resolved parameter block; ``egomotion``: the run has a block B."""
        default = cls.Params()
        preset = params.get("preset") or "paper"   # runs stored before the presets were the paper's
        p = {f: getattr(default, f) for f in ("camera", "model", "gating")}
        p.update(PRESETS[preset])
        p.update({k: v for k, v in params.items() if v is not None and k in p})
        ego = egomotion and p["camera"]
        parts = ["improved block C (preset mata)"] if preset == "mata" else []
        if not ego:
            parts.append("no camera compensation")
        parts.append({"ca": "constant acceleration model", "cj": "constant jerk model"}.get(p["model"], ""))
        if not p["gating"]:
            parts.append("no threshold on measurements")
        if p["delay"] != PRESETS[preset]["delay"]:
            parts.append("delay compensation" if p["delay"] == "compensate" else "measurements as current "
                                                                                  "(delay: ignore)")
        if p["gating"] and p["tau_ewma"] != PRESETS[preset]["tau_ewma"]:
            parts.append(f"confidence gate tau_ewma = {p['tau_ewma']:g}")
        # any other parameter set away from its preset's value: a different configuration too
        parts += [f"{k} = {p[k]}" for k in PRESETS[preset] if k not in ("delay", "tau_ewma") and p[k] != PRESETS[preset][k]]
        return ego, True, ", ".join(x for x in parts if x) or PAPER_BLOCK_C

    @dataclass(frozen=True)
    class Params:
        preset: Literal["mata", "paper"] = param(
            "mata", "values of the parameters left unset: 'mata' (improved, docs/mata.md) or "
            "'paper' (block C as built from the paper; the *_real.yaml experiments and the comparison runs)")
        model: Literal["cv", "ca", "cj"] = param(
            "cv", "dynamic model of the box centre: constant velocity (paper), acceleration or jerk")
        camera: bool = param(
            True, "use block B's homography; false = no camera compensation (H forced to identity)")
        gating: bool = param(
            True, "reject measurements by the tests below; false = use every measurement")
        gate: Literal["absolute", "relative"] | None = _preset_param(
            "gate", "confidence the EWMA gate sees: the tracker's own (paper eq. ewma_score) or "
            "relative to its median on the last 100 accepted boxes")
        alpha_ewma: float = param(
            0.3, "EWMA smoothing factor of the tracker confidence (paper eq. ewma_score)")
        tau_ewma: float | None = _preset_param(
            "tau_ewma", "reject the tracker's box while the confidence EWMA is below this")
        tau_diff: float | None = _preset_param(
            "tau_diff", "reject the tracker's box when its confidence is this far below the EWMA")
        chi2_gate: float | None = _preset_param(
            "chi2_gate", "a box whose squared Mahalanobis innovation (4 corners) exceeds this "
            "(18.47 = chi2 99.9 %) gets R multiplied by d2 / chi2_gate (a bounded step, not a "
            "reject); 0 = off")
        follow_consistent: bool | None = _preset_param(
            "follow_consistent", "while the filter uses the tracker's boxes, the EWMA level test "
            "(tau_ewma) does not reject a box consistent with the prediction (squared Mahalanobis "
            "innovation under the R of a box at typical confidence at most chi2_gate); the drop "
            "test still applies and R still grows as the confidence falls, so a tracker whose "
            "confidence declines slowly on a target that changes its look is followed, not dropped")
        tau_sigma: float = param(2.0, "reject a homography whose covariance moves the box centre by more than this std (px)")
        delay: Literal["ignore", "compensate"] | None = _preset_param(
            "delay", "delayed measurements: apply on arrival (paper) or at their capture time")
        history_s: float = param(2.0, "seconds of state history kept for delay: compensate")
        follow_prior: float | None = _preset_param(
            "follow_prior", "until the first box is used, the own velocity is the mixture of "
            "'still in the world' (paper: zero) and, with this probability, 'still in the image' "
            "(a camera that follows its target)")
        velocity_decay_s: float | None = _preset_param(
            "velocity_decay_s", "time constant (s) of the own velocity's relaxation towards keeping "
            "the target still in the image once boxes are used; 0 = none (paper)")
        feedback_shift: float = param(
            0.0, "with feedback, hand the tracker a search centre only when it lies more than "
            "this fraction of the tracker's newest box (its width in x, height "
            "in y) from that box's centre, where the tracker searches without a prior (0.5: "
            "outside that box); 0 = always (paper L424; docs/mata.md gives the measurements)")
        feedback_carry: bool = param(
            False, "with feedback, when the filter used the tracker's newest box, hand the tracker "
            "that box moved by the filter's predicted motion since its capture instead of the "
            "estimate's centre (false: the estimate, paper L424; docs/mata.md)")
        feedback_hold: bool | None = _preset_param(
            "feedback_hold", "with feedback, hand the tracker no search centre while its newest box "
            "is at most 0.05 s old (HOLD_AGE_S), was used by the filter at a relative confidence of "
            "at least 0.5 (HOLD_CONFIDENCE) and contains the estimate's centre (the tracker searches "
            "there anyway); otherwise the estimate (paper L424; docs/mata.md)")
        fresh_output: bool | None = _preset_param(
            "fresh_output", "report the tracker's box itself, not the filter's, when it was captured "
            "at this tick (no latency), used at a relative confidence of at least 0.5 "
            "(HOLD_CONFIDENCE) and contains the estimate's centre; the filter's state, covariance "
            "and what is fed back are unchanged (docs/mata.md)")
        repeat_hold: bool | None = _preset_param(
            "repeat_hold", "with feedback, on a frame that repeats the previous picture (block B's "
            "Motion.unchanged), hand the tracker no search centre while its newest box is from the "
            "previous tick and was used at a relative confidence of at least 0.5 (HOLD_CONFIDENCE): "
            "it found that box on this same picture (docs/mata.md)")
        q_adapt: bool | None = _preset_param(
            "q_adapt", "the corners' process noise times the average (EWMA, alpha_ewma) of the "
            "used boxes' normalised innovation squared d2 / 4, each capped at chi2_gate / 4, when "
            "above 1 (predictions worse than the filter believes: jerky footage, manoeuvres)")
        h_update: Literal["before_predict", "after_predict"] = param(
            "before_predict", "use this interval's homography before propagating the corners, or after (literal paper)")
        box_motion: Literal["corners", "centre"] | None = _preset_param(
            "box_motion", "propagate both corners through H (paper) or the centre through H and "
            "the size by the local scale sqrt|det J| (rotation-safe)")
        r_box: float | None = _preset_param(
            "r_box", "variance (px^2) of each measured corner coordinate, constant part")
        r_box_rel: float | None = _preset_param(
            "r_box_rel", "std of each measured corner coordinate relative to the box side "
            "sqrt(w h); adds (r_box_rel sqrt(w h))^2 to r_box")
        r_confidence: bool | None = _preset_param(
            "r_confidence", "divide R by the squared relative confidence (R grows as the "
            "confidence falls below its median)")
        r_h_floor: list[float] = param(
            _R_H_FLOOR, "per-entry floor of the homography measurement variance (9 values, row-major)")
        q_box: float | None = _preset_param(
            "q_box", "process noise of each corner coordinate (px^2 per second), constant part")
        q_box_rel: float | None = _preset_param(
            "q_box_rel", "process noise of each corner relative to the box side: adds "
            "(q_box_rel sqrt(w h))^2 per second to q_box")
        q_h: list[float] = param(_Q_H, "process noise of the homography entries (9 values, per second)")
        q_v: float | None = _preset_param(
            "q_v", "process noise of the centre velocity ((px/s)^2 per second)")
        q_a: float = param(1e4, "process noise of the centre acceleration (models ca, cj)")
        q_j: float = param(1e5, "process noise of the centre jerk (model cj)")
        p0_box: float = param(1.0, "initial variance of each corner coordinate (px^2)")
        p0_h: list[float] = param(_P0_H, "initial variance of the homography entries (9 values)")
        p0_v: float = param(1e4, "initial variance of the centre velocity ((px/s)^2)")
        p0_a: float = param(1e4, "initial variance of the centre acceleration ((px/s^2)^2)")
        p0_j: float = param(1e5, "initial variance of the centre jerk ((px/s^3)^2)")

        def __post_init__(self) -> None:
            """Checks beyond the declared types (run when the experiment file is loaded)."""
            for key in ("r_h_floor", "q_h", "p0_h"):
                v = getattr(self, key)
                if len(v) != 9 or not all(np.isfinite(v)) or min(v) < 0:
                    raise ValueError(f"homography_ekf: `{key}` must be 9 non-negative numbers "
                                     f"(row-major h11..h33), got {v!r}")
            if min(self.r_h_floor) <= 0:
                raise ValueError(f"homography_ekf: `r_h_floor` must be positive, got {self.r_h_floor!r}")
            if not 0.0 < self.alpha_ewma <= 1.0:
                raise ValueError(f"homography_ekf: `alpha_ewma` must be in (0, 1], got {self.alpha_ewma}")
            if not self.history_s > 0:
                raise ValueError(f"homography_ekf: `history_s` must be positive, got {self.history_s}")
            for key in ("q_box", "q_box_rel", "q_v", "q_a", "q_j", "p0_box", "p0_v", "p0_a", "p0_j",
                        "tau_sigma", "r_box_rel", "chi2_gate", "velocity_decay_s", "follow_prior",
                        "feedback_shift"):
                v = getattr(self, key)
                if v is not None and not v >= 0:
                    raise ValueError(f"homography_ekf: `{key}` must be >= 0, got {v}")
            if self.follow_prior is not None and not self.follow_prior <= 1:
                raise ValueError(f"homography_ekf: `follow_prior` must be in [0, 1], got {self.follow_prior}")
            if self.r_box is not None and not self.r_box > 0:
                raise ValueError(f"homography_ekf: `r_box` must be positive, got {self.r_box}")
            for key in ("tau_ewma", "tau_diff"):   # thresholds on a confidence in [0, 1]: outside, no gate
                v = getattr(self, key)
                if v is not None and not 0.0 <= v <= 1.0:
                    raise ValueError(f"homography_ekf: `{key}` must be in [0, 1] (a confidence threshold), got {v}")
            def value(key: str) -> Any:   # as resolved() gives it (which itself builds Params)
                v = getattr(self, key)
                return PRESETS[self.preset].get(key) if v is None else v

            if value("follow_consistent") and self.gating and not value("chi2_gate"):
                raise ValueError("homography_ekf: `follow_consistent` tests a box's innovation against `chi2_gate`, "
                                 "which is 0 (off): set chi2_gate > 0 or follow_consistent: false")

        def resolved(self) -> "HomographyEKF.Params":
            """These parameters with every unset one taken from the preset."""
            unset = {k: v for k, v in PRESETS[self.preset].items() if getattr(self, k) is None}
            return dataclasses.replace(self, **unset)

    def __init__(self, params: Params | None = None, backend: str | None = None):
        """``backend`` (or the environment variable MATA_EVAL_EKF_BACKEND): ``numba`` runs each
        tick as one compiled function (ekf_kernels, the ``fast`` extra), ``numpy`` the reference
        (ekf_math); ``auto`` (default) takes numba for preset ``mata`` when it is installed and
        numpy for ``paper``, which then reproduces the published figures bit for bit (the two
        agree to rounding, 1e-9 px: tests/test_ekf_kernels.py)."""
        self.params = p = (params if params is not None else self.Params()).resolved()
        self.n_deriv = N_DERIV[p.model]
        h_q = np.asarray(p.q_h, float) if p.camera else np.zeros(9)
        h_p0 = np.asarray(p.p0_h, float) if p.camera else np.zeros(9)
        dq = [p.q_v, p.q_a, p.q_j][: self.n_deriv]
        dp = [p.p0_v, p.p0_a, p.p0_j][: self.n_deriv]
        self._q = np.concatenate([np.full(4, p.q_box), h_q, np.repeat(dq, 2)])  # rates per second
        self._p0 = np.diag(np.concatenate([np.full(4, p.p0_box), h_p0, np.repeat(dp, 2)]))
        self._h_floor = np.asarray(p.r_h_floor, float)
        self._ticks: list[_Tick] = []
        overridden = [m for m in TICK_METHODS if getattr(type(self), m) is not getattr(HomographyEKF, m)]
        kernels = _compiled_tick(backend or os.environ.get(BACKEND_ENV) or "auto", p, overridden)
        # the compiled tick (a numba dispatcher, picklable like the filter) or None for numpy
        self._kernel = None if kernels is None else kernels.tick
        self._state, self._gate0 = FilterState, GateState()   # a tick's state record, the first gate
        if kernels is not None:
            self._motion_codes = (kernels.MOTION_NONE, kernels.MOTION_H, kernels.MOTION_H_COV)
            self._cfg = kernels.config(
                n_deriv=self.n_deriv, centre=p.box_motion == "centre", h_before=p.h_update == "before_predict",
                gating=p.gating, tau_sigma=p.tau_sigma, chi2=p.chi2_gate, r_box=p.r_box, r_box_rel=p.r_box_rel,
                r_conf=p.r_confidence, q_box_rel=p.q_box_rel, follow=p.follow_prior, decay=p.velocity_decay_s,
                p0_v=p.p0_v, q_adapt=p.q_adapt, alpha=p.alpha_ewma, relative=p.gate == "relative",
                tau_ewma=p.tau_ewma, tau_diff=p.tau_diff, follow_consistent=p.follow_consistent,
                floor=self._h_floor, q=self._q)
            self._state, self._gate0 = kernels.PackedState, kernels.new_gate(CONFIDENCE_HISTORY)
            kernels.load()     # compiled or loaded here, not in the first (timed) tick
            self._dets = np.empty((2, kernels.N_DET))     # the boxes of a tick (grown on demand)
            self._det_row = kernels.DET_ROW, kernels.DET_SIZE
            self._no_h = np.zeros((3, 3))
            self._no_cov = np.zeros((9, 9))
        self._newest: Stamped[TrackerOutput] | None = None  # the tracker's newest box (its own search centre)
        # the states before and after the tick of the tracker's newest box (None: not kept); whether
        # the filter used the box, and what feedback_carry needs, are read from them when asked
        self._newest_tick: tuple[FilterState, FilterState] | None = None
        self._previous_t = -math.inf  # the time of the tick before the newest
        self._trust = False   # the filter used the newest box at HOLD_CONFIDENCE or more (noted)
        # rules that read the tracker's newest box (noted in step())
        self._box_rules = (p.feedback_carry or p.feedback_shift or p.feedback_hold or p.repeat_hold
                           or p.fresh_output)

    # --- interface ---------------------------------------------------------------------------

    def initialize(self, box: Box, t: float) -> Estimate:
        if not box.is_valid:
            raise ValueError(f"homography_ekf: initial box must be finite with positive size, got {box}")
        x = np.zeros(em.state_dim(self.n_deriv))
        x[em.CORNERS] = box.corners()
        x[em.HOM] = np.eye(3).reshape(9)
        start = self._state(x, self._p0.copy(), self._gate0)
        self._ticks = [_Tick(float(t), 0.0, start, start)]
        self._newest = Stamped(TrackerOutput(box, 1.0), float(t), float(t))
        self._newest_tick, self._previous_t = None, -math.inf
        self._trust = False
        return self._estimate(start)

    def step(self, t: float, motions: Sequence[Stamped[Motion]] = (),
             detections: Sequence[Stamped[TrackerOutput]] = ()) -> Estimate:
        ticks = self._ticks
        if not ticks:
            raise RuntimeError("homography_ekf: step() called before initialize()")
        last = ticks[-1]
        if t < last.t - EPS_T:
            raise ValueError(f"homography_ekf: step at t={t} is before the previous tick t={last.t}")
        if t > last.t + EPS_T:
            self._previous_t = last.t
            last = _Tick(float(t), float(t) - last.t, last.after)
            ticks.append(last)
        first = newest = len(ticks) - 1
        on_time = last.t - EPS_T    # captured at the newest tick: the common case, decided here
        for item in motions:
            i = newest if item.t_capture >= on_time else self._tick_index(item.t_capture, True)
            ticks[i].motions.append(item)
            first = i if i < first else first
        noted, t_newest = None, self._newest.t_capture   # the tracker's newest box, its tick
        for item in detections:
            i = newest if item.t_capture >= on_time else self._tick_index(item.t_capture, False)
            ticks[i].detections.append(item)
            first = i if i < first else first
            if self._box_rules and item.t_capture >= t_newest and item.value.box.is_valid:
                noted, t_newest = (item, ticks[i]), item.t_capture
        if first == newest:
            last.after = self._run_tick(last)
        else:
            self._replay(first)
        self._trim()
        if not self._box_rules:
            return self._estimate(self._ticks[-1].after)
        if noted is not None:
            self._note_newest_box(*noted)
        return self._ruled_estimate(self._ticks[-1].after)

    @property
    def state(self) -> FilterState:
        """The newest filter state (x, P, confidence EWMA)."""
        return self._ticks[-1].after

    def diagnostics(self) -> dict[str, float]:
        """The newest state for a diagnosis (``MATA_EVAL_RECORD=1``: ``est_*`` columns of
        ``<seq>.frames.csv``): the centre's own velocity (px/s) and standard deviation (px), the
        number of boxes used since the start (a step up: a box passed the gate; with delay
        compensation it was applied at its capture tick), the gate's EWMA and q_adapt's
        innovation average."""
        s = self._ticks[-1].after
        x, P = s.x, s.P
        ewma = s.ewma
        return {"vx": float(x[13]), "vy": float(x[14]),
                "sd_cx": 0.5 * math.sqrt(max(P[0, 0] + P[2, 2] + 2 * P[0, 2], 0.0)),
                "sd_cy": 0.5 * math.sqrt(max(P[1, 1] + P[3, 3] + 2 * P[1, 3], 0.0)),
                "boxes_used": float(s.n_used), "ewma": math.nan if ewma is None else float(ewma),
                "nis": float(s.gate.nis)}

    # --- ticks --------------------------------------------------------------------------------

    def _tick_index(self, t_capture: float, interval: bool) -> int:
        """The tick a measurement belongs to: the newest under ``delay: ignore`` (applied on
        arrival); under ``compensate`` the tick nearest its capture time, or for a motion
        (``interval``: it ends at its capture time) the first tick at or after it; the newest
        when it is older than the kept history."""
        last = len(self._ticks) - 1
        if self.params.delay == "ignore" or t_capture >= self._ticks[-1].t - EPS_T:
            return last
        if t_capture < self._ticks[0].t - EPS_T:
            return last
        times = np.array([k.t for k in self._ticks])
        if interval:
            return int(np.argmax(times >= t_capture - EPS_T))
        return int(np.argmin(np.abs(times - t_capture)))

    def _replay(self, first: int) -> None:
        for i in range(first, len(self._ticks)):
            tick = self._ticks[i]
            if i > first:
                tick.before = self._ticks[i - 1].after
            tick.after = self._run_tick(tick)

    def _trim(self) -> None:
        if self.params.delay == "ignore":
            self._ticks = self._ticks[-1:]
            return
        horizon = self._ticks[-1].t - self.params.history_s
        while len(self._ticks) > 1 and self._ticks[1].t <= horizon:
            self._ticks.pop(0)

    def _run_tick(self, tick: _Tick) -> FilterState:
        """One tick: H update(s), prediction over dt, corner update(s); measurements in capture
        order. Predicting is skipped when dt = 0 (the initial frame, or measurements added to an
        already-run tick)."""
        if self._kernel is not None:
            return self._tick_compiled(tick)
        with np.errstate(over="ignore", invalid="ignore"):  # a degenerate input is held below
            return self._tick_state(tick)

    def _tick_compiled(self, tick: _Tick) -> FilterState:
        """:meth:`_tick_state` in one compiled call (``ekf_kernels.tick``), the confidence gate
        and its memory (a ``PackedGate``) included. The motion input is decided here, exactly
        as the numpy path decides it: one motion goes as it comes (the kernel tests that it is
        finite), several are composed by :meth:`_motion_measurement`."""
        b, motions, dets = tick.before, tick.motions, tick.detections
        no_motion, with_h, with_cov = self._motion_codes
        H, C, motion = self._no_h, self._no_cov, no_motion
        if len(motions) == 1 and self.params.camera:
            m = motions[0].value
            Hm = np.asarray(m.H, float)
            if m.valid and Hm.shape == (3, 3):
                if m.cov is None:
                    H, motion = Hm, with_h
                elif (Cm := np.asarray(m.cov, float)).shape == (9, 9):
                    H, C, motion = Hm, Cm, with_cov
        elif motions and (meas := self._motion_measurement(motions)) is not None:
            H, C = meas
            C, motion = (self._no_cov, with_h) if C is None else (C, with_cov)
        if len(dets) > 1:
            dets = sorted(dets, key=_t_capture)
            if len(dets) > len(self._dets):
                self._dets = np.empty((2 * len(dets), self._dets.shape[1]))
        row, size = self._det_row
        for i, d in enumerate(dets):
            box = d.value.box
            struct.pack_into(row, self._dets, i * size, box.x, box.y, box.w, box.h, d.value.confidence)
        x, P, g = b.x.copy(), b.P.copy(), b.g.copy()   # the kernel updates them in place
        if self._kernel(self._cfg, x, P, g, tick.dt, H, C, motion, self._dets, len(dets)):
            return self._state(x, P, g)
        return b                                # not finite: a degenerate input, held

    def _tick_state(self, tick: _Tick) -> FilterState:
        x, P, gate = tick.before.x, tick.before.P, tick.before.gate._replace(used_relative=0.0)
        motions = sorted(tick.motions, key=_t_capture)
        before = self.params.h_update == "before_predict"
        if before:
            x, P = self._update_motion(x, P, motions)
        if tick.dt > 0:
            x, P = self._velocity_prior(x, P, tick.dt, gate.n_used)
            fx, F = em.transition(x, tick.dt, self.n_deriv, self.params.box_motion)
            x, P = fx, em.predict_cov(P, F, np.diag(self._process_noise(x, gate.nis) * tick.dt))
        if not before:
            x, P = self._update_motion(x, P, motions)
        for det in sorted(tick.detections, key=_t_capture):
            x, P, gate = self._update_detection(x, P, gate, det.value)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
            return tick.before  # numerically degenerate input (e.g. an absurd H): hold, never NaN
        return FilterState(x, P, gate)

    def _velocity_prior(self, x: np.ndarray, P: np.ndarray, dt: float,
                        n_used: int) -> tuple[np.ndarray, np.ndarray]:
        """Beyond the paper. Until the first box is used, the own velocity is the moment-matched
        mixture of "still in the world" (v = 0, the paper's initial state) and, with
        probability ``follow_prior``, "still in the image" (the camera follows its target: the
        velocity that cancels the camera motion at the box); afterwards, with
        ``velocity_decay_s`` = tau > 0, it relaxes towards the latter with time constant tau."""
        p = self.params
        if p.follow_prior == 0 and p.velocity_decay_s == 0:
            return x, P
        v_img = em.image_static_velocity(x, dt)
        if n_used < 1 and p.follow_prior > 0:
            v = em.deriv_slice(0)
            return em.velocity_mixture(x, P, v_img, p.follow_prior, self._p0[v, v])
        if n_used >= 1 and p.velocity_decay_s > 0:
            x, A = em.relax_velocity(x, v_img, float(np.exp(-dt / p.velocity_decay_s)))
            P = A @ P @ A.T
        return x, P

    def _process_noise(self, x: np.ndarray, nis: float = 1.0) -> np.ndarray:
        """Q rates per second: the corners' grow with the box side sqrt(w h) (q_box_rel) and,
        with ``q_adapt``, by the boxes' average normalised innovation squared when above 1."""
        q = self._q
        if self.params.q_box_rel or (self.params.q_adapt and nis > 1.0):
            q = q.copy()
            q[em.CORNERS] += np.square(self.params.q_box_rel * em.box_side(x))
            if self.params.q_adapt:
                q[em.CORNERS] *= max(nis, 1.0)
        return q

    # --- measurements -----------------------------------------------------------------------------

    def _update_motion(self, x: np.ndarray, P: np.ndarray,
                       motions: list[Stamped[Motion]]) -> tuple[np.ndarray, np.ndarray]:
        """Block B: the motions of this tick composed into one (consecutive intervals), gated by
        validity and tau_sigma, then a partial update of the 9 homography entries. Invalid or
        rejected: no update, the H state is held (paper: H constant between measurements)."""
        meas = self._motion_measurement(motions)
        if meas is None:
            return x, P
        H, C = meas
        # validity: the box corners must stay in front of the camera (w > 0) under H
        for p in (x[em.TL], x[em.BR]):
            if H[2, 0] * p[0] + H[2, 1] * p[1] + H[2, 2] <= 1e-6:
                return x, P
        if self.params.gating and C is not None:
            centre = 0.5 * (x[em.TL] + x[em.BR])
            if not em.transferred_sigma(H, C, centre) <= self.params.tau_sigma:
                return x, P
        return em.joseph_update_block(x, P, H.reshape(9), em.HOM, em.floored(C, self._h_floor))

    def _motion_measurement(self, motions: Sequence[Stamped[Motion]]) -> tuple[np.ndarray, np.ndarray | None] | None:
        """The motions of a tick (in capture order) composed into one (H, C), H in the h33 = 1
        chart; None without camera, without motions, or when one is invalid or not finite."""
        if not self.params.camera or not motions:
            return None
        H, C = None, None
        for s in motions:
            m = s.value
            Hm = np.asarray(m.H, dtype=float)
            if (not m.valid or Hm.shape != (3, 3) or not np.all(np.isfinite(Hm))
                    or abs(Hm[2, 2]) < 1e-12):
                return None
            Cm = None if m.cov is None else np.asarray(m.cov, dtype=float)
            if Cm is not None and (Cm.shape != (9, 9) or not np.all(np.isfinite(Cm))):
                return None
            Hm = em.normalise_h33(Hm)
            if H is None:
                H, C = Hm, Cm
            else:
                H, C = em.compose(H, C, Hm, Cm)
        return H, C

    def _update_detection(self, x: np.ndarray, P: np.ndarray, gate: GateState,
                          out: TrackerOutput) -> tuple[np.ndarray, np.ndarray, GateState]:
        """Block A: confidence gate (eq. ewma_score, on the tracker's confidence or on the
        confidence relative to its median; with ``follow_consistent`` the level test spares a box
        consistent with the prediction while the previous box was used), then a partial update
        of the four corners with R of :meth:`_box_noise`, inflated for an improbable innovation
        (chi2_gate; a hard reject there locks a confidently wrong filter out of all later
        boxes). A non-finite or empty box is never used."""
        p = self.params
        z = np.asarray(out.box.corners(), float)
        consistent = False
        if p.follow_consistent and gate.following and p.chi2_gate and out.box.is_valid:
            # the innovation as a box at the tracker's typical confidence would have it
            d2 = em.mahalanobis2(z - x[em.CORNERS], P[em.CORNERS, em.CORNERS] + self._box_noise(x, 1.0))
            consistent = d2 <= p.chi2_gate
        gate, conf = self._gate_detection(gate, out, consistent)
        if conf is None:
            return x, P, gate
        R = self._box_noise(x, conf)
        if p.q_adapt:  # before R is inflated: d2 measures the prediction against the box's R
            d2 = em.mahalanobis2(z - x[em.CORNERS], P[em.CORNERS, em.CORNERS] + R)
            gate = gate._replace(nis=self._innovation_average(gate.nis, d2))
        if p.gating and p.chi2_gate:
            R = em.robust_noise(z - x[em.CORNERS], P[em.CORNERS, em.CORNERS], R, p.chi2_gate)
        x, P = em.joseph_update_block(x, P, z, em.CORNERS, R)
        return x, P, gate

    def _innovation_average(self, nis: float, d2: float) -> float:
        """q_adapt: the average ``nis`` with a used box's squared Mahalanobis innovation d2 (4
        corners, under the box's R before the chi2 inflation)."""
        p = self.params
        cap = p.chi2_gate if p.chi2_gate else np.inf
        return em.normalised_innovation_average(nis, d2, 4, cap, p.alpha_ewma)

    def _gate_detection(self, gate: GateState, out: TrackerOutput,
                        consistent: bool = False) -> tuple[GateState, float | None]:
        """Block A's gate (needs no state): the gate memory after this box and the confidence
        its noise uses (relative with gate ``relative``), or None when the box is not used. The
        compiled path runs its twin, ``ekf_kernels._gate``, on a packed memory."""
        p = self.params
        raw = float(out.confidence)
        rel = relative_confidence(gate.ranked, raw, ranked=True)
        relative = p.gate == "relative"
        conf = rel if relative else raw
        ewma, accept = confidence_gate(gate.ewma, conf, p.alpha_ewma, p.tau_ewma, p.tau_diff, consistent)
        if relative and conf <= 0:
            accept = False  # a tracker that found nothing says so with confidence 0
        if not out.box.is_valid or (p.gating and not accept):
            return GateState(ewma, gate.accepted, gate.n_used, gate.ranked, gate.nis, False, 0.0), None
        if not relative:
            return GateState(ewma, gate.accepted, gate.n_used + 1, gate.ranked, gate.nis, True, rel), conf
        ranked = list(gate.ranked)
        if len(gate.accepted) == CONFIDENCE_HISTORY:   # the oldest one leaves
            del ranked[bisect.bisect_left(ranked, gate.accepted[0])]
        bisect.insort(ranked, raw)
        return GateState(ewma, gate.accepted[-(CONFIDENCE_HISTORY - 1):] + (raw,), gate.n_used + 1,
                         tuple(ranked), gate.nis, True, rel), conf

    def _box_noise(self, x: np.ndarray, relative_conf: float) -> np.ndarray:
        """R of a box: (r_box + (r_box_rel sqrt(w h))^2) I, divided by the squared relative
        confidence with ``r_confidence`` (floored at 0.1: R at most 100 times larger)."""
        p = self.params
        r = p.r_box + np.square(p.r_box_rel * em.box_side(x))
        if p.r_confidence:
            r = r / max(relative_conf, 0.1) ** 2
        return np.eye(4) * r

    def _note_newest_box(self, det: Stamped[TrackerOutput], tick: _Tick) -> None:
        """Keep the tracker's newest box by capture time (where it searches without a prior)
        and the states before and after its tick as they are now (a later replay replaces the
        tick's states, not these; None when the tick fell out of the history): whether the
        filter used the box and the posterior centre there (for ``feedback_carry``) are read
        from them when asked. Whether the box is trusted (``feedback_hold``, ``repeat_hold``,
        ``fresh_output``) is decided here: the filter used it at a relative confidence of at
        least HOLD_CONFIDENCE (it is its tick's last box, whose ``used_relative`` the gate
        memory records; a tick held on a degenerate input used nothing)."""
        kept = tick.t >= self._ticks[0].t    # ticks are in time order; _trim drops the oldest
        self._newest, self._newest_tick = det, (tick.before, tick.after) if kept else None
        self._trust = kept and tick.after is not tick.before and tick.after.used_relative >= HOLD_CONFIDENCE

    def _newest_use(self) -> tuple[FilterState, FilterState] | None:
        """The states before and after the tick where the filter used the tracker's newest box,
        or None when it did not use it."""
        states = self._newest_tick
        return states if states is not None and states[1].n_used > states[0].n_used else None

    def _newest_fit(self) -> tuple[float, float] | None:
        """The posterior centre of the tick where the filter used the tracker's newest box."""
        use = self._newest_use()
        if use is None:
            return None
        x1, y1, x2, y2 = use[1].x[em.CORNERS]
        return 0.5 * (x1 + x2), 0.5 * (y1 + y2)

    def _ruled_estimate(self, s: FilterState) -> Estimate:
        """The estimate of state ``s`` under the rules that read the tracker's newest box: what
        is fed back (:meth:`_feedback`) and ``fresh_output``, built once (an Estimate costs about
        1 us, a tenth of the tick: issue 18)."""
        x, y, w, h = xywh = _box_values(s)     # the Box is built only where it is returned
        centre = (x + w / 2.0, y + h / 2.0)    # box.center, as its properties compute it
        age = self._ticks[-1].t - self._newest.t_capture     # of the tracker's newest box (s)
        inside = self._trust and _shift(centre, self._newest.value.box) <= 0.5   # trusted, contains it
        feedback, search = self._feedback(centre, age, inside)
        if self.params.fresh_output and inside and age <= EPS_T:   # captured at this tick
            # fresh_output: a box captured at this tick has no latency for the filter to make up,
            # and at LTP the filter's centre is further from the truth than it (docs/mata.md); a
            # box that jumps away from the estimate is still smoothed. What is fed back stays the
            # filter's search centre.
            search = (centre if search is None else search) if feedback else None
            return Estimate(self._newest.value.box, s.P.copy(), feedback, search)
        return Estimate(Box(*xywh), s.P.copy(), feedback, search)

    def _feedback(self, centre: tuple[float, float], age: float,
                  inside: bool) -> tuple[bool, tuple[float, float] | None]:
        """What is fed back to the tracker, given the estimate's ``centre``, the ``age`` of the
        tracker's newest box and whether that box is trusted and contains ``centre``
        (``inside``), as Estimate's (feedback, search) (beyond the paper, whose L424 feeds every
        estimate's centre back; docs/mata.md). ``feedback_carry``: when the filter used the tracker's newest box, the
        search centre is that box moved by the filter's predicted motion since its capture
        (camera and own motion: what the tracker cannot see), not the estimate, which also
        carries the filter's smoothing of the box. ``feedback_shift`` f: nothing is fed back when
        that centre lies within f of the newest box (its width in x, height in y), where the
        tracker searches anyway. ``feedback_hold``: the same with f = 0.5, only while that box is
        at most HOLD_AGE_S old and was used at a relative confidence of at least
        HOLD_CONFIDENCE; an older or doubtful box gets the estimate. ``repeat_hold``: nothing is
        fed back on a repeated picture while that box is fresh and trusted."""
        p = self.params
        if p.repeat_hold and self._repeated_picture() and self._fresh_and_trusted():
            return False, None
        if not (p.feedback_carry or p.feedback_hold or p.feedback_shift):
            return True, None
        b = self._newest.value.box
        search = None
        if p.feedback_carry and (fit := self._newest_fit()) is not None:
            search = (b.cx + centre[0] - fit[0], b.cy + centre[1] - fit[1])
        prior = centre if search is None else search
        if p.feedback_hold and age <= HOLD_AGE_S + EPS_T and (
                inside if search is None else self._trust and _shift(search, b) <= 0.5):
            return False, search
        f = p.feedback_shift
        return (not f or _shift(prior, b) > f), search

    def _fresh_and_trusted(self) -> bool:
        """``repeat_hold``: the tracker's newest box was captured at the previous tick or later
        (on the picture repeated now), and is trusted."""
        return self._newest.t_capture >= self._previous_t - EPS_T and self._trust

    def _repeated_picture(self) -> bool:
        """``repeat_hold``: block B found the newest tick's frame to repeat the previous picture
        (``Motion.unchanged``, e.g. a clip padded to a higher frame rate). Nothing in it moved,
        so the tracker's box from the previous frame was found on this very picture and no
        prediction can improve on it; the filter may still predict motion over the frame (its
        constant velocity spreads the motion of the new pictures over every frame)."""
        motions = self._ticks[-1].motions
        for m in motions:   # all(...) without a generator: asked on every tick
            if not m.value.unchanged:
                return False
        return bool(motions)

    @staticmethod
    def _estimate(s: FilterState) -> Estimate:
        """The estimate of state ``s`` (:func:`_box`, its covariance), fed back as it is."""
        return Estimate(_box(s), s.P.copy())


def _box(s: FilterState) -> Box:
    """The box from the corner states; a degenerate box keeps its centre with >= 1 px sides."""
    return Box(*_box_values(s))


def _box_values(s: FilterState) -> tuple[float, float, float, float]:
    """:func:`_box`'s x, y, w, h (a Box costs half a microsecond: issue 18)."""
    x1, y1, x2, y2 = s.x[:4].tolist()
    w, h = x2 - x1, y2 - y1
    w, h = (1.0 if w < 1.0 else w), (1.0 if h < 1.0 else h)   # max(w, 1.0), without a call
    return 0.5 * (x1 + x2) - w / 2.0, 0.5 * (y1 + y2) - h / 2.0, w, h


def _shift(centre: tuple[float, float], b: Box) -> float:
    """How far a search centre lies from box ``b``'s centre, in box widths (x) or heights (y),
    whichever is more: at most 0.5 inside the box (``feedback_shift``, ``feedback_hold``)."""
    x, y, w, h = b.x, b.y, b.w, b.h      # b.cx and b.cy, without the property calls
    return max(abs(centre[0] - (x + w / 2.0)) / w, abs(centre[1] - (y + h / 2.0)) / h)


def _t_capture(s: Stamped) -> float:
    return s.t_capture


def _compiled_tick(backend: str, params: HomographyEKF.Params, overridden: Sequence[str] = ()):
    """The ekf_kernels module for the numba backend, or None for the numpy reference: with
    ``auto``, numba for preset mata when it is installed, implements every parameter and no
    method of the tick is ``overridden`` by a subclass (the kernel would ignore it)."""
    if backend not in BACKENDS:
        raise ValueError(f"homography_ekf: backend (or ${BACKEND_ENV}) must be one of {BACKENDS}, got {backend!r}")
    if overridden and backend == "numba":
        raise ValueError(f"homography_ekf: backend numba (or ${BACKEND_ENV}=numba) computes the tick in compiled "
                         f"code, which would ignore the subclass's {', '.join(overridden)}; use backend numpy "
                         f"(auto does)")
    if backend == "numpy" or overridden or (backend == "auto" and params.preset == "paper"):
        return None
    try:
        from . import ekf_kernels
    except ImportError:
        if backend == "numba":
            raise ImportError("homography_ekf: backend numba needs numba: pip install 'mata-eval[fast]'") from None
        return None
    missing = {f.name for f in dataclasses.fields(params)} - ekf_kernels.IMPLEMENTS
    if missing:
        if backend == "numba":
            raise ValueError(f"homography_ekf: backend numba does not implement {sorted(missing)} yet; use numpy")
        return None
    return ekf_kernels


@hookimpl
def mata_eval_estimators():
    return [HomographyEKF]
