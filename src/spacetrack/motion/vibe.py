"""ViBe background subtraction (Barnich and Van Droogenbroeck), vectorised over the whole frame.

ViBe is patented (its authors hold patents on the method); check the licence terms before using it in a
product. Each pixel keeps `num_samples` past values. A pixel is background when at least `min_matches`
samples lie within `radius` of it (eq. 2; Euclidean distance in RGB for colour input). Background pixels
replace one random sample of their own model with probability 1/`subsampling`, and, with the same
probability, one random sample of a random 8-neighbour's model (spatial propagation, which lets ghosts
dissolve into the background from their borders). Foreground pixels do not update (conservative,
memoryless update: eqs. 3-4) until they have been foreground for `absorb_after` frames in a row: then they
update too, each with probability 1/`absorb_subsampling`, so a target that stopped becomes background (the
paper's threshold T). Absorbing faster than the background updates (`absorb_subsampling` < `subsampling`)
also clears the ghosts that a target present in the first frame leaves behind within a few frames of T. The
model starts from the first frame: each sample is the value of a random pixel in the 3x3 neighbourhood,
so the first frame already has a mask (latency 0).

Two deliberate changes. The first `min_matches` samples are the pixel's own value: otherwise a star one
pixel wide, whose neighbours are black, starts as foreground and stays so (foreground never updates).
And the update is vectorised: which pixels update is drawn per pixel (a slice at a random offset of a
fixed random table, as in the reference implementation), but the sample to replace and the neighbour's
direction are drawn once per frame for all of them. Each pixel still sees a uniformly random sample and
direction from frame to frame, which is all its memoryless update needs (eqs. 3-4), and an update is then
two masked copies instead of thousands of scattered writes.
"""

from __future__ import annotations

import cv2
import numpy as np

