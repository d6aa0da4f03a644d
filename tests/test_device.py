"""Host code that runs on any Warp device (issue #53): every allocation and launch names the render's device, a device
the machine lacks is refused before any work, and the CPU thread split is one launch on CUDA.

This machine has only Warp's ``cpu`` device, so a render cannot show a call that falls back to Warp's default device
(it is the CPU either way). The check is therefore static: every call that allocates or launches (``wp.zeros``,
``wp.empty``, ``wp.full``, ``wp.ones``, ``wp.array`` with data or a shape, ``wp.from_numpy``, ``wp.launch``) names a
``device=`` (the ``*_like`` and ``clone`` calls take their source's device), and none names a fixed device. A call
without one would run on ``wp.get_device()`` instead of the device of the render, which on a GPU machine is
``cuda:0`` while ``--device cpu`` was asked for, or the reverse.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import warpscatter
from warpscatter.errors import DeviceError

ROOT = Path(__file__).resolve().parent.parent
ALLOCATING = {"zeros", "empty", "full", "ones", "array", "from_numpy", "launch", "launch_tiled"}


def _annotation_nodes(tree: ast.AST) -> set[int]:
    """ids of the nodes inside annotations (``a: wp.array(dtype=float)`` is a type, not an allocation)."""
    out: set[int] = set()
    for n in ast.walk(tree):
        roots = []
        if isinstance(n, ast.arg) and n.annotation is not None:
            roots.append(n.annotation)
        elif isinstance(n, ast.AnnAssign):
            roots.append(n.annotation)
        elif isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and n.returns is not None:
            roots.append(n.returns)
        for r in roots:
            out.update(id(x) for x in ast.walk(r))
    return out


def device_problems(path: Path) -> list[str]:
    """``file:line: wp.NAME ...`` for each allocation or launch in ``path`` naming no ``device=``, or a fixed one."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skip = _annotation_nodes(tree)
    out = []
    for n in ast.walk(tree):
        if id(n) in skip or not isinstance(n, ast.Call):
            continue
        f = n.func
        if not (isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) and f.value.id == "wp"
                and f.attr in ALLOCATING):
            continue
        keywords = {k.arg: k.value for k in n.keywords}
        if f.attr == "array" and not n.args and "data" not in keywords and "shape" not in keywords:
            continue  # wp.array(dtype=...) as a type outside an annotation
        where = f"{path.relative_to(ROOT)}:{n.lineno}: wp.{f.attr}"
        if "device" not in keywords and None not in keywords:  # None: a **kwargs that may carry it
            out.append(f"{where} names no device")
        elif isinstance(keywords.get("device"), ast.Constant):
            out.append(f"{where} names a fixed device {keywords['device'].value!r}")
    return out


def test_every_allocation_and_launch_names_the_device():
    problems = [p for path in sorted((ROOT / "warpscatter").rglob("*.py")) for p in device_problems(path)]
    assert not problems, "\n".join(problems)


def test_the_check_finds_a_call_without_a_device(tmp_path, monkeypatch):
    """The static check itself: it flags the calls it is meant to and passes types and named devices."""
    monkeypatch.setattr(__import__(__name__), "ROOT", tmp_path)
    src = tmp_path / "m.py"
    src.write_text(
        "import warp as wp\n"
        "def f(a: wp.array(dtype=float), device):\n"
        "    x = wp.zeros(3, dtype=float)\n"
        "    y = wp.array(a.numpy(), dtype=float, device=device)\n"
        "    wp.launch(k, dim=3, inputs=[x], device='cpu')\n"
        "    t = wp.array(dtype=float)\n"
        "    return wp.zeros_like(y)\n"
    )
    assert device_problems(src) == ["m.py:3: wp.zeros names no device", "m.py:5: wp.launch names a fixed device 'cpu'"]


def test_a_device_this_machine_lacks_is_refused_before_any_work(tmp_path, monkeypatch):
    monkeypatch.delenv("WARPSCATTER_DEVICE", raising=False)
    with pytest.raises(DeviceError, match=r"device cuda:7: not a device of this machine \(available: cpu"):
        warpscatter.render(ROOT / "configs" / "quickstart.yaml", out_dir=tmp_path / "out", device="cuda:7")
    assert not (tmp_path / "out").exists()
    monkeypatch.setenv("WARPSCATTER_DEVICE", "cuda:7")
    with pytest.raises(DeviceError, match="WARPSCATTER_DEVICE cuda:7") as e:
        warpscatter.render(ROOT / "configs" / "quickstart.yaml", out_dir=tmp_path / "out")
    assert e.value.exit_code == 2 and not (tmp_path / "out").exists()


def test_the_cli_refuses_a_device_from_the_environment(tmp_path, monkeypatch):
    from click.testing import CliRunner

    from warpscatter.cli.main import main as cli

    monkeypatch.setenv("WARPSCATTER_DEVICE", "cuda:0")
    result = CliRunner().invoke(cli, ["render", str(ROOT / "configs" / "quickstart.yaml"), "-o", str(tmp_path / "o")])
    assert result.exit_code == 2
    assert "WARPSCATTER_DEVICE cuda:0: not a device of this machine" in result.output
    assert not (tmp_path / "o").exists()


def test_the_thread_split_is_one_launch_off_the_cpu(monkeypatch):
    """launch_rows on a device that is not the CPU launches once over the whole domain, offset 0."""
    import warp as wp

    from warpscatter.runtime import parallel

    class NotCpu:
        is_cpu = False

    launches = []
    monkeypatch.setattr(parallel.wp, "get_device", lambda device=None: NotCpu())
    monkeypatch.setattr(parallel.wp, "launch", lambda kernel, dim, inputs, device: launches.append((dim, inputs[-1])))
    parallel.launch_rows("kernel", (1000, 7), ["a"], device="cpu", threads=8, min_chunk=1)
    assert launches == [((1000, 7), 0)]
    monkeypatch.undo()
    assert wp.get_device("cpu").is_cpu
