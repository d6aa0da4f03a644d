"""Module paths from before the packages of issue #51 (``warpscatter.raycast``, ``warpscatter.scattering.prefix_sums``,
...): they still import, as the module at the new path, with a :class:`DeprecationWarning` naming it.

:func:`install` (called by ``import warpscatter``) adds a finder to :data:`sys.meta_path` that answers only the names in
:data:`MOVED`; a package that took a moved module's name (``warpscatter.raster``, ``warpscatter.scattering.epipolar``)
forwards its old attributes through :func:`moved_attribute`.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

#: old module path -> the module that holds its code now
MOVED = {
    "warpscatter.wpinit": "warpscatter.runtime.device",
    "warpscatter.parallel": "warpscatter.runtime.parallel",
    "warpscatter.fastmath": "warpscatter.runtime.fastmath",
    "warpscatter.heap": "warpscatter.runtime.heap",
    "warpscatter.stages": "warpscatter.runtime.stages",
    "warpscatter.imageio": "warpscatter.io.images",
    "warpscatter.provenance": "warpscatter.io.provenance",
    "warpscatter.metrics": "warpscatter.io.metrics",
    "warpscatter.resources": "warpscatter.io.resources",
    "warpscatter.raster_funcs": "warpscatter.raster.funcs",
    "warpscatter.raster_scan": "warpscatter.raster.scan",
    "warpscatter.raster_depth": "warpscatter.raster.depth",
    "warpscatter.raster_inputs": "warpscatter.raster.inputs",
    "warpscatter.raycast": "warpscatter.raster.raycast",
    "warpscatter.gbuffer": "warpscatter.raster.gbuffer",
    "warpscatter.config_files": "warpscatter.config.files",
    "warpscatter.animation": "warpscatter.config.animation",
    "warpscatter.reference": "warpscatter.config.reference",
    "warpscatter.jobs": "warpscatter.runs.jobs",
    "warpscatter.sequence": "warpscatter.runs.animation",
    "warpscatter.sweep": "warpscatter.runs.sweep",
    "warpscatter.gallery": "warpscatter.runs.gallery",
    "warpscatter.scattering.epipolar_lines": "warpscatter.scattering.epipolar.lines",
    "warpscatter.scattering.epipolar_textures": "warpscatter.scattering.epipolar.textures",
    "warpscatter.scattering.epipolar_upsampling": "warpscatter.scattering.epipolar.upsampling",
    "warpscatter.scattering.rectification": "warpscatter.scattering.rectify.params",
    "warpscatter.scattering.caster_culling": "warpscatter.scattering.rectify.caster_culling",
    "warpscatter.scattering.filtered_textures": "warpscatter.scattering.prefiltered.textures",
    "warpscatter.scattering.prefix_sums": "warpscatter.scattering.prefiltered.prefix_sums",
    "warpscatter.scattering.row_mips": "warpscatter.scattering.prefiltered.row_mips",
    "warpscatter.scattering.filtered_lookups": "warpscatter.scattering.prefiltered.filtered_lookups",
    "warpscatter.scattering.ray_weights": "warpscatter.scattering.prefiltered.ray_weights",
    "warpscatter.scattering.epipole_fallback": "warpscatter.scattering.prefiltered.epipole_regions",
    "warpscatter.scattering.prefiltered_spot": "warpscatter.scattering.prefiltered.spot_lookups",
}


def _warn(old: str, new: str) -> None:
    warnings.warn(f"{old} moved to {new}; import it from there", DeprecationWarning, stacklevel=3)


class _MovedFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports an old path as the module at its new path (the same module object, not a copy)."""

    def find_spec(self, fullname, path=None, target=None):
        return importlib.util.spec_from_loader(fullname, self) if fullname in MOVED else None

    def create_module(self, spec):
        _warn(spec.name, MOVED[spec.name])
        module = importlib.import_module(MOVED[spec.name])
        self._own_spec = module.__spec__  # the import system sets __spec__ to the old name's: exec_module restores it
        return module

    def exec_module(self, module):
        module.__spec__ = self._own_spec


def install() -> None:
    """Add the finder of the old paths to :data:`sys.meta_path` (once)."""
    if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
        sys.meta_path.append(_MovedFinder())


def moved_attribute(package: str, module: str, name: str):
    """``package.name`` from before ``package`` became a package: ``module.name``, with a DeprecationWarning."""
    if name.startswith("__"):
        raise AttributeError(f"module {package!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)  # AttributeError as usual where module lacks it too
    _warn(f"{package}.{name}", f"{module}.{name}")
    return value
