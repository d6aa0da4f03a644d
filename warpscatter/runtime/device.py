"""One place that initialises Warp for warpscatter and names the default device.

Every kernel module calls :func:`module_options` at import (backward passes off: nothing is differentiated, and
compiles are faster). Importing warpscatter changes none of Warp's global settings; ``WARPSCATTER_KERNEL_CACHE``
moves Warp's kernel cache. :func:`warp_messages` sends Warp's banner and module-load lines to a logger (Warp 1.19 has
no ``wp.config.quiet``).
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import tempfile
import threading

import warp as wp

log = logging.getLogger("warpscatter")
#: Where :func:`warp_messages` sends Warp's debug and info messages (banner, module loads).
warp_log = logging.getLogger("warpscatter.warp")

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
    """Route native writes to fd 2 (Warp's "CUDA driver not found" warning) to the ``warpscatter`` logger (DEBUG)."""
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
    """Initialise Warp once, then run what :func:`after_init` registered; ``quiet_native`` routes Warp's native
    start-up warning on stderr to the ``warpscatter`` logger (DEBUG)."""
    global _initialised
    if _initialised:
        return
    if quiet_native:
        # Warp's banner is held until fd 2 is the terminal's again (a stderr logger would write into the redirection).
        target, held = wp.get_logger(), _HeldMessages()
        wp.set_logger(held)
        try:
            with _native_stderr_to_log():
                wp.init()
        finally:
            wp.set_logger(target)
            held.replay(target)
    else:
        wp.init()
    _initialised = True
    while _after_init:
        _after_init.pop(0)()


class WarpToLogging:
    """A Warp logger sending debug and info to ``warpscatter.warp``, warnings and errors to ``previous``."""

    def __init__(self, previous):
        self.previous = previous

    def debug(self, message: str) -> None:
        warp_log.debug("%s", message)

    def info(self, message: str) -> None:
        warp_log.info("%s", message)

    def warning(self, message: str, category=None, stacklevel: int = 1) -> None:
        self.previous.warning(message, category=category, stacklevel=stacklevel + 1)

    def error(self, message: str) -> None:
        self.previous.error(message)


_quiet_lock = threading.Lock()
_quiet_depth = 0  # warp_messages(verbose=False) blocks running now (renders in several threads share one logger)
_quiet_saved = None  # the Warp logger the outermost block replaced


@contextlib.contextmanager
def warp_messages(verbose: bool = False):
    """Keep Warp's messages out of the user's output for the block: a :class:`WarpToLogging` is installed
    (process-wide: other threads' module loads are logged there too); with ``verbose`` Warp's log level is lowered to
    ``wp.LOG_INFO`` instead. Warp's settings are restored afterwards, also when the block raises."""
    global _quiet_depth, _quiet_saved
    if verbose:
        saved_level = wp.config.log_level
        wp.config.log_level = min(saved_level, wp.LOG_INFO)
        try:
            init()
            yield
        finally:
            wp.config.log_level = saved_level
        return
    with _quiet_lock:
        if _quiet_depth == 0:
            _quiet_saved = wp.get_logger()
            wp.set_logger(WarpToLogging(_quiet_saved))
        _quiet_depth += 1
    try:
        init(quiet_native=True)
        yield
    finally:
        with _quiet_lock:
            _quiet_depth -= 1
            if _quiet_depth == 0:
                wp.set_logger(_quiet_saved)
                _quiet_saved = None


class _HeldMessages:
    """A Warp logger that keeps what Warp logs until :meth:`replay` hands it to another Warp logger, in order."""

    def __init__(self):
        self.messages: list[tuple[str, tuple, dict]] = []

    def debug(self, message: str) -> None:
        self.messages.append(("debug", (message,), {}))

    def info(self, message: str) -> None:
        self.messages.append(("info", (message,), {}))

    def warning(self, message: str, category=None, stacklevel: int = 1) -> None:
        self.messages.append(("warning", (message,), {"category": category}))

    def error(self, message: str) -> None:
        self.messages.append(("error", (message,), {}))

    def replay(self, target) -> None:
        for method, args, kwargs in self.messages:
            getattr(target, method)(*args, **kwargs)
        self.messages.clear()


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
    """The device to launch on, as a Warp device name: ``device``, else ``WARPSCATTER_DEVICE``, else
    ``wp.get_device()``. Raises :class:`~warpscatter.errors.DeviceError` for a device this machine does not have."""
    init()
    if device is not None:
        return check_device(device if isinstance(device, str) else str(device), "device")
    env = os.environ.get("WARPSCATTER_DEVICE")
    return check_device(env, "WARPSCATTER_DEVICE") if env else str(wp.get_device())


_known_devices: set[str] = set()


def check_device(name: str, source: str) -> str:
    """``name`` if Warp has such a device, else :class:`~warpscatter.errors.DeviceError` naming ``source`` (the
    option, variable or argument that gave it) and the devices there are."""
    if name not in _known_devices:
        init()
        try:
            wp.get_device(name)
        except Exception:
            from ..errors import DeviceError

            names = ", ".join(str(d) for d in wp.get_devices())
            raise DeviceError(f"{source} {name}: not a device of this machine (available: {names})") from None
        _known_devices.add(name)
    return name
