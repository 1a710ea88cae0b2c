"""ONNX Runtime against OpenVINO on the same detector graphs: why the ONNX backends run on ONNX Runtime.

Both runtimes load the graphs the pipeline itself makes from the shipped fold-3 weights at the native
640x480 input (`detector.backend=onnxruntime`: float32; `onnxruntime_int8`: that graph with INT8
quantize/dequantize nodes, calibrated on frames of the weights' training folds) and run them batch 1 on
a real frame, timed round-robin (one call of each per round) at each thread count. Agreement: the
largest difference of the decoded boxes (pixels) and scores between the two runtimes, over the rows
either one scores >= 0.1 (what reaches the tracker's cache).

    pip install openvino                      # or: pip install -e '.[bench]'
    python benchmarks/bench_runtimes.py [--threads 1 2] [--repeats 15]
"""

from __future__ import annotations

import argparse
import os

import cv2
import numpy as np

from common import interleaved_samples, markdown_table, summarize, write_report
from spacetrack.config import REPO_ROOT
from spacetrack.pipeline.detector import YoloDetector

SHIPPED = REPO_ROOT / "weights" / "detector_yolov5s_fold3.pt"
FRAME = REPO_ROOT / "data" / "space_default" / "seq_003_occlusion" / "img" / "000060.jpg"
NATIVE = (480, 640)
MIN_SCORE = 0.1


def openvino_call(path, threads: int):
    """A compiled OpenVINO model of the ONNX file `path` on the CPU, float32 inference, `threads` threads."""
    import openvino

    compiled = openvino.Core().compile_model(
        str(path),
        "CPU",
        {"INFERENCE_NUM_THREADS": threads, "PERFORMANCE_HINT": "LATENCY", "INFERENCE_PRECISION_HINT": "f32"},
    )
    request = compiled.create_infer_request()
    return lambda x: request.infer({0: x})[compiled.output(0)]


def agreement(a: np.ndarray, b: np.ndarray) -> dict[str, float]:
    """Largest box (px) and score differences between two (1, N, 5 + classes) decoded outputs."""
    score_a, score_b = (p[0, :, 4:5] * p[0, :, 5:] for p in (a, b))
    kept = (score_a.max(1) >= MIN_SCORE) | (score_b.max(1) >= MIN_SCORE)
    if not kept.any():
        return {"rows": 0, "box_px": 0.0, "score": 0.0}
    return {
        "rows": int(kept.sum()),
        "box_px": float(np.abs(a[0, kept, :4] - b[0, kept, :4]).max()),
        "score": float(np.abs(score_a[kept] - score_b[kept]).max()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args()
    try:
        import openvino
    except ImportError:
        raise SystemExit(
            "bench_runtimes needs OpenVINO: pip install openvino (or pip install -e '.[bench]')"
        ) from None
    if not FRAME.is_file():
        raise SystemExit(f"{FRAME} not found: render the default dataset first (make data)")
    rgb = cv2.cvtColor(cv2.imread(str(FRAME)), cv2.COLOR_BGR2RGB)
    x = np.ascontiguousarray(rgb.transpose(2, 0, 1)[None], dtype=np.float32) / np.float32(255)
    records, rows, agree = [], [], {}
    for threads in args.threads:
        calls = {}
        for backend, kind in (("onnxruntime", "float32"), ("onnxruntime_int8", "INT8")):
            session = YoloDetector(weights=SHIPPED, device="cpu", backend=backend, threads=threads).session(
                *NATIVE
            )
            calls[f"ONNX Runtime {kind}"] = lambda s=session: s(x)[0]
            calls[f"OpenVINO {kind}"] = (lambda f: lambda: f(x))(openvino_call(session.path, threads))
            if threads == args.threads[0]:
                agree[kind] = agreement(calls[f"ONNX Runtime {kind}"](), calls[f"OpenVINO {kind}"]())
        load = os.getloadavg()[0]
        wall, _ = interleaved_samples(calls, repeats=args.repeats)
        reference = summarize(wall["ONNX Runtime float32"])["median"]
        for name, samples in wall.items():
            s = summarize(samples)
            ratio = s["median"] / reference
            records.append({"contender": name, "threads": threads, "input": "640x480", "inference_ms": s,
                            "ratio_to_onnxruntime_float32": ratio, "load_average_1min": load})  # fmt: skip
            rows.append(
                [name, threads, f"{s['median']:.1f}", f"{s['p25']:.1f}", f"{s['p75']:.1f}", f"{ratio:.2f}"]
            )
            print(rows[-1], flush=True)
    agree_rows = [[k, v["rows"], f"{v['box_px']:.2f}", f"{v['score']:.3f}"] for k, v in agree.items()]
    table = (
        "# ONNX Runtime against OpenVINO on the detector's graphs (640x480, batch 1, CPU)\n\n"
        f"OpenVINO {openvino.__version__.split('-')[0]}; the graphs `detector.backend=onnxruntime` and `onnxruntime_int8` "
        f"make from the shipped fold-3 weights; one real frame; {args.repeats} rounds, the contenders of one "
        "thread count alternating call by call. Compare ratios within the run, not times across runs.\n\n"
        + markdown_table(["runtime", "threads", "ms median", "p25", "p75", "x ONNX Runtime float32"], rows)
        + f"\n## Agreement of OpenVINO with ONNX Runtime (rows scoring >= {MIN_SCORE})\n\n"
        + markdown_table(["graph", "rows", "max box difference (px)", "max score difference"], agree_rows)
    )
    write_report(
        "runtimes",
        {"openvino": openvino.__version__.split("-")[0], "results": records, "agreement": agree},
        table,
    )
    print(table)


if __name__ == "__main__":
    main()
