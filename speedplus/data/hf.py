"""A Hugging Face ``datasets.Dataset`` of labelled images: the joined records as columns,
the image (and a twin's mask) as ``datasets.Image`` columns read from their files. It needs
the ``[hf]`` extra (``pip install 'speedplus-builder[hf]'``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from speedplus.data.records import SETS, samples


def hf_dataset(root: str | Path, sets: tuple[str, ...] = SETS) -> Any:
    """``datasets.Dataset`` with columns sample_id, set, domain, image (Image), mask (Image or
    None), q_vbs2tango_true, r_Vo2To_vbs_true (m), keypoints_px, bbox_px (px), camera_matrix,
    dist; ``.save_to_disk`` or ``.to_parquet`` keep it (images embedded)."""
    import datasets

    rows = samples(root, sets)
    columns = {
        "sample_id": [s.sample_id for s in rows], "set": [s.set for s in rows], "domain": [s.domain for s in rows],
        "image": [str(s.image) for s in rows], "mask": [str(s.mask) if s.mask else None for s in rows],
        "q_vbs2tango_true": [s.q_vbs2tango_true.tolist() for s in rows],
        "r_Vo2To_vbs_true": [s.r_Vo2To_vbs_true.tolist() for s in rows],
        "keypoints_px": [None if s.keypoints_px is None else s.keypoints_px.tolist() for s in rows],
        "bbox_px": [None if s.bbox_px is None else s.bbox_px.tolist() for s in rows],
        "camera_matrix": [s.camera_matrix.tolist() for s in rows], "dist": [s.dist.tolist() for s in rows],
    }
    features = datasets.Features({
        "sample_id": datasets.Value("string"), "set": datasets.Value("string"), "domain": datasets.Value("string"),
        "image": datasets.Image(), "mask": datasets.Image(),
        "q_vbs2tango_true": datasets.Sequence(datasets.Value("float64"), length=4),
        "r_Vo2To_vbs_true": datasets.Sequence(datasets.Value("float64"), length=3),
        "keypoints_px": datasets.Sequence(datasets.Sequence(datasets.Value("float64"), length=2)),
        "bbox_px": datasets.Sequence(datasets.Value("float64"), length=4),
        "camera_matrix": datasets.Sequence(datasets.Sequence(datasets.Value("float64"), length=3), length=3),
        "dist": datasets.Sequence(datasets.Value("float64"), length=5),
    })
    return datasets.Dataset.from_dict(columns, features=features)
