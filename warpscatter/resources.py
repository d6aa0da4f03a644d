"""The bundled configs and assets (``configs/*.yaml``, ``assets/*``): where they are, with a clear error where not.

They live in the top-level ``configs/`` and ``assets/`` folders of the source tree, which the bench suites and the
README's examples use. An installed package that does not ship them reports which file is missing and why.
"""

from __future__ import annotations

from pathlib import Path

#: The source tree's root (the folder holding ``configs/`` and ``assets/``).
ROOT = Path(__file__).resolve().parent.parent


def _bundled(folder: str, name: str) -> Path:
    path = ROOT / folder / name
    if not path.is_file():
        raise FileNotFoundError(f"bundled file not found: {path} (the {folder}/ folder of the warpscatter source tree; "
                                f"run from a checkout: git clone + pip install -e .)")
    return path


def bundled_config(name: str) -> Path:
    """``configs/NAME.yaml`` of the source tree.

    Raises:
        FileNotFoundError: naming the path, when this install does not hold it.
    """
    return _bundled("configs", name if name.endswith(".yaml") else f"{name}.yaml")


def bundled_asset(name: str) -> Path:
    """``assets/NAME`` of the source tree (meshes, light textures, environment maps).

    Raises:
        FileNotFoundError: naming the path, when this install does not hold it.
    """
    return _bundled("assets", name)


__all__ = ["ROOT", "bundled_asset", "bundled_config"]
