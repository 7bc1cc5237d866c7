"""Loaders for ML users (docs/loaders.md): a workspace's labelled images, or a SPEED+ export's,
as one joined record per image (``samples``), as a PyTorch ``Dataset`` (``PoseDataset``) and
as a Hugging Face ``datasets.Dataset`` (``hf_dataset``). Units: metres, radians, pixels;
``q_vbs2tango_true`` is the rotation of ``cam_from_target`` (Hamilton, w first),
``r_Vo2To_vbs_true`` its translation at full scale (docs/architecture.md section 3).

Five lines to train from a workspace::

    from torch.utils.data import DataLoader
    from speedplus.data import PoseDataset
    data = PoseDataset("data/default", sets=("twins",))
    for batch in DataLoader(data, batch_size=8, shuffle=True):
        images, q, r = batch["image"], batch["q_vbs2tango_true"], batch["r_Vo2To_vbs_true"]
"""

from speedplus.data.hf import hf_dataset
from speedplus.data.pytorch import PoseDataset
from speedplus.data.records import Sample, samples

__all__ = ["PoseDataset", "Sample", "hf_dataset", "samples"]
