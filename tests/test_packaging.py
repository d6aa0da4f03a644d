"""Packaging (issue #14): what a wheel ships, checked against pyproject.toml without building one.

The wheel itself is built, installed and run by ``.ci/wheel_check`` (a CI step); these tests keep the declarations
complete: every bundled config and asset is package data, ``warpscatter.io.resources`` finds them in both layouts
(source checkout and installed package), the version lives in one place, LICENSE and ``py.typed`` ship.
"""

from __future__ import annotations

import fnmatch
import importlib.metadata
import importlib.util
import re
import shutil
import sys
from pathlib import Path

import pytest
import yaml

import warpscatter
from warpscatter.io import resources

if sys.version_info >= (3, 11):
    import tomllib
else:  # Python 3.10: the test extra installs tomli
    tomllib = pytest.importorskip("tomli")

ROOT = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
SETUPTOOLS = PYPROJECT["tool"]["setuptools"]
CONFIGS = sorted((ROOT / "configs").glob("*.yaml"))
ASSETS = sorted(p for p in (ROOT / "assets").iterdir() if p.is_file())


def _package_data(package: str, folder: str, name: str) -> bool:
    """Whether ``folder/name`` of the source tree ships in ``package``: mapped there by package-dir and matched by a
    package-data pattern (or a Python module, which setuptools ships with every listed package)."""
    if package not in SETUPTOOLS["packages"] or SETUPTOOLS["package-dir"].get(package) != folder:
        return False
    patterns = SETUPTOOLS.get("package-data", {}).get(package, [])
    return name.endswith(".py") or any(fnmatch.fnmatch(name, p) for p in patterns)


def test_source_checkout_finds_the_top_level_folders():
    assert resources.ROOT == ROOT
    assert resources.PACKAGE_DIR == ROOT / "warpscatter"


@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: p.name)
def test_every_bundled_config_is_found_and_ships(config):
    assert resources.bundled_config(config.stem) == config
    assert resources.bundled_config(config.name) == config
    assert _package_data("warpscatter.configs", "configs", config.name)


@pytest.mark.parametrize("asset", ASSETS, ids=lambda p: p.name)
def test_every_asset_file_ships(asset):
    assert _package_data("warpscatter.assets", "assets", asset.name), \
        f"assets/{asset.name} is not package data of warpscatter.assets in pyproject.toml"
    if asset.suffix != ".py":
        assert resources.bundled_asset(asset.name) == asset


def _strings(node):
    if isinstance(node, dict):
        for v in node.values():
            yield from _strings(v)
    elif isinstance(node, list):
        for v in node:
            yield from _strings(v)
    elif isinstance(node, str):
        yield node


@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: p.name)
def test_config_paths_stay_inside_the_shipped_folders(config):
    """A config's relative file paths (meshes, textures, maps) point into assets/, which ships beside configs/;
    only output.dir (written, not read) may point elsewhere."""
    data = yaml.safe_load(config.read_text(encoding="utf-8"))
    data.get("output", {}).pop("dir", None)
    for value in _strings(data):
        if "/" in value and not value.startswith("/"):
            target = (config.parent / value).resolve()
            assert target.parent == ROOT / "assets" and target.is_file(), f"{config.name}: {value}"


def test_missing_bundled_file_names_the_path_and_the_folder():
    with pytest.raises(FileNotFoundError, match=r"configs/no_such_config\.yaml.*it holds: .*quickstart\.yaml"):
        resources.bundled_config("no_such_config")
    with pytest.raises(FileNotFoundError, match=r"assets/no_such\.obj"):
        resources.bundled_asset("no_such.obj")


def _load_resources_from(package_dir: Path):
    """``warpscatter/io/resources.py`` imported as if it lay in ``package_dir`` (a copy: the layout of an install)."""
    (package_dir / "io").mkdir(parents=True, exist_ok=True)
    shutil.copy(ROOT / "warpscatter" / "io" / "resources.py", package_dir / "io" / "resources.py")
    spec = importlib.util.spec_from_file_location("_resources_copy", package_dir / "io" / "resources.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_wheel_layout_finds_the_package_data(tmp_path):
    """In a wheel install configs/ and assets/ lie inside the package (site-packages/warpscatter/...)."""
    site = tmp_path / "site-packages"
    for folder in ("configs", "assets"):
        shutil.copytree(ROOT / folder, site / "warpscatter" / folder)
    res = _load_resources_from(site / "warpscatter")
    assert res.ROOT == site / "warpscatter"
    gate = res.bundled_config("gate")
    assert gate == site / "warpscatter" / "configs" / "gate.yaml"
    assert res.bundled_asset("gate.obj") == site / "warpscatter" / "assets" / "gate.obj"
    assert (gate.parent / "../assets/gate.obj").resolve() == res.bundled_asset("gate.obj")
    # the configs' default output.dir (../out) would be inside the installed package: in_package says so
    assert res.in_package(gate.parent / "../out")
    assert not res.in_package(tmp_path / "out")


def test_install_without_the_data_reports_it(tmp_path):
    res = _load_resources_from(tmp_path / "site-packages" / "warpscatter")
    with pytest.raises(FileNotFoundError, match="holds no such folder"):
        res.bundled_config("quickstart")


def test_in_package_in_a_source_checkout():
    assert not resources.in_package(ROOT / "out")  # the bundled configs' output.dir in a checkout
    assert resources.in_package(ROOT / "warpscatter" / "out")


def test_every_python_package_is_listed():
    found = {".".join(("warpscatter", *p.parent.relative_to(ROOT / "warpscatter").parts))
             for p in (ROOT / "warpscatter").rglob("__init__.py")}
    assert found <= set(SETUPTOOLS["packages"])
    assert SETUPTOOLS["package-dir"]["warpscatter.cli"] == "cli"


def test_version_in_one_place():
    project = PYPROJECT["project"]
    assert "version" not in project and "version" in project["dynamic"]
    assert SETUPTOOLS["dynamic"]["version"] == {"attr": "warpscatter.__version__"}
    # a literal assignment: setuptools reads it without importing the package (nothing heavy at build time)
    init = (ROOT / "warpscatter" / "__init__.py").read_text(encoding="utf-8")
    assert re.search(r'^__version__ = "[0-9][^"]*"$', init, re.M)
    assert warpscatter.__version__ == importlib.metadata.version("warpscatter")


def test_license_and_py_typed_ship():
    license_text = (ROOT / "LICENSE").read_text(encoding="utf-8")
    assert license_text.startswith("MIT License")
    assert "Copyright (c) 2026 the warpscatter developers" in license_text
    assert PYPROJECT["project"]["license"] == "MIT"
    assert PYPROJECT["project"]["license-files"] == ["LICENSE"]
    assert (ROOT / "warpscatter" / "py.typed").is_file()
    assert "py.typed" in SETUPTOOLS["package-data"]["warpscatter"]


def test_dependencies_are_explained():
    """Each runtime dependency carries a comment naming its reason (pyproject.toml's own text)."""
    text = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    block = text[text.index("dependencies = ["):]
    block = block[:block.index("]\n")]
    for dep in PYPROJECT["project"]["dependencies"]:
        line = next(line for line in block.splitlines() if f'"{dep}"' in line)
        assert re.search(r'",\s+#\s+\S', line), f"no reason comment for {dep}"
    assert any(d.startswith("tqdm") for d in PYPROJECT["project"]["dependencies"])
