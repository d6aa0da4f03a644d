"""The exceptions warpscatter raises on purpose (bad input, not bugs), each with the CLI's ``exit_code``: 2 for input
the user can fix before any work, 1 for a failure while rendering or writing. No Warp import.
"""

from __future__ import annotations

from pathlib import Path


class WarpscatterError(Exception):
    """Base class of warpscatter's deliberate errors; ``exit_code`` is what the CLI exits with."""

    exit_code = 1


class ConfigError(WarpscatterError):
    """An invalid configuration: every problem as a ``key.path: reason`` line.

    Attributes:
        problems: the problem lines, in document order of discovery.
        source: the config file the problems were found in (None for in-memory configs).
    """

    exit_code = 2

    def __init__(self, problems: list[str] | str, source: str | Path | None = None):
        self.problems = [problems] if isinstance(problems, str) else list(problems)
        self.source = Path(source) if source is not None else None
        super().__init__(str(self))

    def __str__(self) -> str:
        body = "\n".join(f"  {p}" for p in self.problems)
        head = f"{self.source}:" if self.source is not None else "invalid config:"
        return f"{head}\n{body}"


class InputFileError(WarpscatterError, ValueError):
    """An input file (mesh, texture, environment map, CSM) that cannot be read, is invalid or does not fit the scene;
    treated like an invalid config (exit code 2).

    Attributes:
        message: the reason, naming the file.
        path: the file, where known.
        key: the config key that named the file, where known (the message is then ``key: message``; see :meth:`at`).
    """

    exit_code = 2

    def __init__(self, message: str, *, path: str | Path | None = None, key: str | None = None):
        self.message = str(message)
        self.path = Path(path) if path is not None else None
        self.key = key
        super().__init__(self.message)

    def at(self, key: str) -> InputFileError:
        """This error, reported at config key ``key`` unless it already names one; returns it, for
        ``raise exc.at("scene.meshes.1.path")``."""
        if self.key is None:
            self.key = key
        return self

    def __str__(self) -> str:
        return f"{self.key}: {self.message}" if self.key else self.message

    def __reduce__(self):  # keep path and key through pickling (process executors)
        return self.__class__, (self.message,), {"path": self.path, "key": self.key}


class DeviceError(WarpscatterError, ValueError):
    """A Warp device this machine does not have (``--device``, ``WARPSCATTER_DEVICE`` or a ``device`` argument),
    refused before any work (exit code 2)."""

    exit_code = 2


class NonFiniteImageError(WarpscatterError, FloatingPointError):
    """A rendered image holds NaN or infinite pixels: a bug (every numerically hard case has a documented
    fallback), reported instead of writing the image."""


__all__ = ["ConfigError", "DeviceError", "InputFileError", "NonFiniteImageError", "WarpscatterError"]
