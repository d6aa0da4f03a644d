"""The scene on the device: triangle rasterization into depth maps (:mod:`.rasterizer`, its device building blocks
in :mod:`.funcs`, its scan in :mod:`.scan`, host mirrors in :mod:`.depth`, input checks in :mod:`.inputs`), BVH ray
casting (:mod:`.raycast`) and the camera G-buffer (:mod:`.gbuffer`).

The rasterizer's names were importable from ``warpscatter.raster`` before it became a package; they still are, with
a :class:`DeprecationWarning` (import them from :mod:`.rasterizer`).
"""


def __getattr__(name: str):
    from ..moved import moved_attribute

    return moved_attribute(__name__, "warpscatter.raster.rasterizer", name)
