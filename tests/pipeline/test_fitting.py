"""One recording fitted by one method (:mod:`magbench.pipeline.fitting`): preprocessing undone,
the robustness criterion, which methods can run."""

from __future__ import annotations

import numpy as np
import pytest

from magbench.core.geometry import coverage, sphere_fit
from magbench.core.metrics import real_cost
from magbench.core.model import Calibration
from magbench.pipeline.fitting import applicability, fit_recording, is_meaningful
from magbench.sources.recordings import Recording
from tests.studies.test_real import ellipsoid

OFFSET = np.array([3.0, -2.0, 1.5])                 # hard iron ~3 times the field radius


@pytest.mark.parametrize("how", ["none", "scale", "centre"])
def test_preprocessing_is_undone_in_the_estimate(how):
    y = ellipsoid(300, scale=700.0, offset=OFFSET)
    cal = fit_recording(Recording("x", y), "ellipsoid", how)
    assert real_cost(y, cal.T, cal.h) < 1e-10
    np.testing.assert_allclose(cal.h, 700.0 * OFFSET, rtol=1e-6)


def test_magical_needs_centring_when_the_offset_exceeds_the_radius():
    # The finding behind preprocessing 'centre': from y/||y|| MAG.I.C.AL runs to its cap.
    y = ellipsoid(300, scale=700.0, offset=OFFSET)
    scaled = fit_recording(Recording("x", y), "magical", "scale")
    assert not scaled.converged and real_cost(y, scaled.T, scaled.h) > 1e-3
    centred = fit_recording(Recording("x", y), "magical", "centre")
    assert centred.converged and real_cost(y, centred.T, centred.h) < 1e-10
    np.testing.assert_allclose(centred.h, 700.0 * OFFSET, rtol=1e-6)


def test_degenerate_answer_has_tiny_J_r_but_is_not_meaningful():
    y = ellipsoid(300, sigma=0.01)
    D = 1e4
    far = Calibration(D * np.eye(3), np.array([-D, 0.0, 0.0]))
    J_far = real_cost(y, far.T, far.h)
    c, r = sphere_fit(y)
    J_sphere = real_cost(y, r * np.eye(3), c)
    assert J_far < 1e-3 * J_sphere                 # eq. (81) alone would prefer it
    cov = coverage(far.apply(y))
    assert cov < 0.1
    assert not is_meaningful(True, J_far, J_sphere, cov, coverage(y - c))
    good = fit_recording(Recording("x", y), "magical")
    J_good = real_cost(y, good.T, good.h)
    assert is_meaningful(True, J_good, J_sphere, coverage(good.apply(y)), coverage(y - c))


def test_applicability_reasons():
    small = Recording("x", ellipsoid(6))
    assert "needs at least 10 samples, this fit has 6" in applicability("twostep", small)
    assert "needs gyroscope data" in applicability("sar_ls", Recording("x", ellipsoid(50)))
    assert applicability("sphere", small) == ""
