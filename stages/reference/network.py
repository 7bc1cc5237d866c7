"""The reference keypoint CNN: a small encoder-decoder that outputs one heatmap per Tango
keypoint at a quarter of the input resolution (torch; imported only by training).

Input (N, 3, 192, 192) normalised RGB; output (N, 11, 48, 48). About 0.2 G multiply-adds
per image: small enough to train on two CPU cores in under half an hour.
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
    """Heatmaps (N, K, H/4, W/4) of K keypoints for images (N, 3, H, W)."""

    def __init__(self, keypoints: int = 11, width: int = 16) -> None:
        super().__init__()
        c1, c2, c3, c4 = width, 2 * width, 3 * width, 4 * width
        self.stem = nn.Sequential(_conv(3, c1, 2), _conv(c1, c2, 2))                         # 1/4
        self.down1 = nn.Sequential(_conv(c2, c3, 2), _Residual(c3), _Residual(c3))           # 1/8
        self.down2 = nn.Sequential(_conv(c3, c4, 2), _Residual(c4, 2), _Residual(c4, 4))     # 1/16
        self.up1 = _conv(c4 + c3, c3)
        self.up2 = _conv(c3 + c2, c2)
        self.head = nn.Conv2d(c2, keypoints, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        quarter = self.stem(x)
        eighth = self.down1(quarter)
        sixteenth = self.down2(eighth)
        up = nn.functional.interpolate(sixteenth, size=eighth.shape[-2:], mode="bilinear", align_corners=False)
        up = self.up1(torch.cat([up, eighth], 1))
        up = nn.functional.interpolate(up, size=quarter.shape[-2:], mode="bilinear", align_corners=False)
        up = self.up2(torch.cat([up, quarter], 1))
        return self.head(up)
