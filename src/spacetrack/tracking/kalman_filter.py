"""Constant-velocity Kalman filter on boxes in `xyah` (centre x, centre y, aspect w/h, height; pixels).

The state is (x, y, a, h, vx, vy, va, vh) (paper eq. 5). Process and measurement noise scale with the
box height as in the reference DeepSORT (position 1/20, velocity 1/160 of the height), so big and small
targets get the same relative uncertainty. Every method works on a single track (mean (8,), covariance
(8, 8)) or on a stack of tracks (mean (T, 8), covariance (T, 8, 8)) so the tracker can predict and gate
all tracks in one call.
"""

from __future__ import annotations

import numpy as np

# 0.95 quantile of the chi-square distribution with 4 degrees of freedom: eq. (12)'s gate t(1).
CHI2_95_4DOF = 9.4877

_NDIM = 4  # the filter observes (x, y, a, h) directly: H = [I 0], applied by slicing the state
_MOTION = np.eye(2 * _NDIM) + np.eye(2 * _NDIM, k=_NDIM)  # F of eq. (5) with dt = 1 frame
_STD_POSITION = 1.0 / 20
_STD_VELOCITY = 1.0 / 160


def _diag(std: np.ndarray) -> np.ndarray:
    """(..., n) standard deviations -> (..., n, n) diagonal covariances."""
    n = std.shape[-1]
    out = np.zeros(std.shape + (n,))
    idx = np.arange(n)
    out[..., idx, idx] = std**2
    return out


def _position_std(h: np.ndarray, aspect_std: float) -> np.ndarray:
    h = np.asarray(h, dtype=float)
    return np.stack(
        [_STD_POSITION * h, _STD_POSITION * h, np.full_like(h, aspect_std), _STD_POSITION * h], -1
    )


def _velocity_std(h: np.ndarray) -> np.ndarray:
    h = np.asarray(h, dtype=float)
    return np.stack([_STD_VELOCITY * h, _STD_VELOCITY * h, np.full_like(h, 1e-5), _STD_VELOCITY * h], -1)


class KalmanFilter:
    """Eqs. (5)-(11): initiate from one `xyah` measurement, predict one frame ahead, update, gate."""

    def initiate(self, measurement: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean (8,) and covariance (8, 8) of a new track at `measurement` (`xyah`), velocities zero."""
        measurement = np.asarray(measurement, dtype=float)
        mean = np.concatenate([measurement, np.zeros(_NDIM)])
        p, v = 2 * _STD_POSITION * measurement[3], 10 * _STD_VELOCITY * measurement[3]
        # Twice (position) and ten times (velocity) the process noise; the aspect ratio's stays fixed.
        std = np.array([p, p, 1e-2, p, v, v, 1e-5, v])
        return mean, _diag(std)

    def predict(self, mean: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Eqs. (5)-(6): the state one frame later. Shapes (..., 8) and (..., 8, 8)."""
        h = mean[..., 3]
        q = _diag(np.concatenate([_position_std(h, 1e-2), _velocity_std(h)], -1))
        return mean @ _MOTION.T, _MOTION @ covariance @ _MOTION.T + q

    def project(self, mean: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The state in measurement space (`xyah`) with the detector noise R added: (..., 4), (..., 4, 4)."""
        r = _diag(_position_std(mean[..., 3], 1e-1))
        return mean[..., :_NDIM], covariance[..., :_NDIM, :_NDIM] + r

    def update(
        self, mean: np.ndarray, covariance: np.ndarray, measurement: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Eqs. (7)-(10): correct the predicted state with `measurement` (`xyah`). Shapes as `predict`."""
        projected_mean, projected_cov = self.project(mean, covariance)
        # K = P H^T S^-1, solved rather than inverted; S is symmetric so K^T = S^-1 (H P).
        cross = covariance[..., :_NDIM, :]  # H P
        gain = np.swapaxes(np.linalg.solve(projected_cov, cross), -1, -2)
        innovation = np.asarray(measurement, dtype=float) - projected_mean
        new_mean = mean + (gain @ innovation[..., None])[..., 0]
        new_cov = covariance - gain @ projected_cov @ np.swapaxes(gain, -1, -2)
        return new_mean, new_cov

    def gating_distance(
        self, mean: np.ndarray, covariance: np.ndarray, measurements: np.ndarray, only_position: bool = False
    ) -> np.ndarray:
        """Eq. (11): squared Mahalanobis distances of `measurements` (M, 4) `xyah` to each track.

        `mean` (T, 8) and `covariance` (T, 8, 8) give a (T, M) matrix; a single track gives (M,).
        only_position: over the box centre (x, y) alone (2 degrees of freedom instead of 4).
        """
        projected_mean, projected_cov = self.project(mean, covariance)
        measurements = np.asarray(measurements, dtype=float).reshape(-1, _NDIM)
        if only_position:
            projected_mean, projected_cov = projected_mean[..., :2], projected_cov[..., :2, :2]
            measurements = measurements[:, :2]
        chol = np.linalg.cholesky(projected_cov)
        diff = measurements - projected_mean[..., None, :]  # (..., M, 4)
        z = np.linalg.solve(chol, np.swapaxes(diff, -1, -2))  # L z = d, so |z|^2 = d^T S^-1 d
        return np.sum(z * z, axis=-2)
