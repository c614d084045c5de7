"""format_evaluation: every row and column of an evaluation written as the table
says, against a hand case and the result's own numbers."""

from __future__ import annotations

import numpy as np
import pytest

from rhythmic_jax import RhythmicMap
from rhythmic_jax.eval.report import evaluate_map
from rhythmic_jax.eval.report_text import format_evaluation

N, D = 60, 16
COLS = [
    "accuracy",
    "accuracy_tol",
    "recall@1",
    "recall@5",
    "recall@10",
    "recall@20",
    "pr_auc",
    "recall@100p",
    "storage_bytes",
    "latency_median_s",
    "queries_per_s",
]
HEAD = ["accuracy", "acc_tol", *COLS[2:8], "bytes", "latency", "queries/s"]
W = 13


def unit(a: np.ndarray) -> np.ndarray:
    return (a / np.linalg.norm(a, axis=1, keepdims=True)).astype(np.float32)


@pytest.fixture(scope="module")
def case():
    """A map fitted on 60 random unit frames; noisy queries of the same places."""
    rng = np.random.default_rng(0)
    x = unit(rng.standard_normal((N, D)))
    q = unit(x + 0.3 * rng.standard_normal((N, D)))
    model = RhythmicMap().fit(x, progress=False)
    return model, x, q


# ------------------------------------------------------------- format_evaluation
def test_format_evaluation_prints_every_row_and_column(case):
    model, x, q = case
    res = evaluate_map(model, q, reference=x, tolerance=2, timing=False)
    text = format_evaluation(res)
    lines = text.split("\n")
    rows = ["map", "brute force", "int8/place"]  # int8 fits the map's bytes here
    assert list(res["methods"]) == rows
    assert len(lines) == 14  # and the legend: accuracy, recall@K, the int8 row
    assert lines[11].startswith("accuracy: the hard decode's place (a -1, no match,")
    assert lines[12].startswith("recall@K: a right place (within the tolerance) among")
    assert lines[13].startswith("int8 per place: 60 frames x 16 bytes + the range")
    assert lines[:4] == [
        f"n={N} d={D} queries={N}; compression ratio {res['compression_ratio']:.4f}"
        f" of {N} x {D} float32, {N * D * 4:,} B, the frames brute force searches",
        "decode=hard sequence=off; recall@K ranks single-frame scores (single frames)",
        "ground truth: index-aligned (query i is place i), tolerance ±2 frames",
        f"recall@K over all {N} queries, each with a right place (VPR_Tutorial's "
        "and VPR-methods-evaluation's conventions agree)",
    ]
    assert lines[4] == f"{'method':<12}" + "".join(f"{c:>{W}}" for c in HEAD)
    for line, name in zip(lines[8:11], rows, strict=True):
        r = res["methods"][name]
        want = ", ".join(f"R@{k}: {100 * r[f'recall@{k}']:.1f}" for k in (1, 5, 10, 20))
        assert line == f"{name}: {want} (over {N} queries with a right place)"
    for line, name in zip(lines[5:8], rows, strict=True):
        row = res["methods"][name]
        assert line.startswith(f"{name:<12}")
        cells = line[12:]
        assert len(cells) == W * len(COLS)
        cells = [cells[i : i + W].strip() for i in range(0, len(cells), W)]
        for c in COLS[:8]:
            assert cells[COLS.index(c)] == f"{row[c]:.4f}"
        assert cells[COLS.index("storage_bytes")] == f"{row['storage_bytes']:,}"
        assert cells[-2:] == ["-", "-"]  # no timing


def test_format_evaluation_hand_case():
    result = {
        "n": 1000,
        "d": 8,
        "n_queries": 3,
        "tolerance": 0,
        "decode": "topm",
        "sequence": 4,
        "compression_ratio": 0.123456,
        "methods": {
            "map": {
                "accuracy": 0.5,
                "accuracy_tol": 0.75,
                "recall@1": 0.5,
                "recall@5": 1.0,
                "storage_bytes": 1234567,
                "latency_median_s": 0.0025,
                "queries_per_s": 12345.6,
            },
            "kd": {"accuracy": 1 / 3, "queries_per_s": 55.5},
        },
    }
    lines = format_evaluation(result).split("\n")
    assert lines[:3] == [
        "n=1000 d=8 queries=3; compression ratio 0.1235",
        "decode=topm sequence=4; recall@K ranks single-frame scores (peers at the "
        "same L=4)",
        "ground truth: index-aligned (query i is place i), tolerance ±0 frames",
    ]
    assert lines[3].split() == ["method", *HEAD]
    dash = f"{'-':>{W}}"
    assert lines[4] == (
        f"{'map':<12}"
        + f"{'0.5000':>{W}}{'0.7500':>{W}}{'0.5000':>{W}}{'1.0000':>{W}}"
        + dash * 4
        + f"{'1,234,567':>{W}}{'2.500 ms':>{W}}{'12,346':>{W}}"
    )
    assert lines[5] == f"{'kd':<12}{'0.3333':>{W}}" + dash * 9 + f"{'55.5000':>{W}}"
    assert lines[6:8] == ["map: R@1: 50.0, R@5: 100.0", "kd: "]
    assert lines[8].startswith("accuracy: the topm decode's place is the right")
    assert lines[10] == ("latency: one query alone, from its descriptor to a "
                         "place (a map's template product, a code's encoding and "
                         "an embedding included), median of up to 200 calls after "
                         "20 warm ones; queries/s: all 3 queries in one call "
                         "(batched: not 1/latency)")  # fmt: skip

