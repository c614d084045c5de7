"""The one order of frame names: numbers as numbers, the same for image folders
and hloc's names, total (ties broken by the name) whatever order names come in."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from rhythmic_jax.io.images import list_images
from rhythmic_jax.io.names import name_key, natural_order, natural_sorted


def test_numbers_compare_as_numbers():
    names = ["frame100", "frame10", "frame2", "frame1", "frame20"]
    assert natural_sorted(names) == [
        "frame1",
        "frame2",
        "frame10",
        "frame20",
        "frame100",
    ]
    assert natural_order(names) == [3, 2, 1, 4, 0]
    assert natural_sorted(["b1", "a10", "a9"]) == ["a9", "a10", "b1"]
    # text and numbers interleaved: a2c < a10b (2 < 10 before c against b)
    assert natural_sorted(["a10b1", "a2c1"]) == ["a2c1", "a10b1"]


def test_folders_components_suffix_and_ties():
    names = ["query/frame1.jpg", "db/frame10.jpg", "db/frame9.jpg", "db/sub/frame1.jpg"]
    assert natural_sorted(names) == [
        "db/frame9.jpg", "db/frame10.jpg", "db/sub/frame1.jpg", "query/frame1.jpg",
    ]  # fmt: skip
    # the suffix does not order frames: frame2.png before frame10.jpg
    assert natural_sorted(["frame10.jpg", "frame2.png"]) == [
        "frame2.png",
        "frame10.jpg",
    ]
    # ties (padding, case) broken by the name itself, in every input order
    tied = ["frame10.png", "frame010.png", "Frame10.png"]
    want = natural_sorted(tied)
    assert natural_sorted(tied[::-1]) == want == ["Frame10.png", "frame010.png",
                                                  "frame10.png"]  # fmt: skip
    assert len({name_key(n) for n in tied}) == 3


NAME = r"[a-zA-Z/]{0,2}[0-9]{0,3}[a-z]?(\.png)?"


@settings(max_examples=50, deadline=None)
@given(st.lists(st.from_regex(NAME, fullmatch=True), max_size=12, unique=True))
def test_the_order_is_total_and_deterministic(names):
    rng = np.random.default_rng(len(names))
    shuffled = [names[i] for i in rng.permutation(len(names))]
    assert natural_sorted(shuffled) == natural_sorted(names)
    assert len({name_key(n) for n in names}) == len(names)


def test_an_image_folder_lists_in_the_same_order(tmp_path, rgb, write_image):
    names = [f"frame{i}.png" for i in (1, 2, 10, 11, 100, 3)]
    for name in names:
        write_image(tmp_path, name, rgb(8, 8))
    listed = [p.name for p in list_images(tmp_path, "traversal")]
    assert listed == natural_sorted(names)
    assert listed == ["frame1.png", "frame2.png", "frame3.png", "frame10.png",
                      "frame11.png", "frame100.png"]  # fmt: skip
