"""Time the tracker alone, in milliseconds per frame, at 5, 20 and 100 targets, against a public peer.

Contenders, timed in the same run on the same synthetic detections:
- `spacetrack`: `spacetrack.tracking.DeepSort` (numpy + scipy, vectorised cost and gating matrices);
- `deep-sort-realtime` (the peer): a public pure-Python port of the reference DeepSORT
  (`pip install --no-deps deep-sort-realtime`; `make bench-tracker` installs it).

Both run the Table 2 "original" association settings (cosine 0.2, IoU 0.7, n_init 3, budget 100,
max_age 70) with NMS off (the peer skips it at overlap 1) and no confidence floor (the peer has none),
on the same per-frame detections sorted by confidence. Each synthetic sequence is a detection file
in the DeepSORT layout (targets moving with noise, 128-D features scattered around a per-target mean,
10% missed detections) with its ground truth; `--save-dir DIR` only writes them to DIR, e.g. to
try `python -m spacetrack.track_detections` on. Only the tracker is timed: the per-frame inputs are read
beforehand into each contender's own format. The report also states how many written boxes (id and
box to 0.01 px) the two agree on, and our MOTA against the ground truth as a sanity check.

BLAS is pinned to one thread for both: the matrices are tiny, and on a busy machine multi-threaded
OpenBLAS can stall a 4x4 triangular solve for milliseconds, which would time the machine, not the code.

    python benchmarks/bench_tracker.py [--frames 100] [--repeats 5] [--targets 5 20 100] [--save-dir DIR]
"""

from __future__ import annotations

import argparse
import tempfile
from importlib.metadata import version
from pathlib import Path

import numpy as np
import scipy.linalg  # noqa: F401  (loaded before pinning, so its BLAS is pinned too)
from threadpoolctl import threadpool_limits

from common import markdown_table, summarize, time_call, write_report
from spacetrack.data.layout import BOX, CONF, read_mot
from spacetrack.evaluation import evaluate
from spacetrack.track_detections import rows_as_mot
from spacetrack.tracking import DeepSort
from spacetrack.tracking.io import FEATURES, iter_frames, load_detections

SETTINGS = dict(max_cosine_distance=0.2, nn_budget=100, max_iou_distance=0.7, max_age=70, n_init=3)
FEATURE_DIM = 128
MISS_RATE = 0.1


def write_synthetic_files(
    folder: Path, num_targets: int, num_frames: int, seed: int = 0
) -> tuple[Path, Path]:
    """Write `targets_<n>.npy` (DeepSORT layout) and `targets_<n>_gt.txt` (MOT) into `folder`.

    Targets move at constant velocity; detections add 1 px position noise, 3% size noise and a 128-D
    feature scattered around a per-target mean, miss 10% of the boxes, and come sorted by confidence.
    """
    rng = np.random.default_rng(seed)
    means = rng.normal(size=(num_targets, FEATURE_DIM))
    start = rng.uniform([0, 0], [600, 440], size=(num_targets, 2))
    velocity = rng.normal(0, 2, size=(num_targets, 2))
    size = rng.uniform([12, 16], [40, 50], size=(num_targets, 2))
    dets, gt = [], []
    for frame in range(1, num_frames + 1):
        xy = start + velocity * frame
        ids = np.arange(1, num_targets + 1)
        gt.append(np.column_stack([np.full(num_targets, frame), ids, xy, size, np.ones((num_targets, 3))]))
        seen = rng.random(num_targets) > MISS_RATE
        n = int(seen.sum())
        boxes = np.hstack([xy[seen] + rng.normal(0, 1.0, (n, 2)), size[seen] * rng.normal(1, 0.03, (n, 2))])
        confidence = rng.uniform(0.4, 1.0, n)
        feature = means[seen] + rng.normal(0, 0.3, size=(n, FEATURE_DIM))
        rows = np.column_stack([np.full(n, frame), -np.ones(n), boxes, confidence, -np.ones((n, 3)), feature])
        dets.append(rows[np.argsort(-confidence, kind="stable")])
    det_path, gt_path = folder / f"targets_{num_targets}.npy", folder / f"targets_{num_targets}_gt.txt"
    np.save(det_path, np.concatenate(dets))
    np.savetxt(gt_path, np.concatenate(gt), fmt="%d,%d,%.2f,%.2f,%.2f,%.2f,%d,%d,%d")
    return det_path, gt_path


def frames_from_file(path: Path) -> list[tuple[np.ndarray, ...]]:
    """Per frame (tlwh (N, 4) px, confidence (N,), feature (N, D)) of a detection file."""
    return [
        (rows[:, BOX], rows[:, CONF], rows[:, FEATURES]) for _, rows in iter_frames(load_detections(path))
    ]


def run_ours(frames: list[tuple[np.ndarray, ...]]) -> list[dict[int, np.ndarray]]:
    tracker = DeepSort(**SETTINGS, min_confidence=0.0, nms_max_overlap=1.0)
    return [{int(r[0]): r[1:] for r in tracker.step(*frame)} for frame in frames]


