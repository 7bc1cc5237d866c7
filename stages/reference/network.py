"""The reference keypoint CNN: a small encoder-decoder that outputs one heatmap per target
keypoint at half (``stride`` 2) or a quarter (4) of the input resolution (torch; imported
only by training).

Input (N, 1, 192, 192) normalised grey (a mono camera's, as SPEED+'s) or (N, 3, ...) RGB;
output (N, 11, 96, 96) or (N, 11, 48, 48). About
0.2 G multiply-adds per image at stride 4: small enough to train on two CPU cores.
"""

from __future__ import annotations

import torch
from torch import nn


def _conv(c_in: int, c_out: int, stride: int = 1, dilation: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, 3, stride, padding=dilation, dilation=dilation, bias=False),
                         nn.BatchNorm2d(c_out), nn.ReLU(inplace=True))


class _Residual(nn.Module):
    def __init__(self, channels: int, dilation: int = 1) -> None:
        super().__init__()
        self.body = nn.Sequential(_conv(channels, channels, dilation=dilation),
                                  nn.Conv2d(channels, channels, 3, padding=dilation, dilation=dilation, bias=False),
                                  nn.BatchNorm2d(channels))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.relu(x + self.body(x))


class KeypointNet(nn.Module):
    """Heatmaps (N, K, H/4, W/4) of K keypoints for images (N, C, H, W): C = 1 (grey) or 3."""

    def __init__(self, keypoints: int = 11, width: int = 16, stride: int = 4, channels: int = 1) -> None:
        super().__init__()
        c1, c2, c3, c4 = width, 2 * width, 3 * width, 4 * width
        self.stride = stride
        self.first = _conv(channels, c1, 2)                                                         # 1/2
        self.stem = _conv(c1, c2, 2)                                                         # 1/4
        self.down1 = nn.Sequential(_conv(c2, c3, 2), _Residual(c3), _Residual(c3))           # 1/8
        self.down2 = nn.Sequential(_conv(c3, c4, 2), _Residual(c4, 2), _Residual(c4, 4))     # 1/16
        self.up1 = _conv(c4 + c3, c3)
        self.up2 = _conv(c3 + c2, c2)
        # stride 2: one more level back to half resolution, with the first layer's features
        self.up3 = _conv(c2 + c1, c1) if stride == 2 else None
        self.head = nn.Conv2d(c1 if stride == 2 else c2, keypoints, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        half = self.first(x)
        quarter = self.stem(half)
        eighth = self.down1(quarter)
        sixteenth = self.down2(eighth)
        up = nn.functional.interpolate(sixteenth, size=eighth.shape[-2:], mode="bilinear", align_corners=False)
        up = self.up1(torch.cat([up, eighth], 1))
        up = nn.functional.interpolate(up, size=quarter.shape[-2:], mode="bilinear", align_corners=False)
        up = self.up2(torch.cat([up, quarter], 1))
        if self.up3 is not None:
            up = nn.functional.interpolate(up, size=half.shape[-2:], mode="bilinear", align_corners=False)
            up = self.up3(torch.cat([up, half], 1))
        return self.head(up)
