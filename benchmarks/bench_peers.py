"""Time BoxMOT's trackers against our DeepSORT, in milliseconds per frame, on the same detections.

Contenders, timed in the same run, round-robin (one whole sequence of each per round, so a change of
load hits all alike):
- `deepsort`: `spacetrack.tracking.DeepSort` with `conf/tracker/deepsort_original.yaml` (the paper's
  "original" settings, camera shift on `auto`);
- the peers of `spacetrack.tracking.peers` (`make peers` installs BoxMOT), each with BoxMOT's defaults:
  ByteTrack, OC-SORT, BoT-SORT (its camera-motion compensation on each frame), StrongSORT, Deep OC-SORT.
  The last three take our re-ID features; none builds a network.

Each synthetic sequence is a dark 640x480 sky with textured stars and `--targets` bright targets moving at
constant velocity; the detections are their boxes with 1 px noise, 10% missed, a 128-D feature around a
per-target mean. Every contender gets the frame only if it uses it (`needs_images`). The time is that of
`step` over the sequence, tracker construction included, divided by the frames: wall clock and CPU time
(this process, less sensitive to other processes' load), medians over `--repeats` rounds. The report
also gives each contender's MOTA and HOTA on the synthetic ground truth, as a sanity check.

    python benchmarks/bench_peers.py [--frames 60] [--repeats 5] [--targets 5 20]
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np
from hydra.utils import instantiate
from threadpoolctl import threadpool_limits

from common import interleaved_samples, markdown_table, progress, summarize, write_report
from spacetrack.config import compose_config
from spacetrack.evaluation import evaluate
from spacetrack.track_detections import rows_as_mot
from spacetrack.tracking.peers import BOXMOT_VERSION, PEERS, load_boxmot

FEATURE_DIM = 128
MISS_RATE = 0.1
SIZE = (640, 480)


def synthetic_sequence(num_targets: int, num_frames: int, seed: int = 0) -> tuple[list[tuple], np.ndarray]:
    """([(tlwh, confidence, feature, image)] per frame, MOT ground truth (N, 9))."""
    rng = np.random.default_rng(seed)
    width, height = SIZE
    sky = cv2.GaussianBlur(rng.normal(12, 4, (height, width)).clip(0, 255).astype(np.uint8), (3, 3), 0)
    stars = rng.integers(0, [width, height], size=(300, 2))
    sky[stars[:, 1], stars[:, 0]] = 200
    means = rng.normal(size=(num_targets, FEATURE_DIM))
    start = rng.uniform([40, 40], [width - 80, height - 80], size=(num_targets, 2))
    velocity = rng.normal(0, 2, size=(num_targets, 2))
    size = rng.uniform([8, 8], [30, 30], size=(num_targets, 2))
    frames, gt = [], []
    for frame in range(1, num_frames + 1):
        xy = start + velocity * frame
        gt.append(np.column_stack([np.full(num_targets, frame), np.arange(1, num_targets + 1), xy, size,
                                   np.ones((num_targets, 3))]))  # fmt: skip
        image = sky.copy()
        for (x, y), (w, h) in zip(xy.astype(int), size.astype(int), strict=True):
            cv2.rectangle(image, (x, y), (x + w, y + h), 230, -1)
        seen = rng.random(num_targets) > MISS_RATE
        n = int(seen.sum())
        tlwh = np.hstack([xy[seen] + rng.normal(0, 1.0, (n, 2)), size[seen]])
        feature = means[seen] + rng.normal(0, 0.3, size=(n, FEATURE_DIM))
        frames.append((tlwh, rng.uniform(0.6, 1.0, n), feature, cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)))
    return frames, np.concatenate(gt)


def contenders() -> dict[str, object]:
    """{name: tracker config}: our DeepSORT and each peer, as `conf/tracker/*.yaml` builds them."""
    names = {"deepsort": "deepsort_original", **{peer: peer for peer in PEERS}}
    return {name: compose_config("track", [f"tracker={yaml}"]).tracker for name, yaml in names.items()}


def track(config: object, frames: list[tuple]) -> np.ndarray:
    """Rows (frame, id, x, y, w, h) of a fresh tracker over `frames`."""
    tracker = instantiate(config)
    rows = []
    for f, (tlwh, confidence, feature, image) in enumerate(frames, start=1):
        out = tracker.step(tlwh, confidence, feature, image=image if tracker.needs_images else None)
        rows.append(np.column_stack([np.full(len(out), f), out]))
    return np.concatenate(rows)


def measure(targets: list[int], num_frames: int, repeats: int) -> tuple[list[list], list[dict]]:
    configs = contenders()
    table, results = [], []
    for num_targets in targets:
        frames, gt = synthetic_sequence(num_targets, num_frames)
        calls = {name: (lambda c=c, f=frames: track(c, f)) for name, c in configs.items()}
        wall, cpu = interleaved_samples(calls, repeats=repeats)
        per_frame = 1e3 / num_frames
        ours = summarize(wall["deepsort"], per_frame)["median"]
        ours_cpu = summarize(cpu["deepsort"], per_frame)["median"]
        names = list(configs)
        for i in progress(len(names), f"scoring, {num_targets} targets", unit="tracker"):
            name = names[i]
            scores = evaluate({"s": (gt, rows_as_mot(track(configs[name], frames)))})["s"]
            w, c = summarize(wall[name], per_frame), summarize(cpu[name], per_frame)
            results.append({"targets": num_targets, "tracker": name, "wall_ms_per_frame": w,
                            "cpu_ms_per_frame": c, "wall_over_deepsort": w["median"] / ours,
                            "cpu_over_deepsort": c["median"] / ours_cpu, "mota": scores["mota"],
                            "hota": scores["hota"]})  # fmt: skip
            table.append([num_targets, name, w["median"], w["median"] / ours, c["median"],
                          c["median"] / ours_cpu, scores["mota"], scores["hota"]])  # fmt: skip
        print(f"{num_targets:3d} targets: deepsort {ours:.2f} ms/frame; " + ", ".join(
            f"{r[1]} {r[2]:.2f}" for r in table if r[0] == num_targets and r[1] != "deepsort"))  # fmt: skip
    return table, results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--targets", type=int, nargs="+", default=[5, 20])
    args = parser.parse_args()
    load_boxmot()
    with threadpool_limits(limits=1, user_api="blas"):
        table, results = measure(args.targets, args.frames, args.repeats)
    record = {
        "what": "tracker-only milliseconds per frame (median over rounds of a whole sequence)",
        "frames": args.frames,
        "repeats": args.repeats,
        "blas_threads": 1,
        "boxmot": BOXMOT_VERSION,
        "results": results,
    }
    header = ["targets", "tracker", "wall ms", "wall / deepsort", "CPU ms", "CPU / deepsort", "MOTA", "HOTA"]
    md = (
        "# BoxMOT's trackers against our DeepSORT: time per frame\n\n"
        f"{args.frames} synthetic 640x480 frames per sequence, median of {args.repeats} round-robin rounds, "
        f"BLAS on one thread; BoxMOT {BOXMOT_VERSION} with its defaults, our DeepSORT with "
        "`conf/tracker/deepsort_original.yaml`; same detections and features, same run. "
        "`benchmarks/bench_peers.py` says how.\n\n" + markdown_table(header, table)
    )
    json_path, md_path = write_report("peers", record, md)
    print(f"wrote {json_path} and {md_path}")


if __name__ == "__main__":
    main()
