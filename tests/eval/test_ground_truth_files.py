"""Ground truth from the files users have: a VPR-Bench layout (ragged lists, read
without running its pickle), positions in metres or degrees, @east@north@ file
names, and places grouped from positions, through the command line."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
import skimage.io
from skimage.transform import resize

from rhythmic_jax import RhythmicMap
from rhythmic_jax.app.cli import main
from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.ground_truth import from_lists, from_positions
from rhythmic_jax.eval.ground_truth_files import load_ground_truth, safe_object_npy
from rhythmic_jax.eval.report import evaluate_map
from rhythmic_jax.fitting.places import read_positions
from rhythmic_jax.frames.sources import load_query_source

RNG = np.random.default_rng(0)
N_REF, N_QRY = 20, 12


def _frame(rng) -> np.ndarray:
    low = rng.uniform(0, 1, (4, 8, 3))
    return (resize(low, (32, 64), order=1) * 255).astype(np.uint8)


def _save(path: Path, image) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    skimage.io.imsave(path, image, check_contrast=False)


@pytest.fixture(scope="module")
def vpr_bench(tmp_path_factory):
    """DATASET/ref, DATASET/query and a ragged ground_truth_new.npy."""
    root = tmp_path_factory.mktemp("vprb") / "DATASET"
    rng = np.random.default_rng(1)
    refs = [_frame(rng) for _ in range(N_REF)]
    for i, im in enumerate(refs):
        _save(root / "ref" / f"image{i}.jpg", im)
    gt = np.empty((N_QRY, 2), object)
    for j in range(N_QRY):
        src = (3 * j) % N_REF
        noisy = np.clip(refs[src] + rng.normal(0, 8, refs[src].shape), 0, 255)
        _save(root / "query" / f"image{j}.jpg", noisy.astype(np.uint8))
        right = [src, src + 1][: 1 + j % 2] if j % 4 != 3 else []  # 1, 2 or none
        gt[j] = [j, np.array(right, np.int64) if j % 3 == 0 else right]
    np.save(root / "ground_truth_new.npy", gt, allow_pickle=True)
    return root


def _cli(cwd: Path, *argv: str) -> str:
    env = {**os.environ, "RHYTHMIC_JAX_CACHE": str(cwd / "cache")}
    proc = subprocess.run(["rhythmic-jax", *argv], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout


def test_vpr_bench_layout_through_the_installed_command(vpr_bench, tmp_path):
    fit_dir, elsewhere = tmp_path / "fit", tmp_path / "elsewhere"
    fit_dir.mkdir(), elsewhere.mkdir()
    _cli(fit_dir, "fit", str(vpr_bench / "ref"), "--out", "ds.map", "--no-progress")
    gt_file = str(vpr_bench / "ground_truth_new.npy")
    out = _cli(elsewhere, "evaluate", str(fit_dir / "ds.map"),
               str(vpr_bench / "query"), "--ground-truth", gt_file, "--json",
               "--no-progress")  # fmt: skip
    res = json.loads(out)
    assert res["ground_truth"]["source"] == f"VPR-Bench ground truth {gt_file}"
    assert res["ground_truth"]["queries_in_map"] == 9  # every 4th has no place
    # the same numbers from the library, with the lists given by hand
    model = RhythmicMap.load(fit_dir / "ds.map")
    q = load_query_source(str(vpr_bench / "query"), model, progress=False).x
    lists = [
        [] if j % 4 == 3 else [(3 * j) % N_REF, (3 * j) % N_REF + 1][: 1 + j % 2]
        for j in range(N_QRY)
    ]
    want = evaluate_map(model, q, ground_truth=from_lists(lists, N_REF, "by hand"),
                        timing=False)["methods"]["map"]  # fmt: skip
    got = res["methods"]["map"]
    for key in ("accuracy", "recall@1", "recall@5", "pr_auc", "recall@100p"):
        assert got[key] == pytest.approx(want[key]), key
    assert got["recall@1"] > 0.5 and "brute force" in res["methods"]


class _Marker:
    def __init__(self, path: Path):
        self.path = path

    def __reduce__(self):
        return (os.system, (f"touch {self.path}",))


def test_a_malicious_ground_truth_runs_no_code(vpr_bench, tmp_path, capsys):
    marker = tmp_path / "ran"
    evil = np.empty((2, 2), object)
    evil[0] = [0, [1]]
    evil[1] = [1, _Marker(marker)]
    bad = tmp_path / "ground_truth_new.npy"
    np.save(bad, evil, allow_pickle=True)
    with pytest.raises(InputError, match=r"refused: the pickle names \w+\.system"):
        safe_object_npy(bad)
    model = RhythmicMap().fit(RNG.normal(size=(N_REF, 2048)), progress=False)
    model.config = type(model.config)(descriptor="patchnorm",
                                      descriptor_settings={"width": 64, "height": 32,
                                                           "patch": 8})  # fmt: skip
    model.save(tmp_path / "m.map")
    code = main(["evaluate", str(tmp_path / "m.map"), str(vpr_bench / "query"),
                 "--ground-truth", str(bad), "--no-progress"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and err.strip().count("\n") == 0 and "refused" in err
    assert not marker.exists()
    builtins_eval = np.empty(1, object)
    builtins_eval[0] = _Eval()
    np.save(bad, builtins_eval, allow_pickle=True)
    with pytest.raises(InputError, match=r"builtins\.eval"):
        safe_object_npy(bad)
    assert not marker.exists()


class _Eval:
    def __reduce__(self):
        return (eval, ("1",))


def test_evaluate_with_positions_names_and_places(tmp_path, capsys):
    """Two traversals of different lengths grouped into places by k-means over
    their positions; queries judged by positions (metres), then by names."""
    rng = np.random.default_rng(2)
    east = np.arange(N_REF) * 10.0 + 585_000
    frames = [_frame(rng) for _ in range(N_REF)]
    for run, idx in (("run1", range(N_REF)), ("run2", range(0, N_REF, 2))):
        rows = []
        for i in idx:
            im = np.clip(frames[i] + rng.normal(0, 4, frames[i].shape), 0, 255)
            name = f"@{east[i] + rng.uniform(-2, 2):.2f}@4477000.00@17@T@{i:03d}.png"
            _save(tmp_path / run / name, im.astype(np.uint8))
            rows.append(f"{east[i]:.2f},4477000\n")
        (tmp_path / f"{run}.csv").write_text("easting,northing\n" + "".join(rows))
    qidx = np.arange(1, N_REF, 3)
    for k, i in enumerate(qidx):
        im = np.clip(frames[i] + rng.normal(0, 8, frames[i].shape), 0, 255)
        _save(tmp_path / "qry" / f"@{east[i] + 5:.2f}@4477000.00@17@T@{k:03d}.png",
              im.astype(np.uint8))  # fmt: skip
    (tmp_path / "q.csv").write_text(
        "easting,northing\n" + "".join(f"{east[i] + 5},4477000\n" for i in qidx)
    )
    fit = ["fit", str(tmp_path / "run1"), str(tmp_path / "run2"), "--out",
           str(tmp_path / "p.map"), "--positions", str(tmp_path / "run1.csv"),
           str(tmp_path / "run2.csv"), "--places", "10", "--no-progress"]  # fmt: skip
    assert main(fit) == 0, capsys.readouterr().err
    model = RhythmicMap.load(tmp_path / "p.map")
    assert model.n == 10 and model.extra["reference_labels"].shape == (30,)
    ev = ["evaluate", str(tmp_path / "p.map"), str(tmp_path / "qry"), "--json",
          "--no-progress", "--tolerance-m", "12"]  # fmt: skip
    capsys.readouterr()
    assert main([*ev, "--ground-truth", str(tmp_path / "q.csv")]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["ground_truth"]["tolerance_m"] == 12.0
    assert "q.csv" in res["ground_truth"]["source"]
    ref_xy = np.r_[np.c_[east, np.full(N_REF, 4477000.0)],
                   np.c_[east[::2], np.full(N_REF // 2, 4477000.0)]]  # fmt: skip
    truth = from_positions(ref_xy, np.c_[east[qidx] + 5, np.full(len(qidx), 4477000.0)],
                           12.0, model.extra["reference_labels"])  # fmt: skip
    q = load_query_source(str(tmp_path / "qry"), model, progress=False).x
    want = evaluate_map(model, q, ground_truth=truth, timing=False)["methods"]["map"]
    assert res["methods"]["map"]["recall@5"] == pytest.approx(want["recall@5"])
    assert res["methods"]["map"]["recall@1"] >= 0.5
    assert main([*ev, "--ground-truth", "names"]) == 0
    by_names = json.loads(capsys.readouterr().out)
    assert by_names["ground_truth"]["source"].startswith("@easting@northing@ names")
    assert by_names["ground_truth"]["queries_in_map"] == len(qidx)


def _xy_of_names(folder: Path) -> np.ndarray:
    """Positions parsed here from ``@easting@northing@`` names, in natural order
    (the frames' three-digit index decides it)."""
    names = sorted(p.name for p in folder.iterdir())
    return np.array([[float(n.split("@")[1]), float(n.split("@")[2])] for n in names])


def test_names_ground_truth_from_described_files(tmp_path, capsys):
    """``--positions names`` and ``--ground-truth names`` read the frames' names from
    the records of descriptor files ``describe`` wrote: the images may be gone, and
    the figures are those of the image folders, recomputed here from the names."""
    rng = np.random.default_rng(5)
    east = np.arange(N_REF) * 10.0 + 585_000
    frames = [_frame(rng) for _ in range(N_REF)]
    for i in range(N_REF):
        name = f"@{east[i] + rng.uniform(-2, 2):.2f}@4477000.00@17@T@{i:03d}.png"
        _save(tmp_path / "ref" / name, frames[i])
    qidx = np.arange(1, N_REF, 3)
    for k, i in enumerate(qidx):
        im = np.clip(frames[i] + rng.normal(0, 8, frames[i].shape), 0, 255)
        _save(tmp_path / "qry" / f"@{east[i] + 5:.2f}@4477000.00@17@T@{k:03d}.png",
              im.astype(np.uint8))  # fmt: skip

    def run(ref: str, qry: str, out: str) -> dict:
        fit = ["fit", ref, "--out", str(tmp_path / out), "--positions", "names",
               "--places", "10", "--no-progress"]  # fmt: skip
        assert main(fit) == 0, capsys.readouterr().err
        capsys.readouterr()
        ev = ["evaluate", str(tmp_path / out), qry, "--json", "--no-progress",
              "--tolerance-m", "12", "--ground-truth", "names"]  # fmt: skip
        assert main(ev) == 0, capsys.readouterr().err
        return json.loads(capsys.readouterr().out)

    folders = run(str(tmp_path / "ref"), str(tmp_path / "qry"), "f.map")
    for src in ("ref", "qry"):
        described = ["describe", str(tmp_path / src), "--out",
                     str(tmp_path / f"{src}.npy"), "--no-progress"]  # fmt: skip
        assert main(described) == 0, capsys.readouterr().err
    ref_xy, qry_xy = _xy_of_names(tmp_path / "ref"), _xy_of_names(tmp_path / "qry")
    for src in ("ref", "qry"):
        (tmp_path / src).rename(tmp_path / f"{src}_gone")
    files = run(str(tmp_path / "ref.npy"), str(tmp_path / "qry.npy"), "d.map")
    assert files["ground_truth"]["queries_in_map"] == len(qidx)
    for key in ("recall@1", "recall@5"):
        assert files["methods"]["map"][key] == folders["methods"]["map"][key]
    model = RhythmicMap.load(tmp_path / "d.map")
    truth = from_positions(ref_xy, qry_xy, 12.0, model.extra["reference_labels"])
    q = np.load(tmp_path / "qry.npy")
    want = evaluate_map(model, q, ground_truth=truth, timing=False)["methods"]["map"]
    assert files["methods"]["map"]["recall@5"] == pytest.approx(want["recall@5"])
    # a .npy without a record names no frames: refused in one line, saying so
    np.save(tmp_path / "bare.npy", q)
    ev = ["evaluate", str(tmp_path / "d.map"), str(tmp_path / "bare.npy"),
          "--ground-truth", "names", "--no-progress"]  # fmt: skip
    assert main(ev) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no frame names" in err[0], err


def test_positions_of_aligned_traversals_name_places(tmp_path):
    from rhythmic_jax.eval.ground_truth_files import load_ground_truth

    east = np.arange(10) * 30.0
    both = np.r_[east, east + 2.0]  # two traversals, frame i of each is place i
    np.save(tmp_path / "ref.npy", np.c_[both, np.zeros(20)])
    np.save(tmp_path / "q.npy", np.c_[east[[2, 7]] + 10, np.zeros(2)])
    specs = [str(tmp_path / "ref.npy"), str(tmp_path / "q.npy")]
    truth = load_ground_truth(specs, n_queries=2, n_places=10, query_source="q",
                              tolerance_m=15.0)  # fmt: skip
    assert [p.tolist() for p in truth.positives] == [[2], [7]]
    with pytest.raises(InputError, match="20 reference positions for a map of 7"):
        load_ground_truth(specs, n_queries=2, n_places=7, query_source="q")
    with pytest.raises(InputError, match="2 query positions for 3 queries"):
        load_ground_truth(specs, n_queries=3, n_places=10, query_source="q")


def test_pickled_positions_are_refused_unread(tmp_path):
    """A positions or ground-truth ``.npy`` of pickled objects: one line naming the
    file, nothing unpickled (NumPy's own refusal was a traceback)."""
    from rhythmic_jax.eval.ground_truth_files import load_ground_truth

    marker = tmp_path / "ran"
    evil = np.empty((3, 2), object)
    evil[:] = 1.0
    evil[0, 0] = _Marker(marker)
    bad = tmp_path / "pos.npy"
    np.save(bad, evil, allow_pickle=True)
    with pytest.raises(InputError, match=r"pos\.npy: holds pickled objects"):
        read_positions(bad)
    good = tmp_path / "ref.npy"
    np.save(good, np.zeros((3, 2)))
    for specs in ([str(good), str(bad)], [str(bad), str(good)]):
        with pytest.raises(InputError, match=r"pos\.npy: holds pickled objects"):
            load_ground_truth(specs, n_queries=3, n_places=3, query_source="q")
    (tmp_path / "junk.npy").write_bytes(b"\x93NUMPY not really")
    with pytest.raises(InputError, match=r"junk\.npy is not a valid \.npy file"):
        read_positions(tmp_path / "junk.npy")
    assert not marker.exists()


# ------------------------------------------ a format read from what a file holds


def test_a_vpr_bench_file_under_any_name_gives_its_own_recall(vpr_bench, tmp_path):
    """VPR-Bench's ground_truth_new.npy copied to an OpenVPRLab-like name (holding
    ``_gt_``) or to no telling name at all is still read as VPR-Bench's, with
    the same recall, both ways of counting it."""
    import shutil

    from rhythmic_jax.app import jobs
    from rhythmic_jax.app.specs import EvaluateJob, FitJob

    out = str(tmp_path / "ds.map")
    jobs.fit(FitJob((str(vpr_bench / "ref"),), out))
    original = vpr_bench / "ground_truth_new.npy"
    results = {}
    for name in ("ground_truth_new.npy", "corridor_gt_25m.npy", "labels.npy"):
        path = tmp_path / name
        shutil.copy(original, path)
        for over in ("matched", "all"):
            job = EvaluateJob(out, str(vpr_bench / "query"), ground_truth=(str(path),),
                              recall_over=over)  # fmt: skip
            res = jobs.evaluate(job)
            assert res["ground_truth"]["source"].startswith("VPR-Bench ground truth")
            results[name, over] = res["methods"]["map"]
    for key in ("recall@1", "recall@5", "accuracy", "pr_auc"):
        for over in ("matched", "all"):
            want = results["ground_truth_new.npy", over][key]
            assert results["corridor_gt_25m.npy", over][key] == want, key
            assert results["labels.npy", over][key] == want, key
    matched = results["ground_truth_new.npy", "matched"]
    every = results["ground_truth_new.npy", "all"]
    assert (matched["recall_queries"], every["recall_queries"]) == (9, N_QRY)
    assert every["recall@1"] == pytest.approx(matched["recall@1"] * 9 / N_QRY)


def _ragged(rows) -> np.ndarray:
    out = np.empty(len(rows), object)
    out[:] = [np.asarray(r, np.int64) for r in rows]
    return out


def test_formats_are_read_from_contents_and_names_break_ties(tmp_path):
    from rhythmic_jax.eval.ground_truth_formats import detect_format

    def fmt(name, save):
        save(tmp_path / name)
        return detect_format(tmp_path / name)

    def pickled(a):
        def save(path):
            with open(path, "wb") as f:  # under the name given, .npy or not
                np.save(f, a, allow_pickle=True)

        return save

    bench = np.empty((3, 2), object)
    bench[:] = [[0, [1, 2]], [1, np.array([0])], [2, []]]
    for name in ("ground_truth_new.npy", "x_gt_25m.npy", "gt.dat"):
        assert fmt(name, pickled(bench)) == "vpr-bench"
    for name in ("nord_gt_25m.npy", "ground_truth_new.npy"):
        assert fmt(name, pickled(_ragged([[0, 1], [4], []]))) == "openvprlab"
    tutorial = {"GThard": np.eye(4, dtype=bool), "GTsoft": np.eye(4, dtype=bool)}
    assert fmt("any.npz", lambda p: np.savez(p, **tutorial)) == "vpr-tutorial"
    pnv = {"utmQ": np.zeros((3, 2)), "utmDb": np.ones((4, 2)), "posDistThr": 25.0}
    assert fmt("GT.npz", lambda p: np.savez(p, **pnv)) == "patch-netvlad"
    assert fmt("q_gt_25m.npy", lambda p: np.save(p, np.zeros((5, 2)))) == "positions"
    three = np.arange(15).reshape(5, 3)
    assert fmt("pos.npy", lambda p: np.save(p, three)) == "openvprlab"  # k = 3
    # integer (b, 2): positions or two positives a query; the name decides
    two = np.arange(10).reshape(5, 2)
    assert fmt("pos.npy", lambda p: np.save(p, two)) == "positions"
    assert fmt("nord_gt_25m.npy", lambda p: np.save(p, two)) == "openvprlab"
    csv = "easting,northing\n1,2\n"
    assert fmt("q.csv", lambda p: p.write_text(csv)) == "positions"


def test_a_file_of_no_format_is_refused_naming_what_it_holds(tmp_path):
    from rhythmic_jax.eval.ground_truth_formats import detect_format

    np.savez(tmp_path / "GT.npz", hard=np.zeros((3, 4), bool), thr=np.float32(25))
    with pytest.raises(InputError) as err:
        detect_format(tmp_path / "GT.npz")
    line = str(err.value)
    assert "hard: bool (3, 4), thr: float32 ()" in line and "GThard" in line
    assert "\n" not in line
    np.save(tmp_path / "x_gt_25m.npy", np.zeros((2, 3, 4), np.float32))
    with pytest.raises(InputError, match=r"holds a \.npy of float32 \(2, 3, 4\)"):
        detect_format(tmp_path / "x_gt_25m.npy")
    rows = np.empty(2, object)
    rows[:] = [["a", "b"], ["c"]]
    np.save(tmp_path / "ground_truth_new.npy", rows, allow_pickle=True)
    with pytest.raises(InputError, match=r"row 0 a list of 2: str, str"):
        detect_format(tmp_path / "ground_truth_new.npy")


def test_the_format_said_outright(tmp_path, capsys):
    """``fmt`` (``--ground-truth-format``) reads a file as that format: an integer
    (b, 2) file under a plain name is positions unless said to be positives."""
    two = np.array([[0, 1], [2, 3], [1, 4]])
    np.save(tmp_path / "pairs.npy", two)
    truth = load_ground_truth([str(tmp_path / "pairs.npy")], n_queries=3,
                              n_places=5, query_source="q",
                              fmt="openvprlab")  # fmt: skip
    assert [p.tolist() for p in truth.positives] == two.tolist()
    with pytest.raises(InputError, match="holds no reference positions"):
        load_ground_truth([str(tmp_path / "pairs.npy")], n_queries=3, n_places=5,
                          query_source="q")  # fmt: skip
    with pytest.raises(InputError, match="ground_truth_format vpr-bench: one file"):
        load_ground_truth([str(tmp_path / "pairs.npy")] * 2, n_queries=3,
                          n_places=5, query_source="q", fmt="vpr-bench")  # fmt: skip
    argv = ["evaluate", "m.map", "q.npy", "--ground-truth-format", "vpr-bench"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "--ground-truth-format needs --ground-truth" in err
    argv = ["frontier", "r.npy", "q.npy", "--ground-truth-format", "positions"]
    assert main(argv) == 2
    assert "--ground-truth-format needs --ground-truth" in capsys.readouterr().err


def test_the_command_line_offers_every_format_and_denominator():
    from rhythmic_jax.app import specs
    from rhythmic_jax.eval.ground_truth_formats import FORMATS
    from rhythmic_jax.eval.metrics import RECALL_OVER

    assert specs.GROUND_TRUTH_FORMATS == FORMATS
    assert specs.RECALL_OVER == RECALL_OVER
