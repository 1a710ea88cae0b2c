"""ViBe background subtraction (Barnich and Van Droogenbroeck), vectorised over the whole frame.

ViBe is patented (its authors hold patents on the method); check the licence terms before using it in a
product. Each pixel keeps `num_samples` past values. A pixel is background when at least `min_matches`
samples lie within `radius` of it (eq. 2; Euclidean distance in RGB for colour input). Background pixels
replace one random sample of their own model with probability 1/`subsampling`, and, with the same
probability, one random sample of a random 8-neighbour's model (spatial propagation, which lets ghosts
dissolve into the background from their borders). Foreground pixels do not update (conservative,
memoryless update: eqs. 3-4) until they have been foreground for `absorb_after` frames in a row: then they
update like background, so a target that stopped becomes background (the paper's threshold T). The model starts from the first frame: each sample is the
value of a random pixel in the 3x3 neighbourhood, so the first frame already has a mask (latency 0).
One deliberate change: the first `min_matches` samples are the pixel's own value. Otherwise a star one
pixel wide, whose neighbours are black, starts as foreground and stays so (foreground never updates).

The per-pixel random draws are slices at random offsets of fixed random tables (as in the reference
implementation), so a frame costs no fresh random numbers per pixel.
"""

from __future__ import annotations

import cv2
import numpy as np

from spacetrack.motion.compensation import SceneShift, shift_image
from spacetrack.motion.frames import FrameGuard, match_exposure, to_grey

# The 8-neighbourhood as (dy, dx).
_NEIGHBOURS = np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)])