from spacetrack.motion.compensation import scene_shift_for, shift_image
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
            their model from the current frame. True, false, or "auto" (once the scene is found to move).
        match_exposure: scale each grey frame to the first frame's mean grey level before comparing, so
            an exposure step is not foreground (grey models only).
        absorb_after: frames a pixel must stay foreground before it updates too (1-255); 0 never (pure
            conservative update).
        absorb_subsampling: such a pixel updates with probability 1/absorb_subsampling (1: every frame, so
            it is background about `min_matches` frames after `absorb_after`).
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
        compensate: bool | str = False,
        match_exposure: bool = False,
        absorb_after: int = 60,
        absorb_subsampling: int | None = None,
        seed: int = 0,
    ) -> None:
        if not 1 <= min_matches <= num_samples:
            raise ValueError(f"min_matches must lie in 1..num_samples={num_samples}, got {min_matches}")
        absorb_subsampling = subsampling if absorb_subsampling is None else absorb_subsampling
        if min(subsampling, absorb_subsampling) < 1 or radius <= 0:
            raise ValueError(
                f"subsampling and absorb_subsampling must be >= 1 and radius > 0, got {subsampling}, "
                f"{absorb_subsampling} and {radius}"
            )
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
        self.absorb_subsampling = absorb_subsampling
        self.seed = seed
        self._guard = FrameGuard()
        self.scene_shift = scene_shift_for(compensate)  # may be replaced by a shared one (the fusion)
        self.reset()

    def reset(self) -> None:
        self._guard.reset()
        self.scene_shift.reset()
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
        grey = raw = to_grey(frame)  # the scene shift is measured on the raw frame, as a sharer does
        if self.match_exposure and not self.colour:
            if self._model is None:
                self._level = cv2.mean(grey)[0]
            grey = match_exposure(grey, self._level)
        image = frame if self.colour and frame.ndim == 3 and frame.shape[2] == 3 else grey
        offset = (0, 0)
        if self.compensate:
            offset = tuple(round(v) for v in self.scene_shift.update(raw, self._guard.count - 1))
        if self._model is None:
            self._initialise(image)
            self._foreground_run = np.zeros(grey.shape, np.uint8)
            self._offset = offset  # the first frame's: (0, 0)
            return np.zeros(grey.shape, np.uint8)
        if self.compensate:
            dx, dy = offset[0] - self._offset[0], offset[1] - self._offset[1]
            self._model = shift_image(self._model, dx, dy, image, axis=1)
            self._foreground_run = shift_image(self._foreground_run, dx, dy, 0)
            self._offset = offset
        foreground = self._foreground(image)
        absorbed = None
        if self.absorb_after > 0:
            self._foreground_run = cv2.bitwise_and(cv2.add(self._foreground_run, 1), foreground)
            absorbed = cv2.compare(self._foreground_run, self.absorb_after, cv2.CMP_GE)
        self._update(image, cv2.bitwise_not(foreground), absorbed)
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
        # 255 with probability 1/subsampling; twice the frame size, read at a random offset each frame.
        self._hits = np.where(self._rng.random(2 * n) < 1.0 / self.subsampling, 255, 0).astype(np.uint8)
        if self.absorb_subsampling == self.subsampling:
            self._absorb_hits = self._hits
        else:
            chance = 1.0 / self.absorb_subsampling
            self._absorb_hits = np.where(self._rng.random(2 * n) < chance, 255, 0).astype(np.uint8)

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
        open_ = np.flatnonzero(count < self.min_matches)  # bool input: many times faster than uint8
        if first < self.num_samples and len(open_):
            n = count.size
            rest = self._model[first:].reshape(self.num_samples - first, n, -1)[:, open_]
            values = image.reshape(n, -1)[open_]
            if rest.shape[2] == 1:  # grey: uint8 distances, no squares
                near = (
                    cv2.absdiff(rest[..., 0], np.broadcast_to(values[:, 0], rest.shape[:2]).copy())
                    < self.radius
                )
            else:
                dist2 = ((rest.astype(np.int32) - values.astype(np.int32)) ** 2).sum(axis=2)
                near = dist2 < self.radius**2
            matches = count.reshape(n)[open_] + np.count_nonzero(near, axis=0)
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

    def _drawn(self, candidates: np.ndarray, hits: np.ndarray) -> np.ndarray:
        """(H, W) uint8 mask: the pixels of `candidates` (0/255) where the random table `hits` (read at a
        random offset) is set, i.e. each drawn with that table's probability."""
        n = candidates.size
        start = int(self._rng.integers(0, n))
        return cv2.bitwise_and(candidates, hits[start : start + n].reshape(candidates.shape))

    def _draw(self, background: np.ndarray, absorbed: np.ndarray | None) -> np.ndarray:
        """The pixels that update this time: background ones with probability 1/subsampling, absorbed
        foreground ones with probability 1/absorb_subsampling (uint8 (H, W) masks, 255 = set)."""
        drawn = self._drawn(background, self._hits)
        if absorbed is not None:
            drawn = cv2.bitwise_or(drawn, self._drawn(absorbed, self._absorb_hits))
        return drawn

    def _update(self, image: np.ndarray, background: np.ndarray, absorbed: np.ndarray | None) -> None:
        """Random conservative update (uint8 (H, W) masks, 255 = may update; see `_draw`).

        Drawn pixels copy their value into one sample of their own model, other drawn pixels into one
        sample of their neighbour's model in one direction; sample and direction are random per frame.
        """
        own = self._model[int(self._rng.integers(0, self.num_samples))]
        cv2.copyTo(image, self._draw(background, absorbed), own)  # writes into `own` in place
        dy, dx = (int(v) for v in _NEIGHBOURS[int(self._rng.integers(0, 8))])
        # moving the values and the mask by (dx, dy) lands pixel (y, x) on its neighbour (y + dy, x + dx)
        moved = shift_image(image, dx, dy, 0)
        drawn = shift_image(self._draw(background, absorbed), dx, dy, 0)
        cv2.copyTo(moved, drawn, self._model[int(self._rng.integers(0, self.num_samples))])
