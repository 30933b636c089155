"""What determines a synthetic sequence: :class:`SequenceSpec`, drawn from a seed by
:func:`make_spec`, and the default suite of :func:`suite_specs` (one scenario per difficulty)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

import numpy as np

#: Scenario cycle of the default suite: every suite covers each kind of difficulty.
SCENARIOS = ("cruise", "manoeuvre", "outofview", "occlusion", "crowd")

REF_WIDTH = 1280.0  # geometry, speeds and attribute thresholds scale with width / 1280
GENERATOR_VERSION = 7  # bump when the pixels a seed gives change (cache key of the suite)
# 7: a 0.75 px handheld shake (was 1 px: UAV123 jitters less from frame to frame, on its whole-pixel grid); 6: the operator zooms in spells (80 % of the time); 5: the operators' pace, pans and zoom rate spread evenly over a suite; 4: the uav123 camera; 3: legacy.

#: Camera models (:mod:`.motion`): ``uav123``, image-plane motion matched to UAV123 (the
#: default since generator version 4; in version 5 spread evenly over a suite); ``legacy``,
#: version 3's tight pursuit, pixel for pixel.
MOTIONS = ("uav123", "legacy")


@dataclass(frozen=True)
class SequenceSpec:
    """Everything that determines a synthetic sequence; the same spec gives the same pixels."""

    name: str
    seed: int
    n_frames: int = 300
    width: int = 1280
    height: int = 720
    fps: float = 30.0
    texture_seed: int = 0
    target: Literal["vehicle", "person"] = "vehicle"
    n_distractors: int = 0
    manoeuvres: int = 0          # sudden pans / yaw jerks / zoom jumps
    out_of_view: bool = False    # the camera looks away until the target has left the image
    occlusion: Literal["none", "partial", "full"] = "none"  # a tree canopy on the target's path
    illumination: bool = False   # a cloud shadow darkens the scene for a while
    camouflage: bool = False     # the target takes the colour of the ground where it starts
    draw_target: bool = True     # False renders the same scene without the target (tests)
    motion: Literal["uav123", "legacy"] = "uav123"  # camera model, one of MOTIONS
    pace: float = 0.5            # quantile in (0, 1) of the camera operator's pace (uav123 only)
    pans: float = 0.5            # quantile in (0, 1) of their number of re-framing pans (uav123 only)
    zooming: float = 0.5         # quantile in (0, 1) of how fast they zoom (uav123 only)

    def __post_init__(self) -> None:
        if self.n_frames < 2:
            raise ValueError(f"SequenceSpec {self.name!r}: n_frames must be >= 2, got {self.n_frames}")
        if self.width < 32 or self.height < 24:
            raise ValueError(f"SequenceSpec {self.name!r}: image size must be at least 32x24, "
                             f"got {self.width}x{self.height}")
        for q in ("pace", "pans", "zooming"):
            if not 0.0 < getattr(self, q) < 1.0:
                raise ValueError(f"SequenceSpec {self.name!r}: {q} is a quantile in (0, 1), got {getattr(self, q)}")
        if self.motion not in MOTIONS:
            raise ValueError(f"SequenceSpec {self.name!r}: motion must be one of {', '.join(MOTIONS)}, "
                             f"got {self.motion!r}")


def derive_seed(*key: int) -> int:
    """A 32-bit seed derived from a key of integers (independent streams per purpose)."""
    return int(np.random.SeedSequence([int(k) & 0xFFFFFFFF for k in key]).generate_state(1)[0])


def make_spec(seed: int, n_frames: int = 300, width: int = 1280, height: int = 720, *,
              name: str | None = None, scenario: str | None = None, texture_seed: int | None = None,
              fps: float = 30.0, motion: str = "uav123", quantiles: tuple[float, float, float] | None = None) -> SequenceSpec:
    """A random sequence spec for ``seed``; ``scenario`` (one of :data:`SCENARIOS`) picks which
    difficulties it stages, ``quantiles`` the ``(pace, pans, zooming)`` of the camera operator (see
    :class:`SequenceSpec`), the rest is drawn from the seed."""
    rng = np.random.default_rng(derive_seed(seed, 1))
    scenario = scenario if scenario is not None else SCENARIOS[int(rng.integers(len(SCENARIOS)))]
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; expected one of {', '.join(SCENARIOS)}")
    target = "person" if (scenario == "crowd" or rng.random() < 0.3) else "vehicle"
    spec = dict(
        target=target,
        n_distractors=int(rng.integers(2, 4)) if scenario == "crowd" else int(rng.random() < 0.3),
        manoeuvres=int(rng.integers(1, 3)) if scenario == "manoeuvre" else int(rng.random() < 0.2),
        out_of_view=scenario == "outofview",
        occlusion=("full" if rng.random() < 0.6 else "partial") if scenario == "occlusion" else "none",
        illumination=scenario == "crowd" or bool(rng.random() < 0.15),
    )
    spec["camouflage"] = scenario in ("cruise", "crowd") and bool(rng.random() < 0.4)
    spec["pace"], spec["pans"], spec["zooming"] = quantiles if quantiles is not None else (
        np.random.default_rng(derive_seed(seed, 8)).uniform(1e-6, 1 - 1e-6, 3))
    return SequenceSpec(name=name or f"syn{seed % 100000:05d}_{scenario}", seed=int(seed), n_frames=n_frames,
                        width=width, height=height, fps=fps, motion=motion,
                        texture_seed=int(texture_seed if texture_seed is not None else derive_seed(seed, 2)), **spec)


#: Steps of the suite's low-discrepancy quantiles (:func:`spread_quantiles`), one per quantile.
#: Searched so that every prefix of up to 60 sequences and every scenario's share of it (every
#: 5th sequence) is evenly spread (N x discrepancy <= 2.5 for each step); the first is
#: (3 + 1/phi) / 5, whose multiples of 5 step by the golden ratio.
SPREAD_STEPS = (0.7236068, 0.63, 0.37)


def spread_quantiles(seed: int, i: int) -> tuple[float, float, float]:
    """The ``(pace, pans, zooming)`` quantiles of sequence ``i`` of a suite: an additive-recurrence
    (Kronecker) low-discrepancy sequence ``frac(shift + i * step)`` with a random shift drawn
    from ``seed``. Any first N sequences of a suite then cover the operators' laws evenly, from
    calm to busy, instead of a random draw of them, and so does each scenario's share; sequence
    ``i`` still depends only on ``(seed, i)``."""
    shift = np.random.default_rng(derive_seed(seed, 300)).random(len(SPREAD_STEPS))
    u = (shift + i * np.asarray(SPREAD_STEPS)) % 1.0
    return tuple(float(x) for x in np.clip(u, 1e-6, 1 - 1e-6))


def suite_name(i: int) -> str:
    """The name of sequence ``i`` (from 0) of a suite: ``syn<i+1>_<scenario>``."""
    return f"syn{i + 1:03d}_{SCENARIOS[i % len(SCENARIOS)]}"


def suite_specs(n_sequences: int = 20, n_frames: int = 300, width: int = 1280, height: int = 720,
                seed: int = 0, n_textures: int = 4, motion: str = "uav123") -> list[SequenceSpec]:
    """The default suite: sequence ``i`` is named ``syn<i+1>_<scenario>``, stages the scenario
    ``SCENARIOS[i % 5]`` and depends only on ``(seed, i)`` (not on ``n_sequences``); ground
    textures are shared by groups of sequences (``n_textures`` different grounds); ``motion``
    is the camera model of every sequence (:data:`MOTIONS`); the operators' pace, number of
    pans and zoom rate are spread evenly over the suite (:func:`spread_quantiles`)."""
    if n_sequences < 1:
        raise ValueError(f"n_sequences must be >= 1, got {n_sequences}")
    specs = []
    for i in range(n_sequences):
        sp = make_spec(derive_seed(seed, 100, i), n_frames, width, height,
                       name=suite_name(i),
                       scenario=SCENARIOS[i % len(SCENARIOS)],
                       texture_seed=derive_seed(seed, 200, i % max(1, n_textures)), motion=motion,
                       quantiles=spread_quantiles(seed, i))
        if sp.occlusion != "none":  # alternate full and partial occlusions through the suite
            sp = dataclasses.replace(sp, occlusion="full" if (i // len(SCENARIOS)) % 2 == 0 else "partial")
        specs.append(sp)
    return specs

