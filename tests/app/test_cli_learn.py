"""learn -> fit -> query -> evaluate through the installed command, elsewhere."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from map.test_embedding import two_conditions


def _cli(*argv, cwd, env):
    script = shutil.which("rhythmic-jax")
    cmd = [script] if script else [sys.executable, "-m", "rhythmic_jax.app.cli"]
    proc = subprocess.run(
        [*cmd, *argv], cwd=cwd, env=env, capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


@pytest.mark.slow
def test_learn_fit_query_evaluate_from_another_directory(tmp_path):
    data, work = tmp_path / "data", tmp_path / "elsewhere"
    data.mkdir()
    work.mkdir()
    a, b = two_conditions(n=400, strength=4.0, seed=5)
    for name, x in (("a_train", a[:180]), ("b_train", b[:180]),
                    ("a_test", a[200:]), ("b_test", b[200:])):  # fmt: skip
        np.save(data / f"{name}.npy", x)
    env = {**os.environ, "RHYTHMIC_JAX_CACHE": str(tmp_path / "cache")}
    out = _cli("learn", str(data / "a_train.npy"), str(data / "b_train.npy"),
               "--out", "route.emb", "--k", "40", "--no-progress",
               cwd=work, env=env)  # fmt: skip
    assert "linear 48 -> 40" in out
    _cli("fit", str(data / "a_test.npy"), "--embedding", "route.emb",
         "--out", "route.map", "--no-progress", cwd=work, env=env)  # fmt: skip
    _cli("fit", str(data / "a_test.npy"), "--out", "plain.map", "--no-progress",
         cwd=work, env=env)  # fmt: skip
    info = json.loads(_cli("info", "route.map", "--json", cwd=work, env=env))
    assert info["embedding"] == {"kind": "linear", "k": 40} and info["d"] == 48
    assert info["embedding_bytes"] == 4 * (48 + 48 * 40)
    text = _cli("info", "route.map", cwd=work, env=env)
    assert "embedding_bytes" in text
    _cli("query", "route.map", str(data / "b_test.npy"), "--decode", "soft",
         "--out", "pred.npy", "--no-progress", cwd=work, env=env)  # fmt: skip
    pred = np.load(work / "pred.npy")
    _cli("query", "plain.map", str(data / "b_test.npy"), "--decode", "soft",
         "--out", "plain.npy", "--no-progress", cwd=work, env=env)  # fmt: skip
    plain = np.load(work / "plain.npy")
    gt = np.arange(200)
    assert np.mean(pred == gt) > np.mean(plain == gt) + 0.1
    ev = json.loads(_cli("evaluate", "route.map", str(data / "b_test.npy"),
                         "--decode", "soft", "--json", "--no-progress",
                         cwd=work, env=env))  # fmt: skip
    assert ev["methods"]["map"]["accuracy"] == np.mean(pred == gt)
    assert ev["methods"]["map"]["embedding_bytes"] == info["embedding_bytes"]


@pytest.mark.slow  # a learn and two fits of hog descriptors: about 2 min on 2 cores
def test_fit_takes_the_descriptor_and_fusion_weight_from_the_embedding(
    tmp_path, capsys
):
    """Learned on hog descriptors, the embedding makes ``fit FOLDER --embedding``
    describe with hog (not the default patchnorm) and fuse with its weight;
    ``--fusion`` still wins; ``info`` says where each came from."""
    from skimage import data as skdata
    from skimage.io import imsave
    from skimage.transform import resize

    from rhythmic_jax import RhythmicMap
    from rhythmic_jax.app.cli import main
    from rhythmic_jax.map.embedding import load_embedding

    photo = resize(skdata.astronaut(), (96, 640), anti_aliasing=True)
    frames = [(photo[:, 8 * i : 8 * i + 64] * 255).astype(np.uint8) for i in range(72)]
    rng = np.random.default_rng(0)
    for name, gain in (("a", 1.0), ("b", 0.6)):
        (tmp_path / name).mkdir()
        for i, f in enumerate(frames):
            f = f * gain + 20 * rng.normal(size=f.shape)
            img = np.clip(f, 0, 255).astype(np.uint8)
            imsave(tmp_path / name / f"frame{i:02d}.png", img, check_contrast=False)

    def cli(*argv):
        code = main([*argv, "--no-progress"] if argv[0] != "info" else list(argv))
        out, err = capsys.readouterr()
        assert code == 0, err
        return out

    emb = str(tmp_path / "e")
    cli("learn", str(tmp_path / "a"), str(tmp_path / "b"), "--descriptor", "hog",
        "--k", "16", "--out", emb)  # fmt: skip
    meta = load_embedding(emb)[1]
    w = meta["fusion"]["weight"]
    assert meta["descriptor"] == "hog" and meta["fusion"]["codes"] == "int8"
    cli("fit", str(tmp_path / "a"), "--embedding", emb, "--codes", "int8",
        "--out", str(tmp_path / "m"))  # fmt: skip
    m = RhythmicMap.load(tmp_path / "m")
    assert m.config.descriptor == "hog" and m.config.fusion == w
    text = cli("info", str(tmp_path / "m"))
    assert "descriptor hog taken from it" in text
    assert f"fusion: {w:g} (embedding: learned with the embedding" in text
    cli("fit", str(tmp_path / "a"), "--embedding", emb, "--codes", "int8",
        "--fusion", "0.8", "--out", str(tmp_path / "m2"))  # fmt: skip
    assert RhythmicMap.load(tmp_path / "m2").config.fusion == 0.8
    assert "fusion: 0.8 (option" in cli("info", str(tmp_path / "m2"))


def _learned(tmp_path, capsys, k: int):
    """``learn`` of two synthetic conditions of 200 places: (stdout, the
    warning lines on stderr, the saved held-out figures)."""
    from rhythmic_jax.app.cli import main
    from rhythmic_jax.map.embedding import load_embedding

    a, b = two_conditions(n=200, strength=4.0, seed=11)
    np.save(tmp_path / "a.npy", a)
    np.save(tmp_path / "b.npy", b)
    out = tmp_path / f"k{k}.emb"
    status = main(["learn", str(tmp_path / "a.npy"), str(tmp_path / "b.npy"),
                   "--out", str(out), "--k", str(k), "--no-progress"])  # fmt: skip
    got = capsys.readouterr()
    assert status == 0, got.err
    warned = [line for line in got.err.splitlines() if ": warning: " in line]
    held = load_embedding(out)[1]["learn"]["held_out"]
    assert main(["info", str(out)]) == 0
    assert f"held out: R@1 {held['embedded']:.3f} on 40" in capsys.readouterr().out
    return got.out, warned, held


def test_learn_prints_recall_on_held_out_places_and_warns_in_one_line(tmp_path, capsys):
    """200 places: the last 40 held out after a gap of 10, 150 learned from.
    k = 40 is 3.75 learning places a dimension: one warning line; k = 8 is
    plenty and the embedding beats the raw codes there: no warning."""
    text, warned, held = _learned(tmp_path, capsys, 40)
    assert held["places"] == 40
    assert (f"R@1 {held['embedded']:.3f} on 40 held-out places of the training "
            "route (not used to learn") in text  # fmt: skip
    assert "150 places x 2 traversals" in text
    assert any("150 learning places for 40 embedded dimensions" in w and "--k" in w
               for w in warned), warned  # fmt: skip
    assert len(warned) == len(set(warned)) and all("\n" not in w for w in warned)
    text, warned, held = _learned(tmp_path, capsys, 8)
    assert held["embedded"] >= held["raw"] and warned == [], (held, warned)