def peer_inputs(frames: list[tuple[np.ndarray, ...]]) -> list[tuple[list, list]]:
    return [
        ([(list(box), float(c), 0) for box, c in zip(tlwh, conf, strict=True)], list(feature))
        for tlwh, conf, feature in frames
    ]


def run_peer(inputs: list[tuple[list, list]]) -> list[dict[int, np.ndarray]]:
    from deep_sort_realtime.deepsort_tracker import DeepSort as PeerDeepSort

    tracker = PeerDeepSort(**SETTINGS, nms_max_overlap=1.0, embedder=None)
    outputs = []
    for raw, embeds in inputs:
        tracks = tracker.update_tracks(raw, embeds=embeds)
        outputs.append(
            {int(t.track_id): t.to_tlwh() for t in tracks if t.is_confirmed() and t.time_since_update <= 1}
        )
    return outputs


def agreement(ours: list[dict[int, np.ndarray]], peer: list[dict[int, np.ndarray]]) -> float:
    """Fraction of all boxes written by either contender that both write with the same id and box."""
    same = total = 0
    for a, b in zip(ours, peer, strict=True):
        total += len(a.keys() | b.keys())
        same += sum(np.allclose(a[k], b[k], atol=1e-2) for k in a.keys() & b.keys())
    return same / max(total, 1)


def score(tracks: list[dict[int, np.ndarray]], gt: np.ndarray) -> float:
    """MOTA of per-frame tracker outputs against the synthetic ground truth (a sanity check)."""
    rows = [[frame, k, *box] for frame, out in enumerate(tracks, start=1) for k, box in out.items()]
    return evaluate({"s": (gt, rows_as_mot(np.array(rows)))})["s"]["mota"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--targets", type=int, nargs="+", default=[5, 20, 100])
    parser.add_argument(
        "--save-dir", type=Path, help="only write the synthetic detection and gt files there (no timing)"
    )
    args = parser.parse_args()

    if args.save_dir:
        args.save_dir.mkdir(parents=True, exist_ok=True)
        for num_targets in args.targets:
            paths = write_synthetic_files(args.save_dir, num_targets, args.frames)
            print("wrote", *paths)
        return
    with tempfile.TemporaryDirectory() as folder, threadpool_limits(limits=1, user_api="blas"):
        rows, results = measure(Path(folder), args.targets, args.frames, args.repeats)
    write(rows, results, args.frames, args.repeats)


def measure(folder: Path, targets: list[int], num_frames: int, repeats: int) -> tuple[list[list], list[dict]]:
    per_frame = 1e3 / num_frames  # seconds per sequence -> ms per frame
    rows, results = [], []
    for num_targets in targets:
        det_path, gt_path = write_synthetic_files(folder, num_targets, num_frames)
        frames = frames_from_file(det_path)
        inputs = peer_inputs(frames)
        ours = summarize(
            time_call(
                lambda f=frames: run_ours(f), repeats=repeats, warmup=1, desc=f"ours, {num_targets} targets"
            ),
            per_frame,
        )
        peer = summarize(
            time_call(
                lambda i=inputs: run_peer(i), repeats=repeats, warmup=1, desc=f"peer, {num_targets} targets"
            ),
            per_frame,
        )
        tracks = run_ours(frames)
        agree = agreement(tracks, run_peer(inputs))
        mota = score(tracks, read_mot(gt_path))
        ratio = peer["median"] / ours["median"]
        results.append(
            {
                "targets": num_targets,
                "detections": int(sum(len(f[0]) for f in frames)),
                "spacetrack_ms_per_frame": ours,
                "peer_ms_per_frame": peer,
                "peer_over_spacetrack": ratio,
                "agreement": agree,
                "spacetrack_mota": mota,
            }
        )
        rows.append(
            [num_targets, ours["median"], ours["p25"], ours["p75"], peer["median"], ratio, agree, mota]
        )
        print(
            f"{num_targets:4d} targets: spacetrack {ours['median']:.2f} ms/frame, peer {peer['median']:.2f}"
        )
    return rows, results


def write(rows: list[list], results: list[dict], num_frames: int, repeats: int) -> None:
    """reports/tracker.json (everything measured, with the settings) and reports/tracker.md."""
    record = {
        "what": "tracker-only milliseconds per frame (median over repeats of a whole sequence)",
        "frames": num_frames,
        "repeats": repeats,
        "blas_threads": 1,
        "settings": {**SETTINGS, "nms_max_overlap": 1.0, "min_confidence": 0.0},
        "feature_dim": FEATURE_DIM,
        "miss_rate": MISS_RATE,
        "peer": f"deep-sort-realtime {version('deep-sort-realtime')}",
        "results": results,
    }
    header = ["targets", "spacetrack ms", "p25", "p75", "peer ms", "peer / spacetrack", "same boxes", "MOTA"]
    table = (
        "# Tracker-only time per frame\n\n"
        f"{num_frames} frames per sequence, median of {repeats} runs, BLAS on one thread; peer: "
        f"{record['peer']} (same settings, same detections, same run).\n\n" + markdown_table(header, rows)
    )
    json_path, md_path = write_report("tracker", record, table)
    print(f"wrote {json_path} and {md_path}")


if __name__ == "__main__":
    main()
