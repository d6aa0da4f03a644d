"""The exceptions warpscatter raises on purpose: bad input, not bugs.

Every one derives from :class:`WarpscatterError` and carries the exit code the CLI ends with
(``exit_code``): 2 for input the user can fix before any work (an invalid config, a file that does not fit
the scene), 1 for a failure while rendering or writing. Library code raises these types; only the CLI turns
them into exit codes. This module does not import Warp.
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
    """An input file (a precomputed coherent shadow map, say) that cannot be read or does not fit the scene; the
    message names the file and the reason. The CLI treats it like an invalid config (exit code 2)."""

    exit_code = 2


class NonFiniteImageError(WarpscatterError, FloatingPointError):
    """A rendered image holds NaN or infinite pixels: a bug (every numerically hard case has a documented
    fallback), reported instead of writing the image."""


__all__ = ["ConfigError", "InputFileError", "NonFiniteImageError", "WarpscatterError"]
