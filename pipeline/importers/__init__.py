"""Sessions from data captured elsewhere: DiLiGenT objects and plain image folders.

>>> from pipeline.importers import import_diligent, import_images

:mod:`.diligent` reads and imports a DiLiGenT object folder, :mod:`.images` loose image files
matched by glob patterns, and :mod:`.write` is what both write into the new session.
"""

from .diligent import DiligentObject, import_diligent, read_diligent, read_normal_gt_mat
from .images import SKIPPED_WORDS, SPHERE_CROP_HINT, expand_glob, import_images, import_notes, natural_key
from .write import check_sizes

__all__ = ["import_diligent", "import_images", "read_diligent", "read_normal_gt_mat", "DiligentObject",
           "expand_glob", "natural_key", "check_sizes", "SPHERE_CROP_HINT", "SKIPPED_WORDS", "import_notes"]
