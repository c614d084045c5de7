"""The torch networks: ImageNet classes of scikit-image's photographs, the feature
tap, and VGG16 against a functional re-computation from its state dict."""

from __future__ import annotations

import numpy as np
import pytest
import skimage.data
import torch
import torch.nn.functional as F

from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.nets import (
    VGG16,
    EfficientNetLite0,
    lite0_weights_path,
    load_efficientnet_lite0,
    load_vgg16,
)


@pytest.fixture(autouse=True)
def one_thread():
    """Leave the second core to the other tests running beside these."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def lite0() -> EfficientNetLite0:
    return load_efficientnet_lite0()


def _imagenet_input(image: np.ndarray) -> torch.Tensor:
    """uint8 (H, W, 3) -> (1, 3, 224, 224) in [0, 1]: the centred square, resized."""
    h, w = image.shape[:2]
    s = min(h, w)
    y, x = (h - s) // 2, (w - s) // 2
    t = torch.from_numpy(np.ascontiguousarray(image[y : y + s, x : x + s, :3]))
    t = t.permute(2, 0, 1)[None].float() / 255.0
    return F.interpolate(t, (224, 224), mode="bilinear", antialias=True)


# ImageNet class indices: 281 tabby, 282 tiger cat, 285 Egyptian cat,
# 967 espresso, 657 missile, 665 moped.
PHOTOS = {
    "chelsea": (lambda: skimage.data.chelsea(), {281, 282, 285}),
    "coffee": (lambda: skimage.data.coffee(), {967}),
    "rocket": (lambda: skimage.data.rocket(), {657}),
    "motorcycle_left": (lambda: skimage.data.stereo_motorcycle()[0], {665}),
}


def test_lite0_names_the_imagenet_class(lite0):
    batch = torch.cat([_imagenet_input(load()) for load, _ in PHOTOS.values()])
    with torch.inference_mode():
        top1 = lite0(batch.contiguous(memory_format=torch.channels_last)).argmax(1)
    for (name, (_, classes)), got in zip(PHOTOS.items(), top1.tolist(), strict=True):
        assert got in classes, f"{name}: top-1 class {got}, expected one of {classes}"


def test_lite0_tap_shape_and_consistency(lite0):
    x = torch.rand(2, 3, 112, 224)
    with torch.inference_mode():
        tap = lite0.features(x, 10)
        assert tap.shape == (2, 112, 7, 14)  # 10,976 values: the default descriptor
        # the tap is a prefix of the full network: continuing from it gives the logits
        y = tap
        for block in lite0._blocks[11:]:
            y = block(y)
        y = F.relu6(lite0._bn1(lite0._conv_head(y))).mean(dim=(2, 3))
        torch.testing.assert_close(lite0._fc(y), lite0(x))
    for block in range(16):
        s = EfficientNetLite0.block_stride(block)
        c = EfficientNetLite0.block_channels(block)
        with torch.inference_mode():
            shape = lite0.features(torch.rand(1, 3, 40, 72), block).shape
        assert shape == (1, c, -(-40 // s), -(-72 // s))


def test_lite0_weights_file_errors(tmp_path):
    state = torch.load(lite0_weights_path(), weights_only=True)
    state.pop("_fc.bias")
    state["_fc.extra"] = torch.zeros(1)
    path = tmp_path / "lite0.pth"
    torch.save(state, path)
    with pytest.raises(
        InputError, match=r"missing \[_fc.bias\].*unexpected \[_fc.extra\]"
    ):
        load_efficientnet_lite0(path)
    with pytest.raises(InputError, match="not found"):
        load_efficientnet_lite0(tmp_path / "absent.pth")


def _fc7_reference(state: dict, x: torch.Tensor) -> torch.Tensor:
    """VGG16 fc7 computed layer by layer from the torchvision state dict."""
    mean = torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)
    std = torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
    y = (x - mean) / std
    convs = sorted({int(k.split(".")[1]) for k in state if k.startswith("features.")})
    pool_after = {2, 7, 14, 21, 28}  # last conv before each max pool (4, 9, ..., 30)
    for i in convs:
        y = F.relu(
            F.conv2d(
                y, state[f"features.{i}.weight"], state[f"features.{i}.bias"], padding=1
            )
        )
        if i in pool_after:
            y = F.max_pool2d(y, 2)
    y = F.adaptive_avg_pool2d(y, 7).flatten(1)
    y = F.relu(F.linear(y, state["classifier.0.weight"], state["classifier.0.bias"]))
    return F.relu(F.linear(y, state["classifier.3.weight"], state["classifier.3.bias"]))


@pytest.fixture(scope="module")
def vgg_file(tmp_path_factory):
    """A randomly initialised torchvision-layout VGG16 state dict on disk."""
    torch.manual_seed(0)
    net = VGG16()
    state = net.state_dict()
    path = tmp_path_factory.mktemp("vgg") / "vgg16.pth"
    torch.save(state, path)
    return path, state


def test_vgg16_fc7_matches_functional_reference(vgg_file):
    path, state = vgg_file
    assert len(state) == 32  # 13 convs + 3 linears, weight and bias each
    net = load_vgg16(path)
    x = torch.rand(2, 3, 64, 48)
    with torch.inference_mode():
        fc7 = net.fc7(x.contiguous(memory_format=torch.channels_last))
        ref = _fc7_reference(state, x)
        assert fc7.shape == (2, 4096)
        torch.testing.assert_close(fc7, ref, rtol=1e-4, atol=1e-5)
        logits = net(x)
    assert logits.shape == (2, 1000)
    assert float(ref.abs().sum()) > 0  # random weights still give a live fc7


def test_vgg16_bad_files(vgg_file, tmp_path):
    path, state = vgg_file
    with pytest.raises(InputError, match="not found"):
        load_vgg16(tmp_path / "absent.pth")
    # small stand-in tensors keep the files tiny; keys are checked before shapes
    part = {k: torch.zeros(1) for k in state if k != "classifier.6.weight"}
    torch.save(part, tmp_path / "part.pth")
    with pytest.raises(InputError, match=r"missing \[classifier.6.weight\]"):
        load_vgg16(tmp_path / "part.pth")
    torch.save(
        dict(part, **{"classifier.6.weight": torch.zeros(1)}), tmp_path / "w.pth"
    )
    with pytest.raises(InputError, match="32 tensors have the wrong shape"):
        load_vgg16(tmp_path / "w.pth")
    (tmp_path / "junk.pth").write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="junk.pth"):
        load_vgg16(tmp_path / "junk.pth")
