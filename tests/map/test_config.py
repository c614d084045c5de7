"""The map's configuration: one JAX-free module, checked once, offered by the CLI."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from rhythmic_jax import InputError
from rhythmic_jax.map.config import (
    DECODERS,
    DTYPES,
    INT8,
    SOLVERS,
    MapConfig,
    check_weight,
    codes_setting,
)


def test_the_config_and_its_defaults_import_no_jax_and_no_numpy():
    code = (
        "import sys, rhythmic_jax.map.config as c; c.MapConfig(); "
        "print('jax' in sys.modules, 'numpy' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False False"


@pytest.mark.parametrize(
    "settings, line",
    [
        (dict(solver="sgd"), "solver must be one of ('newton', 'lbfgs'), got 'sgd'"),
        (dict(dtype="float64"), "dtype must be one of ('float32', 'float16', "
         "'int8'), got 'float64'"),
        (dict(decode="best"), "decode must be one of ('hard', 'soft', 'topm'), got "
         "'best'"),
        (dict(gap=1), "gap must be in (0, 1), got 1"),
        (dict(gap=0.0), "gap must be in (0, 1), got 0.0"),
        (dict(c=0.0), "c must be positive, got 0.0"),
        (dict(codes=0), "codes must be a number of ITQ bits >= 1 or 'int8' (a byte "
         "per dimension), got 0"),
        (dict(codes=True), "codes must be a number of ITQ bits >= 1 or 'int8' (a "
         "byte per dimension), got True"),
        (dict(fusion=1.5), "fusion weight must be a number in [0, 1], got 1.5"),
        (dict(threshold=float("nan")), "threshold must be a finite number, got nan"),
        (dict(layout="spiral"), "layout 'spiral': expected"),
    ],
)  # fmt: skip
def test_a_bad_setting_is_refused_when_made_in_one_line(settings, line):
    with pytest.raises(InputError) as err:
        MapConfig(**settings)
    assert str(err.value).startswith(line), str(err.value)
    assert "\n" not in str(err.value)


def test_the_words_and_the_checks_of_settings():
    assert SOLVERS == ("newton", "lbfgs") and DECODERS == ("hard", "soft", "topm")
    assert DTYPES == ("float32", "float16", "int8")
    assert codes_setting(INT8) == "int8" and codes_setting(np.int64(12)) == 12
    assert check_weight(np.float32(0.25)) == 0.25
    with pytest.raises(InputError, match="fusion weight"):
        check_weight(False)
    config = MapConfig(r=3, codes="int8", layout="mixed:8,9", fusion=0)
    assert (config.r, config.codes, config.layout) == (3, "int8", "mixed:8,9")
    with pytest.raises(AttributeError):
        config.r = 2  # frozen


def test_modules_that_act_on_the_words_share_them():
    from rhythmic_jax.decoding.dispatch import DECODERS as dispatched
    from rhythmic_jax.map.codes import INT8 as codes_int8
    from rhythmic_jax.map.quantize import DTYPES as stored

    assert dispatched is DECODERS and stored is DTYPES and codes_int8 == INT8


def test_the_command_line_offers_the_config_defaults_and_words():
    from rhythmic_jax.app.cli import _parser

    parser = _parser()
    fit = {a.dest: a for a in parser.commands["fit"]._actions}
    default = MapConfig()
    for name in ("r", "level", "count", "c", "solver", "gap", "layout", "dtype"):
        assert fit[name].default == getattr(default, name), name
    assert tuple(fit["solver"].choices) == SOLVERS
    assert tuple(fit["dtype"].choices) == DTYPES
    for command in ("query", "evaluate"):
        actions = {a.dest: a for a in parser.commands[command]._actions}
        assert tuple(actions["decode"].choices) == DECODERS
    args = parser.parse_args(["fit", "x.npy", "--out", "m", "--solver", "lbfgs"])
    assert args.solver == "lbfgs" and args.dtype == "float32"
