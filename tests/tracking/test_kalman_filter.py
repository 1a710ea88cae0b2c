import numpy as np
from scipy.stats import chi2

from spacetrack.tracking.kalman_filter import CHI2_95_4DOF, KalmanFilter


def test_gate_is_the_chi_square_95_quantile_with_4_dof():
    assert np.round(chi2.ppf(0.95, 4), 4) == CHI2_95_4DOF


def test_initiate_and_predict_follow_eqs_5_6_with_height_scaled_noise():
    kf = KalmanFilter()
    mean, cov = kf.initiate(np.array([100.0, 50.0, 0.5, 40.0]))
    np.testing.assert_allclose(mean, [100, 50, 0.5, 40, 0, 0, 0, 0])
    # position std 2 * h / 20 = 4 px, velocity std 10 * h / 160 = 2.5 px/frame
    # aspect ratio: std 1e-2, its rate 1e-5 (fixed, not height-scaled)
    np.testing.assert_allclose(np.diag(cov), [16, 16, 1e-4, 16, 6.25, 6.25, 1e-10, 6.25])

    mean[4:6] = [3.0, -1.0]
    new_mean, new_cov = kf.predict(mean, cov)
    np.testing.assert_allclose(new_mean[:2], [103.0, 49.0])  # x' = F x with dt = 1
    F = np.eye(8) + np.eye(8, k=4)
    q = np.diag(np.square([2.0, 2.0, 1e-2, 2.0, 0.25, 0.25, 1e-5, 0.25]))  # h / 20, h / 160
    np.testing.assert_allclose(new_cov, F @ cov @ F.T + q)


def test_update_moves_towards_the_measurement_and_shrinks_uncertainty():
    kf = KalmanFilter()
    mean, cov = kf.predict(*kf.initiate(np.array([100.0, 50.0, 0.5, 40.0])))
    new_mean, new_cov = kf.update(mean, cov, np.array([110.0, 50.0, 0.5, 40.0]))
    assert 100 < new_mean[0] < 110
    assert new_cov[0, 0] < cov[0, 0]
    # eqs. (8)-(10) written out with an explicit inverse
    H = np.eye(4, 8)
    R = np.diag(np.square([2.0, 2.0, 1e-1, 2.0]))
    K = cov @ H.T @ np.linalg.inv(H @ cov @ H.T + R)
    np.testing.assert_allclose(new_mean, mean + K @ (np.array([110.0, 50, 0.5, 40]) - H @ mean))
    np.testing.assert_allclose(new_cov, (np.eye(8) - K @ H) @ cov, atol=1e-9)


def test_gating_distance_is_the_squared_mahalanobis_distance_and_batches():
    kf = KalmanFilter()
    rng = np.random.default_rng(1)
    states = [kf.predict(*kf.initiate(np.array([x, 60.0, 0.4, h]))) for x, h in [(10, 30), (200, 80)]]
    measurements = rng.normal([100, 60, 0.4, 50], [50, 10, 0.05, 10], size=(5, 4))
    means = np.stack([m for m, _ in states])
    covs = np.stack([c for _, c in states])
    batched = kf.gating_distance(means, covs, measurements)
    assert batched.shape == (2, 5)
    for row, (mean, cov) in enumerate(states):
        proj_mean, proj_cov = kf.project(mean, cov)
        d = measurements - proj_mean
        expected = np.einsum("mi,ij,mj->m", d, np.linalg.inv(proj_cov), d)
        np.testing.assert_allclose(batched[row], expected)
        np.testing.assert_allclose(kf.gating_distance(mean, cov, measurements), expected)
