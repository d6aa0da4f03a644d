"""Every fenced code block of the README and of docs/**/*.md runs, as printed (issue #50: "every example runs").

The convention (docs/index.md, "Contributing to the docs", says the same in short):

- ```` ```python ```` blocks of a page run in order in ONE namespace (a later block may use the names of an
  earlier one), as ``python script.py`` would run them (``__name__ == "__main__"``); each block is written to a file
  first, because Warp reads a kernel's source from its file.
- ```` ```bash ````, ```` ```sh ````, ```` ```shell ```` blocks: every line is a command; ```` ```console ````: the
  lines after ``$ `` are (the rest is output). Comments are dropped, ``\\`` continuations joined, ``A && B``
  split. ``warpscatter ...`` (also ``.venv/bin/warpscatter``) runs in-process through click's CliRunner;
  ``python -m warpscatter.X`` and ``python FILE.py`` in-process through runpy; ``cd``, ``mkdir``, ``ls``, ``cat``
  ... as processes; leading ``VAR=value`` set the environment. Each command must exit 0. Anything else (``pip``,
  ``git``, ``python -m venv``) fails the test and must be marked skip.
- ```` ```yaml ```` blocks with ``scene``, ``camera`` and ``light`` are whole configs: validated with
  ``warpscatter.load_config`` (paths relative to ``configs/``, as for a config saved there, else to the clone's
  root); other YAML blocks must parse. ```` ```text ````, ```` ```output ```` and the rest do not run.
- A marker on the last non-blank line before the fence changes that:
  ``<!-- example: skip REASON -->`` does not run the block (a marker without a reason fails the test);
  ``<!-- example: standalone -->`` runs a Python block in a fresh namespace of its own;
  ``<!-- example: file PATH -->`` saves the block's text as ``PATH`` (relative to the clone's root) for a later
  command of the page (a YAML file saved so is also checked as above).

Where the examples stand: each page runs from its own temporary folder laid out like the root of a fresh clone
(``configs/`` copied, so that a config's ``output.dir: ../out`` lands in the temporary folder; ``assets/`` linked).

Small renders, text unchanged: the pages print real sizes (960x540, 1024-texel shadow maps).
The test shrinks them where every config passes, in validation: ``Config.model_validate`` is wrapped (monkeypatch)
so that the data it validates has the camera at most ``doc_examples.MAX_SIDE`` pixels on its longer side (aspect
kept, the default size included) and shadow maps at most ``MAX_SHADOW_MAP`` texels. Every path into a render
(YAML file, dict, ``--set``, ``model_copy``, a sweep's cases, the workers of an executor, which receive validated
data) goes through it. ``warpscatter bench`` gets ``--quick --repeats 1 --warmup 0`` and
``python -m warpscatter.runs.gallery`` ``--quick`` appended.
"""

from __future__ import annotations

import re
from pathlib import Path

import doc_examples as de
import pytest
import yaml

PAGES = de.pages()


def _id(path: Path) -> str:
    return str(path.relative_to(de.ROOT))


@pytest.fixture
def small_renders(monkeypatch):
    """Every config validated while the fixture is active is shrunk (doc_examples.shrink_config_data)."""
    de.shrink_configs(monkeypatch)


def _check_markers(page_blocks: list[de.Block]) -> None:
    for b in page_blocks:
        if b.marker is None:
            continue
        assert b.marker in ("skip", "standalone", "file"), f"{b.where}: unknown example marker {b.marker!r}"
        if b.marker == "skip":
            assert b.argument, f"{b.where}: <!-- example: skip --> needs a reason: <!-- example: skip REASON -->"
        if b.marker == "file":
            assert b.argument and not Path(b.argument).is_absolute() and ".." not in Path(b.argument).parts, (
                f"{b.where}: <!-- example: file PATH --> needs a relative PATH inside the clone")
        if b.marker == "standalone":
            assert b.lang in de.PYTHON, f"{b.where}: `standalone` applies to Python blocks"


def _check_yaml(block: de.Block, clone: Path) -> None:
    from warpscatter import load_config
    from warpscatter.errors import ConfigError

    try:
        data = yaml.safe_load(block.code)
    except yaml.YAMLError as exc:
        pytest.fail(f"{block.where}: not YAML: {exc}")
    if not (isinstance(data, dict) and {"scene", "camera", "light"} <= set(data)):
        return
    if block.marker == "file":
        load_config(str(clone / block.argument))
        return
    errors = []
    for folder in (clone / "configs", clone):
        try:
            load_config(data, config_dir=folder)
            return
        except ConfigError as exc:
            errors.append(str(exc))
    pytest.fail(f"{block.where}: the config does not validate:\n{errors[0]}")


