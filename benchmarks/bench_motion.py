"""Table 3: median time per 640x480 frame of every motion detector, OpenCV MOG2 being the peer.

Contenders (built from conf/motion/, as a user runs them), fed the same synthetic RGB frames in one run:
two-, three- and five-frame difference, our ViBe, OpenCV MOG2 and KNN, the Fig. 8 fusion (region 'and',
the default) and, for reference, the fusion with the paper's pixel 'and', the fusion with global motion
compensation (fed the same scene with the star field slewing) and MOG2 fed grey frames. The frames hold
a noisy dark sky, 300 static stars and three moving targets. Contenders are timed in interleaved rounds
(a block of frames each, round after round), so load from other processes on this machine falls on all
of them alike; all of it twice: with one OpenCV thread, every contender on one core
(the fusion runs its two detectors in turn), and with OpenCV's default thread count, where MOG2 and KNN
split each frame over the cores and the fusion runs the difference and ViBe on two threads
(`parallel: true`; `fusion_in_turn` is the default, which runs them in turn).
Writes reports/motion.json, reports/motion.md and experiments/table3_motion/timing.md (the same next to
the paper's numbers).

    python benchmarks/bench_motion.py [--rounds 15] [--block 10]
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np
from hydra.utils import instantiate

from common import markdown_table, progress, summarize, write_report
from spacetrack.config import REPO_ROOT, compose_config
from spacetrack.io import atomic_write_text

WIDTH, HEIGHT = 640, 480
PEER = "mog2"
# Table 3 of the paper, seconds per frame (its own camera and machine).
PAPER_S = {"three_frame": 0.012, "five_frame": 0.018, "mog2": 0.043, "vibe": 0.031, "fusion": 0.025}
SLEW = (1.0, 0.5)  # pixels per frame of the star field fed to the compensated fusion
METHODS = ("two_frame", "three_frame", "five_frame", "vibe", "mog2", "knn", "fusion")


def synthetic_frames(num: int, seed: int = 0, slew: tuple[float, float] = (0.0, 0.0)) -> list[np.ndarray]:
    """`num` RGB uint8 frames: dark noisy sky, static stars, three targets moving 1-3 px per frame; with
    `slew` (pixels per frame) the star field drifts as under a slewing camera (same stars, same targets)."""
    rng = np.random.default_rng(seed)
    sky = np.zeros((HEIGHT, WIDTH), np.float32)
    ys, xs = rng.integers(0, HEIGHT, 300), rng.integers(0, WIDTH, 300)
    sky[ys, xs] = rng.uniform(60, 255, 300)
    sky = cv2.GaussianBlur(sky, (5, 5), 0.8) + 4.0
    sky = np.tile(sky, (2, 2))  # room to drift: the view wraps around the repeated field
    starts = rng.uniform((80, 80), (WIDTH - 280, HEIGHT - 180), (3, 2))
    velocities = rng.uniform(-3, 3, (3, 2))
    frames = []
    for t in range(num):
        x0, y0 = int(slew[0] * t) % WIDTH, int(slew[1] * t) % HEIGHT
        view = sky[y0 : y0 + HEIGHT, x0 : x0 + WIDTH]
        image = view + rng.normal(0, 2.0, view.shape).astype(np.float32)
        for k, (start, velocity) in enumerate(zip(starts, velocities, strict=True)):
            cx, cy = start + velocity * t
            cv2.ellipse(image, (int(cx), int(cy)), (18 + 6 * k, 8 + 3 * k), 30 * k, 0, 360, 90 + 50 * k, -1)
        grey = np.clip(image, 0, 255).astype(np.uint8)
        frames.append(np.dstack([grey, grey, (grey * 0.9).astype(np.uint8)]))
    return frames


def contenders(one_core: bool = False) -> dict[str, object]:
    """{name: detector} from the project's configs (the paper's methods, peers, and references).

    With `one_core` the fusion runs its two detectors in turn (`parallel=False`, the default), as every
    contender then gets one core; otherwise on two threads (`parallel=True`), and `fusion_in_turn` is the
    default fusion, for reference. `fusion_compensated` is the fusion with global motion compensation on
    (each part measures the scene's shift by phase correlation): what a slewing camera costs.
    """
    cfg = compose_config("eval_motion", ["logger=none"])
    built = {name: instantiate(cfg.methods[name]) for name in METHODS}
    built["fusion"] = instantiate(cfg.methods.fusion, parallel=not one_core)
    if not one_core:
        built["fusion_in_turn"] = instantiate(cfg.methods.fusion, parallel=False)
    built["fusion_pixel_and"] = instantiate(cfg.methods.fusion, combine="pixel", parallel=not one_core)
    compensated = {"compensate": True}  # for a slewing camera: both parts register every frame first
    built["fusion_compensated"] = instantiate(
        cfg.methods.fusion, parallel=not one_core, difference=compensated, background=compensated
    )
    built["mog2_grey"] = instantiate(cfg.methods.mog2, grey=True)
    return built


def time_interleaved(
    detectors: dict, frames: list[np.ndarray], rounds: int, block: int, own_frames: dict | None = None
) -> dict[str, list]:
    """Seconds per `apply` call of each detector, fed the frames in order, round-robin in blocks;
    `own_frames` gives some detectors {name: frames} of their own (the same number)."""
    feeds = {name: (own_frames or {}).get(name, frames) for name in detectors}
    samples: dict[str, list[float]] = {name: [] for name in detectors}
    cursor = {name: 0 for name in detectors}
    for name, detector in detectors.items():  # warm-up: every detector past its start-up frames
        for frame in feeds[name][:10]:
            detector.apply(frame)
        if hasattr(detector, "flush"):
            detector.flush()
        cursor[name] = 10
    for _ in progress(rounds, ", ".join(detectors), unit="round"):
        for name, detector in detectors.items():
            for _ in range(block):
                frame = feeds[name][cursor[name] % len(frames)]
                cursor[name] += 1
                start = time.perf_counter()
                detector.apply(frame)
                samples[name].append(time.perf_counter() - start)
            if hasattr(detector, "flush"):
                # a parallel fusion's worker may still be on the last frame: that time is the fusion's,
                # and must not fall on the next contender's block
                start = time.perf_counter()
                detector.flush()
                samples[name][-1] += time.perf_counter() - start
    return samples


def measure(
    frames: list[np.ndarray], slewing: list[np.ndarray], rounds: int, block: int, threads: int
) -> dict[str, dict]:
    """Summary of each contender's seconds per frame with OpenCV limited to `threads` threads; the
    compensated fusion gets the `slewing` frames, so that it pays for its warps as well."""
    cv2.setNumThreads(threads)
    own = {"fusion_compensated": slewing}
    samples = time_interleaved(contenders(one_core=threads == 1), frames, rounds, block, own)
    return {name: summarize(s) for name, s in samples.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--block", type=int, default=10)
    parser.add_argument("--frames", type=int, default=120, help="distinct frames (fed cyclically)")
    args = parser.parse_args()

    frames = synthetic_frames(args.frames)
    slewing = synthetic_frames(args.frames, slew=SLEW)
    # One OpenCV thread: every contender on one core, as the pipeline runs motion beside the networks;
    # then OpenCV's default, where MOG2 and KNN (and our OpenCV calls) may spread over all cores.
    settings = {1: None, cv2.getNumThreads(): None}
    for threads in settings:
        settings[threads] = measure(frames, slewing, args.rounds, args.block, threads)
    header = ["detector", "median ms/frame", "p25", "p75", f"ratio to {PEER}", "mean ms/frame", "mean ratio"]
    parts, table3 = [], {}
    for threads, stats in settings.items():
        peer, peer_mean = stats[PEER]["median"], stats[PEER]["mean"]
        rows = [
            [n, s["median"], s["p25"], s["p75"], s["median"] / peer, s["mean"], s["mean"] / peer_mean]
            for n, s in stats.items()
        ]
        parts.append(f"## {threads} OpenCV thread(s)\n\n" + markdown_table(header, rows))
        for name in PAPER_S:
            table3.setdefault(name, [name]).extend([stats[name]["median"], stats[name]["median"] / peer])
    md = (
        f"# Motion detection time per {WIDTH}x{HEIGHT} RGB frame\n\n"
        f"{args.rounds} interleaved rounds of {args.block} frames per detector; peer: OpenCV {PEER} "
        "(colour frames). Our methods compensate camera motion `auto`: on these still frames they measure "
        "the scene's shift every 10th frame only, which the mean shows and the median hides. "
        f"`fusion_compensated` (compensation on) is fed the same scene with the star field slewing {SLEW} "
        "pixels per frame.\n\n" + "\n\n".join(parts)
    )
    record = {
        "what": f"motion detector apply() per {WIDTH}x{HEIGHT} RGB frame (synthetic star field, 3 targets)",
        "peer": PEER,
        "rounds": args.rounds,
        "block": args.block,
        "opencv": cv2.__version__,
        "by_opencv_threads": {
            str(threads): {name: {**s, "ratio_to_peer": s["median"] / stats[PEER]["median"]}
                           for name, s in stats.items()}
            for threads, stats in settings.items()
        },
        "slew_px_per_frame_of_fusion_compensated": SLEW,
        "paper_table3_s": PAPER_S,
    }  # fmt: skip
    write_report("motion", record, md)
    paper_header = ["method"]
    for threads in settings:
        paper_header += [f"ours ms ({threads} thr.)", f"ours / {PEER} ({threads} thr.)"]
    paper_header += ["paper ms", f"paper / {PEER}"]
    rows = [cells + [1e3 * PAPER_S[name], PAPER_S[name] / PAPER_S[PEER]] for name, cells in table3.items()]
    timing = (
        "# Table 3 reproduction: time per frame\n\n"
        f"Ours: median over {args.rounds * args.block} frames of {WIDTH}x{HEIGHT}, this machine, with 1 and "
        f"{max(settings)} OpenCV threads, `make bench-motion`. Paper: its Table 3 (own camera, own machine); "
        "compare the ratios, not the milliseconds.\n\n" + markdown_table(paper_header, rows)
    )
    atomic_write_text(REPO_ROOT / "experiments" / "table3_motion" / "timing.md", timing)
    print(md)


if __name__ == "__main__":
    main()
