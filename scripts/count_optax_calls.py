"""How many optax calls a default ``RhythmicMap.fit`` makes.

Every public callable of ``optax`` (and of ``optax.tree_utils``) is wrapped with a
counter before the package under test is imported, then a default map is fitted
on random unit descriptors and the calls are printed by name. Run against another
checkout with ``PYTHONPATH=/that/checkout``.

    python scripts/count_optax_calls.py --n 600 --d 64
"""

from __future__ import annotations

import argparse
import collections
import functools
import json

import numpy as np
import optax

COUNTS: collections.Counter[str] = collections.Counter()


def _wrap(module, prefix: str) -> None:
    for name in dir(module):
        value = getattr(module, name)
        if name.startswith("_") or not callable(value) or isinstance(value, type):
            continue

        def counted(*args, _f=value, _n=f"{prefix}.{name}", **kwargs):
            COUNTS[_n] += 1
            return _f(*args, **kwargs)

        setattr(module, name, functools.wraps(value)(counted))


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=600)
    ap.add_argument("--d", type=int, default=64)
    args = ap.parse_args(argv)
    _wrap(optax, "optax")
    _wrap(optax.tree_utils, "optax.tree_utils")
    import rhythmic_jax

    rng = np.random.default_rng(0)
    x = rng.standard_normal((args.n, args.d)).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    model = rhythmic_jax.RhythmicMap().fit(x, progress=False)
    out = {
        "package": rhythmic_jax.__file__,
        "n": args.n,
        "d": args.d,
        "solver": model.config.solver,
        "periods": list(model.periods),
        "optax_calls": sum(COUNTS.values()),
        "by_name": dict(COUNTS.most_common()),
    }
    print(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
