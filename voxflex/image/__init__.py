"""Label images and their files."""

from .io import SUPPORTED_EXTENSIONS, image_format, load_image, save_image
from .label_image import CONNECTIVITIES, LabelImage

__all__ = ["LabelImage", "CONNECTIVITIES", "load_image", "save_image", "image_format", "SUPPORTED_EXTENSIONS"]
