import json

import numpy as np
import pytest

from spacetrack.config import compose_config
from spacetrack.evaluate import run


def test_scores_a_results_file_prints_a_table_and_writes_json(tmp_path, capsys):
    gt, results, out = tmp_path / "gt.txt", tmp_path / "res.txt", tmp_path / "metrics.json"
    gt.write_text("1,1,0,0,20,20,1,0,1\n1,2,100,0,20,20,1,0,1\n2,1,0,0,20,20,1,0,1\n2,2,100,0,20,20,0,0,0\n")
    results.write_text("1,5,0,0,20,20,1,-1,-1,-1\n2,5,1,0,20,20,1,-1,-1,-1\n2,6,300,0,20,20,1,-1,-1,-1\n")
    cfg = compose_config("evaluate", ["logger=none", f"gt={gt}", f"results={results}", f"output_file={out}"])
    metrics = run(cfg)
    # 3 counted ground-truth boxes (one is hidden): 2 matched, 1 missed, 1 false positive
    assert (metrics["fn"], metrics["fp"], metrics["idsw"]) == (1, 1, 0)
    assert metrics["mota"] == 1 - 2 / 3
    # HOTA: the moved box (IoU 380 / 420 = 0.905) matches at the 18 thresholds alpha <= 0.90, where
    # TP 2, FN 1, FP 1 (DetA 1/2) and both matches are gt 1 - result 5 (AssA 1); at alpha 0.95 only
    # frame 1 matches: DetA 1/5, AssA 1 / (2 + 2 - 1).
    assert metrics["hota"] == pytest.approx((18 * np.sqrt(1 / 2) + np.sqrt(1 / 5 / 3)) / 19)
    saved = json.loads(out.read_text())
    assert saved["OVERALL"] == metrics and set(saved) == {"res", "OVERALL"}
    table = capsys.readouterr().out
    assert "| res | 33.33 |" in table and "MOTA" in table and "HOTA" in table
