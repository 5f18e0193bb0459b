"""Label images and their files."""

from .io import SUPPORTED_EXTENSIONS, image_format
from .label_image import CONNECTIVITIES, LabelImage, load_image, save_image

__all__ = ["LabelImage", "CONNECTIVITIES", "load_image", "save_image", "image_format", "SUPPORTED_EXTENSIONS"]
