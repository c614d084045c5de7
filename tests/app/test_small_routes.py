"""Small routes: what cannot be trained on the route is skipped with a note
(``frontier``) or refused in one line (``fit --codes``), never a traceback from
faiss; from 2 places up, on descriptors of 512 and 2048 dimensions."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rhythmic_jax.app.cli import main
from rhythmic_jax.eval.frontier import FrontierConfig, pq_bits, trainable
from rhythmic_jax.map.codes import fit_codes


def run(capsys, *argv):
    code = main([*argv])
    out, err = capsys.readouterr()
    return code, out, err


def _route(folder, n: int, d: int):
    """Unit-norm references (n, d) and queries near them, as .npy files."""
    rng = np.random.default_rng(n * 7 + d)
    x = rng.normal(size=(n, d)).astype(np.float32)
    q = x + 0.3 * rng.normal(size=x.shape).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    ref, qry = folder / f"r{n}_{d}.npy", folder / f"q{n}_{d}.npy"
    np.save(ref, x)
    np.save(qry, q)
    return str(ref), str(qry)


@pytest.mark.parametrize("n", [1, 2, 10, 111, 200, 256, 3000])
@pytest.mark.parametrize("d", [64, 512, 2048])
def test_trainable_keeps_what_faiss_can_fit(n, d):
    """Every ITQ size kept is at most min(n, d) (faiss's PCA limit), every one
    left out is named in a note; PQ keeps the sizes that divide d."""
    cfg = FrontierConfig(bits=(32, 64, 128, 256, 512), pq=(8, 16, 24, 32, 64))
    kept, notes = trainable(cfg, n, d)
    assert kept.bits == tuple(b for b in cfg.bits if b <= min(n, d))
    dropped = [b for b in cfg.bits if b not in kept.bits]
    if dropped:
        itq = next(line for line in notes if line.startswith("ITQ bits"))
        assert all(str(b) in itq for b in dropped) and "skipped" in itq
    assert kept.pq == (tuple(m for m in cfg.pq if d % m == 0) if n >= 2 else ())
    assert (pq_bits(n) < 8 and n >= 2) == any("-bit sub-quantisers" in x for x in notes)
    assert kept.maps == cfg.maps and kept.lengths == cfg.lengths


@pytest.mark.parametrize("n, bits", [(2, 2), (10, 10), (111, 111), (12, 11)])
def test_itq_fits_at_its_limit_and_refuses_above_it(n, bits):
    """ITQ of exactly min(n, d) bits fits; one bit more is refused in one line
    before faiss (which would stop in PCAMatrix::prepare_Ab)."""
    from rhythmic_jax.errors import InputError

    x = np.random.default_rng(n).normal(size=(n, 512)).astype(np.float32)
    assert fit_codes(x, bits).projection.shape == (bits, 512)
    with pytest.raises(InputError, match=f"at most {n} bits on {n} places"):
        fit_codes(x, n + 1)


@pytest.mark.parametrize("n, d", [(2, 512), (10, 2048), (111, 512), (200, 2048)])
def test_fit_codes_on_small_routes_is_a_map_or_one_line(tmp_path, capsys, n, d):
    """``fit --codes 256``: one line naming the limit below 256 places; the
    largest size the route can train, and int8, fit."""
    ref, _ = _route(tmp_path, n, d)
    code, out, err = run(capsys, "fit", ref, "--out", str(tmp_path / "a.map"),
                         "--codes", "256", "--no-progress")  # fmt: skip
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert f"--codes 256: at most {n} bits on {n} places" in err
    assert not (tmp_path / "a.map").exists()
    for codes in (str(min(n, d)), "int8"):
        code, out, err = run(capsys, "fit", ref, "--out", str(tmp_path / codes),
                             "--codes", codes, "--no-progress")  # fmt: skip
        assert code == 0, err
        assert f"map {tmp_path / codes}: n={n} d={d}" in out


def _frontier(capsys, tmp_path, n, d):
    ref, qry = _route(tmp_path, n, d)
    code, out, err = run(capsys, "frontier", ref, qry, "--maps", "2:1",
                         "--grid", "full", "--json", "--no-progress")  # fmt: skip
    assert code == 0, err
    assert "Traceback" not in err
    result = json.loads(out)
    names = [r["name"] for r in result["rows"]]
    for bits in (32, 64, 128, 256, 512):
        assert (f"ITQ {bits} bits" in names) == (bits <= min(n, d)), names
    skipped = [b for b in (32, 64, 128, 256, 512) if b > min(n, d)]
    if skipped:
        assert result["skipped"][0].startswith("ITQ bits " + str(skipped[0]))
    assert "brute force" in names and any(x.startswith("map r=2") for x in names)
    assert sum(x.startswith("PQ ") for x in names) == 4  # 8, 16, 32, 64 divide d
    return result


@pytest.mark.parametrize("n, d", [(2, 512), (10, 2048)])
def test_frontier_on_a_few_places_skips_with_a_note(tmp_path, capsys, n, d):
    result = _frontier(capsys, tmp_path, n, d)
    assert result["n"] == n and len(result["skipped"]) == 2  # ITQ bits, PQ bits


@pytest.mark.slow
@pytest.mark.parametrize("n, d", [(111, 512), (200, 2048), (111, 2048), (200, 512)])
def test_frontier_on_a_corridor_skips_with_a_note(tmp_path, capsys, n, d):
    result = _frontier(capsys, tmp_path, n, d)
    assert any(r["name"] == "ITQ 64 bits" for r in result["rows"])
    code, out, err = run(capsys, "frontier", str(tmp_path / f"r{n}_{d}.npy"),
                         str(tmp_path / f"q{n}_{d}.npy"), "--maps", "2:1",
                         "--grid", "full", "--no-progress")  # fmt: skip
    assert code == 0, err
    skipped = ", ".join(str(b) for b in (128, 256, 512) if b > min(n, d))
    assert f"ITQ bits {skipped}: skipped" in out