@pytest.mark.parametrize("page", PAGES, ids=_id)
def test_page_examples_run(page, tmp_path, small_renders, monkeypatch):
    page_blocks = de.blocks(page)
    _check_markers(page_blocks)
    runnable = [b for b in page_blocks if b.marker != "skip" and b.lang in de.PYTHON | de.SHELL | de.YAML]
    if not runnable:
        pytest.skip(f"{_id(page)} has no runnable code block")
    clone = de.clone_folder(tmp_path / "clone")
    scripts = tmp_path / "blocks"
    scripts.mkdir()
    monkeypatch.chdir(clone)
    monkeypatch.syspath_prepend(str(clone))  # `import` of a file a block saved
    shell = de.Shell(clone)
    namespace = de.new_namespace()
    for k, block in enumerate(runnable):
        if block.marker == "file":
            target = clone / block.argument
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(block.code, encoding="utf-8")
            if block.lang in de.YAML:
                _check_yaml(block, clone)
            continue
        if block.lang in de.YAML:
            _check_yaml(block, clone)
        elif block.lang in de.PYTHON:
            ns = de.new_namespace() if block.marker == "standalone" else namespace
            try:
                de.run_python(block, ns, scripts, k)
            except BaseException as exc:  # noqa: BLE001  (SystemExit too: reported with the block's place)
                if isinstance(exc, SystemExit) and exc.code in (0, None):
                    continue
                raise AssertionError(f"{block.where} raised {type(exc).__name__}: {exc}") from exc
        else:
            cmds = de.commands(block)
            assert cmds, f"{block.where}: a shell block without a command (use ```text for output)"
            for line, command in cmds:
                code, out = shell.run(command)
                assert code == 0, (f"{_id(page)}:{line}: `{command}` exited {code} (block at {block.where}):\n"
                                   f"{out[-3000:]}")


# ---- the convention itself ------------------------------------------------------------------------------------


def test_blocks_markers_and_commands_are_parsed():
    text = """
Some text.

<!-- example: skip installs into a new virtualenv -->
```bash
python -m venv .venv && .venv/bin/pip install -e .
```

<!-- example: standalone -->

```python
x = 1
```

```console
$ warpscatter render configs/quickstart.yaml \\
    --set camera.fov_y=40   # a comment
wrote out/quickstart.png
$ ls out && echo "a # not a comment"
```

```{toctree}
index
```
"""
    got = de.blocks(Path("page.md"), text)
    assert [(b.lang, b.marker, b.argument, b.line) for b in got] == [
        ("bash", "skip", "installs into a new virtualenv", 5), ("python", "standalone", "", 11),
        ("console", None, "", 15)]
    assert de.commands(got[2]) == [(16, "warpscatter render configs/quickstart.yaml      --set camera.fov_y=40"),
                                   (19, "ls out"), (19, 'echo "a # not a comment"')]


def test_a_skip_marker_needs_a_reason():
    text = "<!-- example: skip -->\n```bash\nwarpscatter --version\n```\n"
    with pytest.raises(AssertionError, match="needs a reason"):
        _check_markers(de.blocks(Path("page.md"), text))


def test_configs_are_shrunk_and_text_is_not(small_renders, tmp_path):
    import warpscatter

    config = warpscatter.load_config(str(de.ROOT / "configs" / "quickstart.yaml"),
                                     {"camera.width": 960, "camera.height": 540})
    assert max(config.camera.width, config.camera.height) <= de.MAX_SIDE
    assert abs(config.camera.width / config.camera.height - 16 / 9) < 0.05
    assert de.shrink_cli_args(["bench", "prefiltered"]) == ["bench", "prefiltered", "--quick", "--repeats", "1",
                                                            "--warmup", "0"]


# ---- images ---------------------------------------------------------------------------------------------------

#: Markdown images ``![alt](path "title")``, MyST/RST ``{image}`` / ``{figure}`` / ``.. image::`` directives and
#: HTML ``<img src=...>``.
_IMAGE_PATTERNS = [re.compile(r"!\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)"),
                   re.compile(r"^\s*(?:```|:::)\{(?:image|figure)\}\s+(\S+)", re.M),
                   re.compile(r"^\s*\.\. (?:image|figure)::\s+(\S+)", re.M),
                   re.compile(r"<img\s[^>]*src=[\"']([^\"']+)[\"']", re.I)]


def images(page: Path) -> list[tuple[int, str]]:
    """(line, target) of every image a page names (outside code blocks and inline code)."""
    text = page.read_text(encoding="utf-8")
    text = re.sub(r"(`+)(?!`)(.+?)(?<!`)\1(?!`)", lambda m: " " * len(m.group(0)), text)  # inline code, same lines
    fenced = {b.line + k for b in de.blocks(page, text) for k in range(len(b.code.splitlines()) + 2)}
    out = []
    for pattern in _IMAGE_PATTERNS:
        for m in pattern.finditer(text):
            line = text.count("\n", 0, m.start(1)) + 1
            if line not in fenced:
                out.append((line, m.group(1)))
    return out


@pytest.mark.parametrize("page", PAGES, ids=_id)
def test_named_images_exist(page):
    missing = []
    for line, target in images(page):
        if re.match(r"^[a-z]+://", target) or target.startswith("data:"):
            continue
        path = target.split("#")[0].split("?")[0]
        resolved = (de.DOCS / path.lstrip("/")) if path.startswith("/") else (page.parent / path)
        if not resolved.is_file():
            missing.append(f"{_id(page)}:{line}: {target}")
    assert not missing, "images named but missing:\n" + "\n".join(missing)


def test_image_patterns(tmp_path):
    page_text = ('![a](images/x.png) and `![b](in/code.png)`\n\n```{figure} images/y.png\n:alt: y\n```\n\n'
                 '<img src="z.png" width=3>\n\n```python\n# ![not](an/image.png)\n```\n')
    page = tmp_path / "page.md"
    page.write_text(page_text, encoding="utf-8")
    assert sorted(t for _, t in images(page)) == ["images/x.png", "images/y.png", "z.png"]
