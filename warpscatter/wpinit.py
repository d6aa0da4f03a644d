"""One place that initialises Warp for warpscatter and names the default device.

Every kernel module of warpscatter calls :func:`module_options` at import time so all of them
share one set of module options (backward passes off: nothing here is differentiated, and
compiles are ~2.5x faster). Importing warpscatter changes none of Warp's global settings: Warp's
log level and messages stay the user's (the CLI quiets them, see ``warpscatter --help``);
``WARPSCATTER_KERNEL_CACHE``, when set, moves Warp's kernel cache.

The default device follows Warp's: :func:`default_device` returns the device given, else
``WARPSCATTER_DEVICE``, else ``wp.get_device()`` (so ``wp.ScopedDevice`` and ``wp.set_device`` apply).
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import tempfile

import warp as wp

log = logging.getLogger("warpscatter")

_initialised = False
_after_init: list = []  # callables init() runs once Warp is up (after_init)

#: Module options shared by every warpscatter kernel module (one option set = one compile cost).
MODULE_OPTIONS = {"enable_backward": False}


def _configure() -> None:
    """Settings that must precede ``wp.init()`` (applied when this module is first imported)."""
    cache = os.environ.get("WARPSCATTER_KERNEL_CACHE")
    if cache:
        wp.config.kernel_cache_dir = cache


_configure()


@contextlib.contextmanager
def _native_stderr_to_log():
    """Route what native code writes to file descriptor 2 (Warp's "CUDA driver not found" warning on a machine
    without a GPU) to the ``warpscatter`` logger at DEBUG level instead of the terminal."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no real stderr (embedded interpreters): nothing to redirect
        yield
        return
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            text = sink.read().decode("utf-8", "replace").strip()
            if text:
                log.debug("Warp (native): %s", text)


def init(quiet_native: bool = False) -> None:
    """Initialise Warp once, then run what :func:`after_init` registered.

    Args:
        quiet_native: route Warp's native start-up messages on stderr (the CUDA-driver warning of a CPU-only
            machine) to the ``warpscatter`` logger at DEBUG level; the CLI does this unless ``-v`` is given.
    """
    global _initialised
    if _initialised:
        return
    if quiet_native:
        with _native_stderr_to_log():
            wp.init()
    else:
        wp.init()
    _initialised = True
    while _after_init:
        _after_init.pop(0)()


def initialised() -> bool:
    """Whether :func:`init` has run in this process."""
    return _initialised


def after_init(fn) -> None:
    """Call ``fn()`` once :func:`init` has started Warp (at once if it has)."""
    if _initialised:
        fn()
    else:
        _after_init.append(fn)


def module_options() -> None:
    """Apply :data:`MODULE_OPTIONS` to the calling module. Call at the top of each kernel module."""
    import inspect

    frame = inspect.currentframe().f_back
    wp.set_module_options(MODULE_OPTIONS, module=frame.f_globals["__name__"])


def default_device(device=None) -> str:
    """The device to launch on, as a Warp device name: ``device`` (a name or a ``wp.context.Device``), else
    ``WARPSCATTER_DEVICE``, else Warp's current device (``wp.get_device()``: ``"cpu"`` on a machine without a GPU,
    whatever ``wp.ScopedDevice`` / ``wp.set_device`` chose otherwise)."""
    init()
    if device is not None:
        return str(device) if not isinstance(device, str) else device
    return os.environ.get("WARPSCATTER_DEVICE") or str(wp.get_device())
