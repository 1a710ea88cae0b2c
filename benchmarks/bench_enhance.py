"""Time the DWT/HSV enhancement per 640x480 frame against classical peers, stage by stage.

Contenders, timed in the same run on the same dark frame:
- `dwt_hsv`: the full pipeline with the parameters of conf/enhance/dwt_hsv.yaml;
- `clahe_v` (the peer): OpenCV CLAHE on V of HSV, the classical contrast enhancement;
- `hsv_roundtrip`: RGB -> HSV -> RGB with the same float32 conversion, the floor of any HSV method;
and each stage of `dwt_hsv` alone, so users see where the time goes.

The frame is rendered by the project's dataset builder (dim scenario, 640x480) into a temporary folder;
its ground-truth motion mask gives the target pixels, so the report also states how much each contender
raises the contrast (mean target V - mean background V) / std background V. With `--synthetic` a
synthetic dim frame is used instead (no renderer needed).

    python benchmarks/bench_enhance.py [--repeats 50] [--synthetic]
"""

from __future__ import annotations

import argparse
import os
import tempfile
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np
from hydra.utils import instantiate

from common import interleaved_samples, markdown_table, summarize, write_report
from spacetrack.config import compose_config
from spacetrack.enhance import DwtHsvEnhancer
from spacetrack.enhance import dwt_hsv as stages

WIDTH, HEIGHT = 640, 480


def rendered_dim_frame() -> tuple[np.ndarray, np.ndarray, str]:
    """A frame of the dim scenario from the dataset builder: (RGB uint8, target mask, description)."""
    from spacetrack import build_data

    with tempfile.TemporaryDirectory() as root:
        overrides = [
            "data.name=bench_enhance",
            "data/scenario=[dim]",
            "data.num_sequences=2",
            "data.num_folds=2",
            "data.num_frames=8",
            f"data.width={WIDTH}",
            f"data.height={HEIGHT}",
            "data.image_ext=png",
            "logger=none",
            "progress=false",
            "workers=1",
            f"data_root={root}",
        ]
        build_data.run(compose_config("build_data", overrides))
        seq = Path(root) / "bench_enhance" / "seq_000_dim"
        rgb = cv2.cvtColor(cv2.imread(str(seq / "img" / "000006.png")), cv2.COLOR_BGR2RGB)
        mask = cv2.imread(str(seq / "masks" / "000006.png"), cv2.IMREAD_GRAYSCALE) > 0
    return rgb, mask, "dataset builder, scenario dim, seed 0, sequence 0, frame 6"


def synthetic_dim_frame(seed: int = 0) -> tuple[np.ndarray, np.ndarray, str]:
    """Sky at 8 grey levels with noise sigma 3, 40 stars, four dim discs of 22-34 grey levels."""
    rng = np.random.default_rng(seed)
    img = 8.0 + rng.normal(0.0, 3.0, (HEIGHT, WIDTH, 3))
    rows, cols = np.mgrid[:HEIGHT, :WIDTH]
    mask = np.zeros((HEIGHT, WIDTH), bool)
    for r0, c0, radius, colour in [
        (120, 160, 14, (28, 28, 28)),
        (300, 420, 9, (30, 24, 16)),
        (380, 120, 6, (22, 26, 34)),
        (200, 520, 20, (24, 24, 24)),
    ]:
        inside = (rows - r0) ** 2 + (cols - c0) ** 2 <= radius**2
        img[inside] += np.asarray(colour, float) - 8.0
        mask |= inside
    stars = rng.integers(0, [HEIGHT, WIDTH], size=(40, 2))
    img[stars[:, 0], stars[:, 1]] = 200.0
    return np.clip(np.rint(img), 0, 255).astype(np.uint8), mask, f"synthetic dim frame, seed {seed}"


def contrast(rgb: np.ndarray, target: np.ndarray) -> float:
    """(mean target V - mean background V) / std background V; background = 7+ px away from targets."""
    background = cv2.dilate(target.astype(np.uint8), np.ones((15, 15), np.uint8)) == 0
    v = rgb.max(axis=2).astype(np.float64)
    return float((v[target].mean() - v[background].mean()) / v[background].std())


def clahe_v(clip_limit: float = 2.0, tile: int = 8):
    clahe = cv2.createCLAHE(clipLimit=clip_limit, tileGridSize=(tile, tile))

    def run(rgb: np.ndarray) -> np.ndarray:
        hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
        hsv[..., 2] = clahe.apply(np.ascontiguousarray(hsv[..., 2]))
        return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)

    return run


