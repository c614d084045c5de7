"""``evaluate --plot`` (recall@N curves and the predicted place along the route)
and ``evaluate --matches`` (queries beside the place chosen and the right one)
on image folders; the queries drawn, checked by hand."""

from __future__ import annotations

import numpy as np
import pytest
from skimage import data as skdata
from skimage.io import imsave
from skimage.transform import resize

from rhythmic_jax.app.cli import main
from rhythmic_jax.app.matches import pick


def run(capsys, *argv):
    code = main([*argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("folders")
    photo = resize(skdata.astronaut(), (96, 400), anti_aliasing=True)
    frames = [(photo[:, 8 * i : 8 * i + 64] * 255).astype(np.uint8) for i in range(40)]
    rng = np.random.default_rng(0)
    changed = [np.clip(f * 0.6 + rng.normal(0, 25, f.shape), 0, 255).astype(np.uint8)
               for f in frames]  # fmt: skip
    for name, pics in (("ref", frames), ("qry", changed)):
        (root / name).mkdir()
        for i, img in enumerate(pics):
            imsave(root / name / f"{name}_{i:03d}.png", img, check_contrast=False)
    assert main(["fit", str(root / "ref"), "--out", str(root / "m.map"),
                 "--no-progress"]) == 0  # fmt: skip
    return root


def test_pick_spreads_successes_and_takes_the_surest_failures_first():
    correct = [True, True, False, True, False, True, False, True]
    conf = [0.1, 0.2, 0.9, 0.3, None, 0.5, 2.0, 0.4]
    good, bad = pick(correct, conf, successes=3, failures=2)
    assert good == [0, 3, 7] and bad == [6, 2]
    assert pick(correct, conf, successes=9, failures=9)[1] == [6, 2, 4]


def test_evaluate_plot_and_matches_on_image_folders(folders, capsys):
    root = folders
    plot, drawn = root / "p.png", root / "m.png"
    code, out, err = run(capsys, "evaluate", str(root / "m.map"), str(root / "qry"),
                         "--tolerance", "1", "--plot", str(plot), "--matches",
                         str(drawn), "--no-progress")  # fmt: skip
    assert code == 0, err
    assert plot.stat().st_size > 20_000 and drawn.stat().st_size > 20_000
    assert f"-> {drawn}" in out and "recall@N and the route" in out
    code, out, err = run(capsys, "evaluate", str(root / "m.map"), str(root / "qry"),
                         "--matches", str(root / "m.jpg"))  # fmt: skip
    assert code == 2 and "--matches" in err and ".png" in err


def test_matches_of_descriptor_files_are_refused_in_one_line(folders, capsys,
                                                             tmp_path):  # fmt: skip
    np.save(tmp_path / "q.npy", np.zeros((5, 8), np.float32))
    np.save(tmp_path / "r.npy", np.eye(8, dtype=np.float32))
    assert main(["fit", str(tmp_path / "r.npy"), "--out", str(tmp_path / "n.map"),
                 "--no-progress"]) == 0  # fmt: skip
    capsys.readouterr()
    code, _, err = run(capsys, "evaluate", str(tmp_path / "n.map"),
                       str(tmp_path / "q.npy"), "--matches", str(tmp_path / "m.png"))
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "image folder" in err and "holds descriptors" in err
    code, _, err = run(capsys, "evaluate", str(tmp_path / "n.map"),
                       str(folders / "qry"), "--descriptor", "patchnorm",
                       "--matches", str(tmp_path / "m.png"))  # fmt: skip
    assert code == 2 and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("codes", ["int8", 16])
def test_the_recall_per_byte_rows_name_the_codes_by_their_kind(codes):
    """An int8 hybrid's codes are "int8 per place" in the plot, not ITQ bits."""
    from rhythmic_jax import RhythmicMap
    from rhythmic_jax.eval.report import evaluate_map

    rng = np.random.default_rng(5)
    x = rng.standard_normal((50, 24)).astype(np.float32)
    q = x + 0.1 * rng.standard_normal(x.shape).astype(np.float32)
    model = RhythmicMap(r=2, level=1, codes=codes).fit(x)
    res = evaluate_map(model, q, reference=x, timing=False, curves=True)
    names = {r["kind"]: r["name"] for r in res["frontier"]}
    want = "int8 per place alone" if codes == "int8" else "ITQ 16 bits alone"
    assert names["codes"] == want
    assert "ITQ" not in " ".join(names.values()) or codes != "int8"
