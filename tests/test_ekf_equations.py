"""The pose EKF's own predict and update (runtime/localization/ekf.py, written out so a robot does not install
filterpy and with it matplotlib) are filterpy's ExtendedKalmanFilter's, number for number."""
from __future__ import annotations

import numpy as np
import pytest
from filterpy import kalman                # the [test] extra's, for this comparison only

from runtime.localization.ekf import _UnicycleEKF
from runtime.localization.enu import wrap_angle


def _random_spd(rng, n):
    a = rng.normal(size=(n, n))
    return a @ a.T + n * np.eye(n)


@pytest.mark.parametrize("known", [True, False])
def test_predict_and_update_match_filterpy(known):
    class Reference(kalman.ExtendedKalmanFilter):
        predict_x = _UnicycleEKF.predict_x

    rng = np.random.default_rng(3)
    ours, ref = _UnicycleEKF(dim_x=5, dim_z=2), Reference(dim_x=5, dim_z=2)
    x0, P0 = rng.normal(size=5), _random_spd(rng, 5)
    for f in (ours, ref):
        f.x, f.P = x0.copy(), P0.copy()
    H2 = np.array([[1.0, 0, 0, 0, 0], [0, 1.0, 0, 0, 0]])
    H1 = np.array([[0, 0, 1.0, 0, 0]])
    for step in range(20):
        F, Q = np.eye(5) + 0.1 * rng.normal(size=(5, 5)), 0.01 * _random_spd(rng, 5)
        for f in (ours, ref):
            f.F, f.Q = F, Q
            f.predict(u=(0.05, known))
        z, R = rng.normal(size=2), _random_spd(rng, 2)
        for f in (ours, ref):
            f.update(z, lambda s: H2, lambda s: H2 @ s, R=R)
        h = np.array([rng.uniform(-3, 3)])
        for f in (ours, ref):
            f.update(h, lambda s: H1, lambda s: H1 @ s, R=np.array([[0.04]]),
                     residual=lambda a, b: np.array([wrap_angle(float(a[0] - b[0]))]))
        np.testing.assert_array_equal(ours.x, ref.x)          # bit for bit: runs must not change
        np.testing.assert_array_equal(ours.P, ref.P)
