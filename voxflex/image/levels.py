"""Voxel levels of a label image: 2x2x2 blocks merged into one voxel, or every voxel split into 2x2x2.

>>> import numpy as np
>>> from voxflex.image.label_image import LabelImage
>>> merge_blocks(LabelImage(np.ones((4, 4, 2), np.uint8))).shape
(2, 2, 1)
"""

from __future__ import annotations

import numpy as np

__all__ = ["merge_blocks", "split_voxels", "image_at_level"]


def merge_blocks(image):
    """The image with every 2x2x2 block merged (twice the spacing, same origin and direction).

    A block is material when at least half of its 8 voxels are (an odd size is padded with empty
    voxels); its label is the most common label among them (the smallest on ties); its occupancy the
    mean of the block's.  The rule of ``voxflex tradeoff``'s coarser voxel levels.
    """
    from .label_image import LabelImage

    labels = np.asarray(image.labels)
    shape = tuple(-(-s // 2) * 2 for s in labels.shape)
    pad = [(0, s - t) for s, t in zip(shape, labels.shape)]
    lab = np.pad(labels, pad)
    blocks = lab.reshape(shape[0] // 2, 2, shape[1] // 2, 2, shape[2] // 2, 2).transpose(0, 2, 4, 1, 3, 5)
    blocks = blocks.reshape(*blocks.shape[:3], 8)
    material = (blocks > 0).sum(-1) >= 4
    present = np.unique(labels[labels > 0])
    counts = np.stack([(blocks == v).sum(-1) for v in present], axis=-1)
    coarse = np.where(material, present[np.argmax(counts, axis=-1)], 0).astype(labels.dtype)
    occ = None
    if image.occupancy is not None:
        o = np.pad(np.asarray(image.occupancy, dtype=float), pad)
        o = o.reshape(shape[0] // 2, 2, shape[1] // 2, 2, shape[2] // 2, 2).mean(axis=(1, 3, 5))
        occ = np.where(material, o, 0.0)
    return LabelImage(coarse, spacing=np.asarray(image.spacing) * 2, origin=image.origin,
                      direction=image.direction, occupancy=occ)


def split_voxels(image):
    """The image with every voxel split into 2x2x2 (half the spacing, the same geometry, labels and
    occupancy repeated)."""
    from .label_image import LabelImage

    rep = lambda a: np.repeat(np.repeat(np.repeat(a, 2, 0), 2, 1), 2, 2)  # noqa: E731
    occ = None if image.occupancy is None else rep(np.asarray(image.occupancy))
    return LabelImage(rep(image.labels), spacing=np.asarray(image.spacing) / 2, origin=image.origin,
                      direction=image.direction, occupancy=occ)


def image_at_level(image, level: int):
    """The image on grid ``level``: each positive step splits every voxel into 2x2x2
    (:func:`split_voxels`), each negative one merges 2x2x2 blocks (:func:`merge_blocks`)."""
    out = image
    for _ in range(abs(int(level))):
        out = split_voxels(out) if level > 0 else merge_blocks(out)
    return out
