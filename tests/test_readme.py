"""The README's promises: its commands exist, its kernel example compiles and runs."""

import importlib
import re
from pathlib import Path

import numpy as np
import warp as wp

README = (Path(__file__).resolve().parent.parent / "README.md").read_text()


def test_readme_kernel_example_runs(tmp_path, monkeypatch):
    block = re.search(r"```python\n(.*?)```", README, re.S).group(1)
    (tmp_path / "readme_example.py").write_text(block)  # Warp reads kernel source from a file
    monkeypatch.syspath_prepend(str(tmp_path))
    ns = importlib.import_module("readme_example").__dict__
    from warpscatter.shadows import moments

    z = np.array([-0.5, 0.2], np.float32)
    b = moments.moments4(np.array([0.0, 0.0], np.float32))  # an occluder at depth 0 on both texels
    out = wp.zeros(2, dtype=float)
    wp.launch(ns["my_shadows"], dim=2, inputs=[wp.array(b, dtype=wp.vec4), wp.array(z, dtype=float), out])
    s = out.numpy()
    assert s[0] < 0.05 and s[1] > 0.9  # in front of the occluder lit, behind it shadowed


def test_readme_setup_commands():
    assert 'pip install -e . && .venv/bin/warpscatter render configs/quickstart.yaml' in README
    assert 'pip install -e ".[test]" && .venv/bin/pytest' in README
