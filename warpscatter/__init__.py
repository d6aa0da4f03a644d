"""warpscatter: real-time shadows and single scattering in participating media as NVIDIA Warp kernels.

The library is importable without the CLI. Kernel modules expose their ``@wp.func`` building blocks
as public API so that user kernels can call them (see the README's map of the code).
"""

import os as _os

__version__ = "0.1.0"

# In a source checkout the click application lives in the top-level ``cli/`` folder, which an
# installed package maps to ``warpscatter.cli``. When this package is imported straight from the
# tree (repository root on sys.path), let ``warpscatter.cli`` resolve to that folder as well.
_here = _os.path.dirname(_os.path.abspath(__file__))
_source_root = _os.path.dirname(_here)
if not _os.path.isdir(_os.path.join(_here, "cli")) and _os.path.isfile(
    _os.path.join(_source_root, "cli", "__init__.py")
):
    __path__.append(_source_root)  # noqa: F821  (module __path__ of a package)
