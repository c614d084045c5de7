"""The demo end to end on a reduced route; what it prints matches the saved map."""

from __future__ import annotations

import json

import numpy as np

from rhythmic_jax import RhythmicMap
from rhythmic_jax.app.demo import DemoConfig, changed_appearance, demo_mosaic, run_demo


def test_mosaic_and_change_are_deterministic():
    a = demo_mosaic(2, 64)
    assert a.shape == (128, 128, 3) and a.dtype == np.uint8
    np.testing.assert_array_equal(changed_appearance(a), changed_appearance(a))
    assert np.abs(changed_appearance(a).astype(int) - a).mean() > 5


def test_demo_reports_what_the_saved_map_holds(tmp_path, capsys):
    cfg = DemoConfig(grid=2, photo=128, tile=32, stride=16)
    result = run_demo(tmp_path, config=cfg, progress=False)
    printed = capsys.readouterr().out
    model = RhythmicMap.load(tmp_path / "map")
    assert result["periods"] == list(model.periods)
    assert f"{model.storage_bytes:,} bytes" in printed
    assert f"{model.compression_ratio:.4f}" in printed
    on_disk = json.loads((tmp_path / "report.json").read_text())
    assert on_disk["storage_bytes"] == model.storage_bytes
    same = on_disk["same_appearance"]["methods"]
    assert same["brute force"]["accuracy"] == 1.0
    assert same["map"]["accuracy"] >= 0.9
    assert (tmp_path / "report.png").stat().st_size > 1000
    assert "report.png" in (tmp_path / "report.md").read_text()
    assert "report:" in printed


def test_demo_prints_a_baseline_at_the_maps_bytes_recomputed(tmp_path, capsys):
    """Beside brute force, the row at the map's own bytes; its bytes fit the
    map's, and the printed cells are those of report.json (the row's figures
    are recomputed in numpy in tests/eval/test_budget_peers.py)."""
    from rhythmic_jax.eval.budget_peers import pca_dims

    cfg = DemoConfig(grid=2, photo=128, tile=32, stride=16)
    result = run_demo(tmp_path, config=cfg, progress=False)
    printed = capsys.readouterr().out
    model = RhythmicMap.load(tmp_path / "map")
    changed = result["changed_appearance"]
    names = [k for k in changed["methods"] if k not in ("map", "brute force")]
    assert len(names) == 1
    row = changed["methods"][names[0]]
    n, d = model.n, model.d
    int8 = n * d + 2 * d * 4
    if int8 <= model.storage_bytes:
        assert names[0] == "int8/place" and row["storage_bytes"] == int8
    else:
        k = pca_dims(n, d, model.storage_bytes)
        assert names[0] == f"PCA {k}"
        assert row["storage_bytes"] == 4 * (d + d * k + n * k)
    assert row["storage_bytes"] <= model.storage_bytes
    line = next(s for s in printed.split("\n")[::-1] if s.startswith(names[0] + " "))
    assert f"{row['accuracy']:.4f}" in line and f"{row['storage_bytes']:,}" in line
    assert row["latency_median_s"] > 0  # timed like the other rows


def test_the_demo_writes_into_a_fresh_temporary_folder(tmp_path, monkeypatch):
    """Without --out the demo's folder is a new one under the system's temporary
    folder, never an existing one, and never the current folder."""
    from rhythmic_jax.app.demo import fresh_folder

    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", None)  # TMPDIR read again
    (tmp_path / "rhythmic_demo-1").mkdir()
    first, second = fresh_folder("rhythmic_demo"), fresh_folder("rhythmic_demo")
    assert (first, second) == (
        tmp_path / "rhythmic_demo-2",
        tmp_path / "rhythmic_demo-3",
    )
    assert first.is_dir() and not any(first.iterdir())


def test_a_file_at_the_report_folder_is_refused_before_work(tmp_path, capsys):
    from rhythmic_jax.app.cli import main

    (tmp_path / "taken").write_text("x")
    assert main(["demo", "--quick", "--out", str(tmp_path / "taken")]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""  # refused before the route is drawn
    err = captured.err.strip().splitlines()
    assert err == [f"rhythmic-jax demo: error: --out {tmp_path / 'taken'}: a file, "
                   "not a folder"]  # fmt: skip
