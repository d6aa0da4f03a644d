"""The bundled configs and assets (``configs/*.yaml``, ``assets/*``): where they are, with a clear error where not.

:data:`ROOT` holds both side by side (so the configs' relative paths resolve): the top of a source checkout, or the
package folder of a wheel install, where bundled configs render with ``-o DIR`` (:func:`in_package`).
"""

from __future__ import annotations

from pathlib import Path

#: The installed (or checked-out) ``warpscatter`` package folder.
PACKAGE_DIR = Path(__file__).resolve().parent.parent


def _find_root() -> Path:
    if (PACKAGE_DIR / "configs").is_dir():
        return PACKAGE_DIR
    return PACKAGE_DIR.parent


#: The folder holding ``configs/`` and ``assets/``: the package folder of a wheel install, else the source tree's root.
ROOT = _find_root()


def _bundled(folder: str, name: str) -> Path:
    path = ROOT / folder / name
    if not path.is_file():
        where = (f"the {folder}/ folder of the installed package ({ROOT / folder})" if ROOT == PACKAGE_DIR else
                 f"the {folder}/ folder of the warpscatter source tree ({ROOT / folder})")
        if (ROOT / folder).is_dir():
            names = sorted(p.name for p in (ROOT / folder).iterdir() if p.is_file() and not p.name.startswith("."))
            hint = f"it holds: {', '.join(names)}"
        else:
            hint = "this install holds no such folder: reinstall warpscatter from its wheel, or run from a checkout"
        raise FileNotFoundError(f"bundled file not found: {path} (looked in {where}; {hint})")
    return path


def bundled_config(name: str) -> Path:
    """``configs/NAME.yaml`` (``NAME`` with or without ``.yaml``) of the source tree or the installed package;
    FileNotFoundError naming the path when this install does not hold it."""
    return _bundled("configs", name if name.endswith(".yaml") else f"{name}.yaml")


def bundled_configs() -> list[Path]:
    """Every bundled config (``configs/*.yaml`` of the source tree or the installed package), sorted by name."""
    return sorted((ROOT / "configs").glob("*.yaml"))


def bundled_asset(name: str) -> Path:
    """``assets/NAME`` (meshes, light textures, environment maps), as :func:`bundled_config` finds configs."""
    return _bundled("assets", name)


def in_package(path: str | Path) -> bool:
    """Whether ``path`` lies inside the installed package folder, where nothing should be written unasked."""
    try:
        Path(path).expanduser().resolve().relative_to(PACKAGE_DIR)
    except ValueError:
        return False
    return True


__all__ = ["PACKAGE_DIR", "ROOT", "bundled_asset", "bundled_config", "bundled_configs", "in_package"]
