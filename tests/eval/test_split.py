import numpy as np
import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.split import NORDLAND_SPLIT, PlaceSplit, route_split


def test_nordland_split_is_disjoint_with_its_gap():
    s = NORDLAND_SPLIT
    assert s.train[0] == 0 and s.train[-1] == 1199
    assert s.test[0] == 1220 and s.test[-1] == 3575 and len(s.test) == 2356
    assert np.intersect1d(s.train, s.test).size == 0
    assert s.distance() == 21  # 1220 - 1199


def test_route_split_gap_is_the_distance():
    for gap in (0, 3, 10):
        assert route_split(50, 20, gap).distance() == gap + 1


def test_shared_places_are_refused():
    with pytest.raises(InputError, match="both train and test"):
        PlaceSplit(train=np.arange(10), test=np.arange(9, 20), gap=0)


@pytest.mark.parametrize(
    "args", [(10, 0, 0), (10, 5, -1), (10, 9, 1), (1, 1, 0), (10, 2.5, 0)]
)
def test_bad_route_splits(args):
    with pytest.raises(InputError):
        route_split(*args)
