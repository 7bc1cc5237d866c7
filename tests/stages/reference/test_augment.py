"""The training augmentations: deterministic for a seed, geometry untouched, and each step
of the robust recipe doing what it says."""

import numpy as np

from stages.reference import augment as aug


def _batch(seed: int = 0):
    rng = np.random.default_rng(seed)
    images = np.zeros((6, 64, 64, 3), np.uint8)
    masks = np.zeros((6, 64, 64), np.uint8)
    images[:, 20:44, 16:48] = rng.integers(60, 200, (6, 1, 1, 3))  # a target on black space
    masks[:, 20:44, 16:48] = 255
    return images, masks


def test_the_same_seed_gives_the_same_images_and_another_seed_others():
    images, masks = _batch()
    for kind in aug.AUGMENTATIONS:
        first = aug.augment(kind, images, masks, np.random.default_rng(7))
        again = aug.augment(kind, images, masks, np.random.default_rng(7))
        other = aug.augment(kind, images, masks, np.random.default_rng(8))
        assert first.dtype == np.float32 and first.shape == images.shape
        assert np.array_equal(first, again), kind
        assert not np.array_equal(first, other), kind
        assert first.min() >= 0.0 and first.max() <= 1.0


def test_grey_images_take_the_same_recipe_in_one_channel():
    """A mono camera's crops (C = 1) come out grey and seeded; a glare or an Earth added in
    colour reaches them as its luminance, so the grey of a grey image stays grey."""
    images, masks = _batch()
    grey = images[..., :1].copy()
    for kind in aug.AUGMENTATIONS:
        first = aug.augment(kind, grey, masks, np.random.default_rng(7))
        assert first.shape == grey.shape and first.dtype == np.float32
        assert np.array_equal(first, aug.augment(kind, grey, masks, np.random.default_rng(7)))
        assert not np.array_equal(first, aug.augment(kind, grey, masks, np.random.default_rng(8)))
        assert first.min() >= 0.0 and first.max() <= 1.0
    keypoints = np.full((len(grey), 3, 2), 32.0)
    turned, _, _ = aug.geometric(grey, masks, keypoints, np.random.default_rng(2))
    assert turned.shape == grey.shape and turned.any()


def test_robust_steps_change_what_they_claim(monkeypatch):
    images, masks = _batch()
    x, alpha = images.astype(np.float32) / 255, masks.astype(np.float32) / 255
    for step in aug.ROBUST:
        monkeypatch.setattr(aug, "ROBUST", {name: float(name == step) for name in aug.ROBUST})
        monkeypatch.setattr(aug, "_sensor", lambda x, rng: x)  # isolate the step
        out = aug.robust(x.copy(), alpha, np.random.default_rng(1))
        outside, inside = masks == 0, masks == 255
        changed_out = np.abs(out - x)[outside].max()
        changed_in = np.abs(out - x)[inside].max()
        if step == "earth":  # space becomes a planet in some images; the target stays
            assert changed_out > 0.05 and np.allclose(out[inside], x[inside], atol=0.03)
        elif step == "texture":  # the target only
            assert changed_in > 0.05 and np.allclose(out[outside], x[outside], atol=0.03)
        else:
            assert max(changed_in, changed_out) > 0.02, step


def test_earth_backgrounds_are_bright_somewhere_and_vary():
    patches = [aug.earth_patch(np.random.default_rng(seed), 48, 64) for seed in range(6)]
    assert all(p.shape == (48, 64, 3) and p.dtype == np.float32 for p in patches)
    assert max(p.max() for p in patches) > 0.2
    assert len({p.tobytes() for p in patches}) == 6


def test_geometric_moves_keypoints_with_the_pixels_and_is_seeded():
    rng = np.random.default_rng(3)
    images = np.zeros((8, 96, 96, 3), np.uint8)
    masks = np.zeros((8, 96, 96), np.uint8)
    keypoints = rng.uniform(25, 70, (8, 5, 2))
    for index in range(8):  # a bright 3x3 spot on every keypoint
        for x, y in np.rint(keypoints[index]).astype(int):
            images[index, y - 1:y + 2, x - 1:x + 2] = 255
            masks[index, y - 1:y + 2, x - 1:x + 2] = 255
        keypoints[index] = np.rint(keypoints[index])
    out_images, out_masks, out_keypoints = aug.geometric(images, masks, keypoints, np.random.default_rng(5))
    again = aug.geometric(images, masks, keypoints, np.random.default_rng(5))
    assert all(np.array_equal(a, b) for a, b in zip((out_images, out_masks, out_keypoints), again, strict=True))
    assert not np.allclose(out_keypoints, keypoints, atol=2)  # it did move them
    for index in range(8):
        for x, y in out_keypoints[index]:
            if 2 <= x <= 93 and 2 <= y <= 93:  # the spot's brightest pixel is where the keypoint went
                window = out_images[index, int(round(y)) - 2:int(round(y)) + 3, int(round(x)) - 2:int(round(x)) + 3, 0]
                assert window.max() >= 120 and out_masks[index, int(round(y)), int(round(x))] > 60
