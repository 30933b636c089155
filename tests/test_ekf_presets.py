"""``preset: paper`` is block C exactly as it was before the improved default (outputs of the
old code on a fixed scenario, stored in tests/data by tests/ekf_reference_scenario.py)."""

from __future__ import annotations

import numpy as np
import pytest

from ekf_reference_scenario import CONFIGS, REFERENCE, run
from mata_eval_plugins.estimators.homography_ekf import PRESETS, HomographyEKF

P = HomographyEKF.Params


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_preset_paper_reproduces_the_old_filter(name):
    """Bit for bit when the reference was stored; since the faster Joseph block update of
    b8f6397 (same algebra, other product order) to rounding: 1e-12 relative (measured 3e-13 px
    on the boxes, 5e-11 relative on one covariance entry of ``after``)."""
    ref = np.load(REFERENCE)
    boxes, covs = run(HomographyEKF(P(preset="paper", **CONFIGS[name])))
    np.testing.assert_allclose(boxes, ref[f"{name}_boxes"], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(covs, ref[f"{name}_covs"], rtol=1e-9, atol=1e-15)


def test_the_default_preset_is_not_the_paper_and_yaml_overrides_a_preset_value():
    assert P().resolved().delay == "compensate"
    assert P(preset="paper").resolved().delay == "ignore"
    assert P(preset="paper", delay="compensate").resolved().delay == "compensate"
    boxes, _ = run(HomographyEKF(P()))
    assert not np.array_equal(boxes, np.load(REFERENCE)["ignore_boxes"])
    assert set(PRESETS["paper"]) == set(PRESETS["mata"])
