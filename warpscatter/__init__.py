"""warpscatter: real-time shadows and single scattering in participating media as NVIDIA Warp kernels.

The library is importable without the CLI. Kernel modules expose their ``@wp.func`` building blocks
as public API so that user kernels can call them (see the README's map of the code); the settings
models (``warpscatter.config`` and each technique's ``settings`` module) and the method registry
(``warpscatter.methods``) import no Warp.
"""

__version__ = "0.1.0"
