"""Training-time augmentations of the reference models (numpy and OpenCV; deterministic for
a generator state).

Geometry (``geometric``, both models): a random rotation in the image plane about the
crop's centre, a scale and a shift, applied alike to the image, the mask and the keypoints.
Without it the first model over-fitted its 2,700 crops (8% of training keypoints more than
5 px off, 45% of held-out ones, most on another keypoint's place). No flips: a mirror image
changes handedness, which no pose of the body explains. Then one of two recipes:

- ``photometric`` (the plain model): brightness (gain), gamma, offset and sensor noise.
- ``robust`` (the augmented model, against the synthetic-to-real gap, after the
  augmentations of the SPEED+ literature: style randomisation, random Earth backgrounds,
  noise, blur, glare): each image gets, with the probabilities of ``ROBUST``,
  a random Earth background behind the target (where the render's mask is empty), texture
  randomisation of the target (a smooth random field multiplied into its pixels), style
  (a random colour mixing and saturation), glare and lens flare (a bright blob with a halo,
  a streak through it and ghosts towards the image centre), Gaussian blur, the photometric
  jitter, and stronger noise (Gaussian and shot). Neural style transfer is not used: it
  needs a pretrained network this project cannot download.

Grey images (a mono camera's, C = 1) take the same recipe: the robust steps run on the grey
repeated in three channels, and the result is taken back to its luminance
(``stages.common.tone``), as the mono camera would see a tinted glare or a coloured Earth;
the photometric jitter and the noise then act on the one channel, as on a mono sensor.
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np

from stages.common.earth import albedo_map
from stages.common.tone import luminance

Augmentation = Literal["photometric", "robust"]
AUGMENTATIONS: tuple[Augmentation, ...] = ("photometric", "robust")
#: probability of each step of the robust recipe
ROBUST = {"earth": 0.5, "texture": 0.5, "style": 0.7, "glare": 0.4, "blur": 0.5}


def geometric(images: np.ndarray, masks: np.ndarray, keypoints: np.ndarray, rng: np.random.Generator,
              rotation: bool = True, scale: float = 0.15, shift: float = 0.06,
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rotated (uniform angle), scaled (1 +- ``scale``) and shifted (+- ``shift`` of the
    size) copies of images (N, H, W, C) uint8, masks (N, H, W) uint8 and keypoints (N, K, 2)
    input pixels (pixel centres at integers); what comes into view from outside is black,
    as space is."""
    n, height, width = images.shape[:3]
    out_images, out_masks, out_keypoints = np.empty_like(images), np.empty_like(masks), np.empty_like(keypoints)
    centre = np.array([(width - 1) / 2, (height - 1) / 2])
    for index in range(n):
        angle = rng.uniform(0.0, 360.0) if rotation else 0.0
        zoom = rng.uniform(1 - scale, 1 + scale)
        offset = rng.uniform(-shift, shift, 2) * (width, height)
        warp = cv2.getRotationMatrix2D((float(centre[0]), float(centre[1])), angle, zoom)
        warp[:, 2] += offset
        out_images[index] = cv2.warpAffine(images[index], warp, (width, height), flags=cv2.INTER_LINEAR,
                                           borderMode=cv2.BORDER_CONSTANT).reshape(images.shape[1:])
        out_masks[index] = cv2.warpAffine(masks[index], warp, (width, height), flags=cv2.INTER_LINEAR,
                                          borderMode=cv2.BORDER_CONSTANT)
        out_keypoints[index] = keypoints[index] @ warp[:, :2].T + warp[:, 2]
    return out_images, out_masks, out_keypoints


def photometric(x: np.ndarray, rng: np.random.Generator, noise_max: float = 0.04) -> np.ndarray:
    """Gain, gamma, offset and Gaussian noise on images (N, H, W, C) float32 in [0, 1]."""
    n = len(x)
    gain = rng.uniform(0.6, 1.6, (n, 1, 1, 1)).astype(np.float32)
    gamma = rng.uniform(0.7, 1.4, (n, 1, 1, 1)).astype(np.float32)
    offset = rng.uniform(-0.03, 0.05, (n, 1, 1, 1)).astype(np.float32)
    noise = rng.normal(0.0, 1.0, x.shape).astype(np.float32) * rng.uniform(0.0, noise_max, (n, 1, 1, 1)).astype(
        np.float32)
    return np.clip(np.power(np.clip(x * gain, 0, 1), gamma) + offset + noise, 0.0, 1.0)


def _smooth_field(rng: np.random.Generator, height: int, width: int, channels: int, cells: int) -> np.ndarray:
    coarse = rng.random((cells, cells, channels)).astype(np.float32)
    field = cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)
    return field.reshape(height, width, channels)


