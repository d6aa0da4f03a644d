"""One place that initialises Warp for warpscatter and names the default device.

Every kernel module of warpscatter calls :func:`module_options` at import time so all of them
share one set of module options (backward passes off: nothing here is differentiated, and
compiles are ~2.5x faster). Warp's own log is kept quiet unless ``WARPSCATTER_VERBOSE`` is set.
"""

from __future__ import annotations

import os

import warp as wp

_initialised = False

#: Module options shared by every warpscatter kernel module (one option set = one compile cost).
MODULE_OPTIONS = {"enable_backward": False}


def _configure() -> None:
    """Settings that must precede ``wp.init()`` (applied when this module is first imported)."""
    if not os.environ.get("WARPSCATTER_VERBOSE"):
        wp.config.log_level = wp.LOG_WARNING
    cache = os.environ.get("WARPSCATTER_KERNEL_CACHE")
    if cache:
        wp.config.kernel_cache_dir = cache


_configure()


def init() -> None:
    """Initialise Warp once (quiet logging and ``WARPSCATTER_KERNEL_CACHE`` are applied at import)."""
    global _initialised
    if _initialised:
        return
    wp.init()
    _initialised = True


def module_options() -> None:
    """Apply :data:`MODULE_OPTIONS` to the calling module. Call at the top of each kernel module."""
    import inspect

    frame = inspect.currentframe().f_back
    wp.set_module_options(MODULE_OPTIONS, module=frame.f_globals["__name__"])


def default_device(device: str | None = None) -> str:
    """Return the device to launch on: the argument, ``WARPSCATTER_DEVICE``, or ``"cpu"``."""
    init()
    return device or os.environ.get("WARPSCATTER_DEVICE", "cpu")
