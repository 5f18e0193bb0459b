"""Label images and their files."""

from .label_image import LabelImage

__all__ = ["LabelImage"]