def earth_patch(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """An Earth-like background (H, W, 3) float32: a window of the albedo map, lit across a
    random terminator, below a random limb (black space above it) in half the cases."""
    texture = albedo_map(1024)
    size = int(rng.integers(96, 480))
    v0 = int(rng.integers(0, texture.shape[0] - size // 2))
    u0 = int(rng.integers(0, texture.shape[1] - size))
    window = texture[v0:v0 + size // 2, u0:u0 + size]
    patch = cv2.resize(window, (width, height), interpolation=cv2.INTER_LINEAR)
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float32)
    angle = rng.uniform(0, 2 * np.pi)
    along = (np.cos(angle) * (xs - width / 2) + np.sin(angle) * (ys - height / 2)) / max(width, height)
    light = np.clip(rng.uniform(0.4, 1.0) + rng.uniform(0.5, 2.5) * along, 0.0, 1.0) * rng.uniform(1.5, 4.0)
    patch = patch * light[..., None]
    if rng.random() < 0.5:  # the limb: a large circle whose inside is the planet
        radius = rng.uniform(1.5, 6.0) * max(width, height)
        centre_angle = rng.uniform(0, 2 * np.pi)
        reach = radius + rng.uniform(-0.4, 0.4) * max(width, height)
        cx, cy = width / 2 + reach * np.cos(centre_angle), height / 2 + reach * np.sin(centre_angle)
        inside = np.hypot(xs - cx, ys - cy) < radius
        patch = patch * inside[..., None]
    return np.clip(patch, 0.0, 1.0).astype(np.float32)


def _glare(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """An additive glare (H, W, 1): a bright core with a halo, a streak and flare ghosts."""
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float32)
    cx, cy = rng.uniform(-0.2, 1.2) * width, rng.uniform(-0.2, 1.2) * height
    core = rng.uniform(2.0, 10.0)
    out = rng.uniform(0.5, 1.5) * np.exp(-((xs - cx) ** 2 + (ys - cy) ** 2) / (2 * core**2))
    out += rng.uniform(0.1, 0.4) * np.exp(-np.hypot(xs - cx, ys - cy) / (4 * core))
    angle = rng.uniform(0, np.pi)
    distance = np.abs(np.sin(angle) * (xs - cx) - np.cos(angle) * (ys - cy))
    out += rng.uniform(0.1, 0.5) * np.exp(-distance**2 / (2 * rng.uniform(0.5, 1.5) ** 2))
    for fraction in rng.uniform(0.3, 1.7, int(rng.integers(1, 4))):  # ghosts along the line to the centre
        gx, gy = cx + fraction * (width / 2 - cx), cy + fraction * (height / 2 - cy)
        radius = rng.uniform(3.0, 15.0)
        out += rng.uniform(0.05, 0.2) * (np.hypot(xs - gx, ys - gy) < radius)
    return out[..., None].astype(np.float32)


def robust(x: np.ndarray, masks: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The robust recipe on images (N, H, W, C) float32 in [0, 1] (C = 3, or 1: grey) with the
    target's masks (N, H, W) float32 in [0, 1] (the render's mask, cropped as the image)."""
    out = np.empty_like(x)
    n, height, width, channels = x.shape
    for index in range(n):
        image, alpha = np.broadcast_to(x[index], (height, width, 3)).copy(), masks[index][..., None]
        if rng.random() < ROBUST["texture"]:
            image = image * (alpha * (0.5 + _smooth_field(rng, height, width, 3, int(rng.integers(3, 12))))
                             + (1 - alpha))
        if rng.random() < ROBUST["earth"]:
            image = image * alpha + earth_patch(rng, height, width) * (1 - alpha)
        if rng.random() < ROBUST["style"]:
            mixing = np.eye(3, dtype=np.float32) + rng.normal(0, 0.15, (3, 3)).astype(np.float32)
            image = image @ mixing.T
            grey = image.mean(axis=-1, keepdims=True)
            image = grey + rng.uniform(0.3, 1.5) * (image - grey)
        if rng.random() < ROBUST["glare"]:
            image = image + _glare(rng, height, width) * rng.uniform(0.8, 1.0, 3).astype(np.float32)
        if rng.random() < ROBUST["blur"]:
            image = cv2.GaussianBlur(np.clip(image, 0, 1), (0, 0), rng.uniform(0.4, 1.6))
        image = np.clip(image, 0.0, 1.0)
        out[index] = luminance(image)[..., None] if channels == 1 else image
    return _sensor(out, rng)


def _sensor(x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The photometric jitter with stronger read noise, and shot noise (grows with the signal)."""
    out = photometric(x, rng, noise_max=0.07)
    shot = rng.uniform(0.0, 0.03, (len(x), 1, 1, 1)).astype(np.float32)
    return np.clip(out + rng.normal(0.0, 1.0, out.shape).astype(np.float32) * shot * np.sqrt(out), 0.0, 1.0)


def augment(kind: Augmentation, images: np.ndarray, masks: np.ndarray | None,
            rng: np.random.Generator) -> np.ndarray:
    """Augmented copies (N, H, W, C) float32 in [0, 1] of images (N, H, W, C) uint8."""
    x = images.astype(np.float32) / 255.0
    if kind == "photometric":
        return photometric(x, rng)
    if masks is None:
        raise ValueError("the robust augmentation needs the target's masks")
    return robust(x, masks.astype(np.float32) / 255.0, rng)