def stage_calls(enhancer: DwtHsvEnhancer, rgb: np.ndarray) -> dict[str, object]:
    """Each stage of the pipeline as a no-argument call on the intermediate results of this frame."""
    e = enhancer
    h, s, v = stages.to_hsv(rgb)
    dwt_kw = dict(
        wavelet=e.wavelet,
        level=e.level,
        target_mean=e.target_mean,
        gamma_min=e.gamma_min,
        detail_gain=e.detail_gain,
        detail_threshold=e.detail_threshold,
    )
    bil_kw = dict(
        bilateral_d=e.bilateral_d,
        bilateral_sigma_color=e.bilateral_sigma_color,
        bilateral_sigma_space=e.bilateral_sigma_space,
    )
    hs_kw = dict(
        saturation_coupling=e.saturation_coupling, hue_smoothing=e.hue_smoothing, hue_sigma=e.hue_sigma
    )
    v_dwt = stages.wavelet_brighten(v, **dwt_kw)
    v_bil = stages.bilateral(v_dwt, **bil_kw)
    return {
        "stage 1 to_hsv": lambda: stages.to_hsv(rgb),
        "stage 2 wavelet_brighten": lambda: stages.wavelet_brighten(v, **dwt_kw),
        "stage 3 bilateral": lambda: stages.bilateral(v_dwt, **bil_kw),
        "stage 4 adjust_hue_saturation": lambda: stages.adjust_hue_saturation(h, s, v, v_bil, **hs_kw),
        "stage 5 stretch": lambda: stages.stretch(
            v_bil, low_percentile=e.low_percentile, high_percentile=e.high_percentile
        ),
        "stage 6 to_rgb": lambda: stages.to_rgb(h, s, v_bil),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument(
        "--synthetic", action="store_true", help="use a synthetic dim frame, not a rendered one"
    )
    args = parser.parse_args()

    rgb, target, frame_desc = synthetic_dim_frame() if args.synthetic else rendered_dim_frame()
    enhancer = instantiate(compose_config("build_data", ["enhance=dwt_hsv", "logger=none"]).enhance)
    contenders = {
        "dwt_hsv": enhancer,
        "clahe_v": clahe_v(),
        "hsv_roundtrip": lambda x: stages.to_rgb(*stages.to_hsv(x)),
    }
    peer = "clahe_v"
    calls = {name: (lambda f=f: f(rgb)) for name, f in contenders.items()}
    calls.update(stage_calls(enhancer, rgb))

    load_before = os.getloadavg()
    wall, cpu = interleaved_samples(calls, repeats=args.repeats)
    results = {
        name: {**summarize(wall[name]), "cpu_median": summarize(cpu[name])["median"]} for name in calls
    }
    peer_median = results[peer]["median"]
    base_contrast = contrast(rgb, target)
    rows = []
    for name, stats in results.items():
        stats["ratio_to_peer"] = stats["median"] / peer_median
        if name in contenders:
            stats["contrast"] = contrast(contenders[name](rgb), target)
        rows.append(
            [
                name,
                stats["median"],
                stats["p25"],
                stats["p75"],
                stats["cpu_median"],
                stats["ratio_to_peer"],
                stats.get("contrast", ""),
            ]
        )
    record = {
        "what": f"one {WIDTH}x{HEIGHT} RGB uint8 frame per call, milliseconds",
        "frame": frame_desc,
        "input_contrast": base_contrast,
        "peer": peer,
        "repeats": args.repeats,
        "load_average_1min": {"before": load_before[0], "after": os.getloadavg()[0]},
        "params": asdict(enhancer),
        "results": results,
    }
    table = markdown_table(
        ["contender", "median ms", "p25 ms", "p75 ms", "CPU ms", f"x {peer}", "contrast"], rows
    )
    md = (
        f"# DWT/HSV enhancement, {WIDTH}x{HEIGHT} frame\n\n"
        f"Frame: {frame_desc}. Median of {args.repeats} calls after 3 warm-up calls, contenders timed "
        f"round-robin; `x {peer}` is the median over the peer's median in the same run. Machine: "
        f"{os.cpu_count()} CPUs, 1-minute load average {load_before[0]:.1f} before the run.\n"
        f"Contrast = (mean target V - mean background V) / std background V; the input frame has "
        f"{base_contrast:.2f}.\n\n" + table
    )
    json_path, md_path = write_report("enhance", record, md)
    print(md)
    print(f"wrote {json_path} and {md_path}")


if __name__ == "__main__":
    main()