class ViBe:
    """Streaming ViBe detector (latency 0).

    Args:
        num_samples: samples per pixel (N, paper: 20).
        radius: match distance R in grey levels (paper: 20).
        min_matches: matching samples needed to be background (#min, paper: 2).
        subsampling: an update happens with probability 1/subsampling (paper: 16).
        colour: model RGB triples (Euclidean distance) instead of grey values.
        compensate: move the model with the camera (see `compensation`); pixels entering the view restart
            their model from the current frame.
        match_exposure: scale each grey frame to the first frame's mean grey level before comparing, so
            an exposure step is not foreground (grey models only).
        absorb_after: frames a pixel must stay foreground before it updates like background (1-255);
            0 never (pure conservative update).
        seed: seed of the random tables; reset() restores it, so a rerun gives the same masks.
    """

    latency = 0

    def __init__(
        self,
        *,
        num_samples: int = 20,
        radius: float = 20.0,
        min_matches: int = 2,
        subsampling: int = 16,
        colour: bool = False,
        compensate: bool = False,
        match_exposure: bool = False,
        absorb_after: int = 60,
        seed: int = 0,
    ) -> None:
        if not 1 <= min_matches <= num_samples:
            raise ValueError(f"min_matches must lie in 1..num_samples={num_samples}, got {min_matches}")
        if subsampling < 1 or radius <= 0:
            raise ValueError(f"subsampling must be >= 1 and radius > 0, got {subsampling} and {radius}")
        if not 0 <= absorb_after <= 255:
            raise ValueError(f"absorb_after must lie in 0..255 frames, got {absorb_after}")
        self.num_samples = num_samples
        self.radius = radius
        self.min_matches = min_matches
        self.subsampling = subsampling
        self.colour = colour
        self.compensate = compensate
        self.match_exposure = match_exposure
        self.absorb_after = absorb_after
        self.seed = seed
        self._guard = FrameGuard()
        self._shift = SceneShift()
        self.reset()

    def reset(self) -> None:
        self._guard.reset()
        self._shift.reset()
        self._rng = np.random.default_rng(self.seed)
        self._model: np.ndarray | None = None  # (N, H, W) grey or (N, H, W, 3) colour samples
        self._offset = (0, 0)
        self._level = 0.0  # the first frame's mean grey level
        self._foreground_run: np.ndarray | None = None  # (H, W) uint8 frames in a row as foreground, capped

    @property
    def mask_index(self) -> int:
        return self._guard.count - 1

    def apply(self, frame: np.ndarray) -> np.ndarray | None:
        frame = self._guard.check(frame)
        grey = to_grey(frame)
        if self.match_exposure and not self.colour:
            if self._model is None:
                self._level = cv2.mean(grey)[0]
            grey = match_exposure(grey, self._level)
        image = frame if self.colour and frame.ndim == 3 and frame.shape[2] == 3 else grey
        if self._model is None:
            self._initialise(image)
            self._foreground_run = np.zeros(grey.shape, np.uint8)
            self._offset = self._shift.update(grey) if self.compensate else (0, 0)
            return np.zeros(grey.shape, np.uint8)
        if self.compensate:
            offset = self._shift.update(grey)
            dx, dy = offset[0] - self._offset[0], offset[1] - self._offset[1]
            self._model = shift_image(self._model, dx, dy, image, axis=1)
            self._foreground_run = shift_image(self._foreground_run, dx, dy, 0)
            self._offset = offset
        foreground = self._foreground(image)
        updating = foreground == 0
        if self.absorb_after > 0:
            self._foreground_run = cv2.bitwise_and(cv2.add(self._foreground_run, 1), foreground)
            updating |= self._foreground_run >= self.absorb_after
        self._update(image, updating)
        return foreground

    def _initialise(self, image: np.ndarray) -> None:
        h, w = image.shape[:2]
        self._tables(h * w)
        padded = cv2.copyMakeBorder(image, 1, 1, 1, 1, cv2.BORDER_REFLECT_101)
        if padded.ndim < image.ndim:  # copyMakeBorder drops a trailing channel axis of 1
            padded = padded[..., None]
        rows, cols = np.mgrid[1 : h + 1, 1 : w + 1]
        samples = [image] * self.min_matches
        for _ in range(self.num_samples - self.min_matches):
            dy, dx = _NEIGHBOURS[self._rng.integers(0, 8, (h, w))].transpose(2, 0, 1)
            samples.append(padded[rows + dy, cols + dx])
        self._model = np.stack(samples)

    def _tables(self, n: int) -> None:
        # Twice the frame size, read from a random offset below n each frame.
        size = 2 * n
        self._hit_positions = np.flatnonzero(self._rng.random(size) < 1.0 / self.subsampling)
        self._sample_draw = self._rng.integers(0, self.num_samples, size)
        self._direction_draw = self._rng.integers(0, 8, size)

    def _foreground(self, image: np.ndarray) -> np.ndarray:
        """(H, W) uint8 mask, 255 where fewer than `min_matches` samples lie within `radius` of the pixel.

        Two passes, same answer as counting all samples: the first few samples are compared over the whole
        frame, which settles most background pixels; only the pixels still short of matches are compared
        with the remaining samples.
        """
        first = min(self.num_samples, self.min_matches + 2)
        count = np.zeros(image.shape[:2], np.uint8)
        for sample in self._model[:first]:
            cv2.add(count, self._near(sample, image), count)
        foreground = cv2.compare(count, self.min_matches, cv2.CMP_LT)
        open_ = np.flatnonzero(foreground)
        if first < self.num_samples and len(open_):
            n = count.size
            values = image.reshape(n, -1)[open_].astype(np.int32)
            rest = self._model[first:].reshape(self.num_samples - first, n, -1)[:, open_].astype(np.int32)
            dist2 = ((rest - values) ** 2).sum(axis=2)
            matches = count.reshape(n)[open_] + (dist2 < self.radius**2).sum(axis=0)
            foreground.reshape(n)[open_[matches >= self.min_matches]] = 0
        return foreground

    def _near(self, sample: np.ndarray, image: np.ndarray) -> np.ndarray:
        """(H, W) uint8, 1 where `sample` lies within `radius` of `image` (strictly), else 0."""
        diff = cv2.absdiff(sample, image)
        if diff.ndim == 3:
            sq = cv2.multiply(diff, diff, dtype=cv2.CV_32F).sum(axis=2)
            return (sq < self.radius**2).astype(np.uint8)
        _, near = cv2.threshold(diff, int(np.ceil(self.radius)) - 1, 1, cv2.THRESH_BINARY_INV)
        return near

    def _chosen(self, n: int) -> np.ndarray:
        """Sorted flat indices of the pixels drawn, each with probability 1/subsampling."""
        start = int(self._rng.integers(0, n))
        lo, hi = np.searchsorted(self._hit_positions, [start, start + n])
        return self._hit_positions[lo:hi] - start

    def _pick(self, table: np.ndarray, pixels: np.ndarray) -> np.ndarray:
        """One random draw from `table` per pixel in `pixels`."""
        return table[int(self._rng.integers(0, len(table) // 2)) + pixels]

    def _update(self, image: np.ndarray, updating: np.ndarray) -> None:
        """Conservative random update of the pixels marked in `updating` (bool (H, W)) and their neighbours."""
        h, w = updating.shape
        n = h * w
        channels = image.shape[2:]
        flat_model = self._model.reshape(self.num_samples * n, *channels)
        flat_image = image.reshape(n, *channels)
        may_update = updating.reshape(n)
        own = self._chosen(n)
        own = own[may_update[own]]
        flat_model[self._pick(self._sample_draw, own) * n + own] = flat_image[own]
        src = self._chosen(n)
        src = src[may_update[src]]
        dy, dx = _NEIGHBOURS[self._pick(self._direction_draw, src)].T
        target = np.clip(src // w + dy, 0, h - 1) * w + np.clip(src % w + dx, 0, w - 1)
        flat_model[self._pick(self._sample_draw, src) * n + target] = flat_image[src]
