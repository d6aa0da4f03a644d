"""Collecting and running the fenced code blocks of the README and the docs (used by tests/test_doc_examples.py,
tests/test_readme.py and tests/test_moments.py; the convention is stated at the top of tests/test_doc_examples.py).
"""

from __future__ import annotations

import contextlib
import glob
import io
import os
import re
import runpy
import shlex
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"

#: Languages whose blocks run (python), run as commands (the shells), are validated (yaml), or are left alone.
PYTHON = {"python", "py", "python3"}
SHELL = {"bash", "sh", "shell", "console", "shell-session"}
YAML = {"yaml", "yml"}

#: ``<!-- example: skip REASON -->`` / ``standalone`` / ``file PATH`` on the last non-blank line before a fence.
MARKER = re.compile(r"^\s*<!--\s*example:\s*(\S+)(.*?)-->\s*$")
FENCE = re.compile(r"^(?P<indent> {0,3})(?P<fence>`{3,}|~{3,})\s*(?P<info>[^`]*)$")


@dataclass
class Block:
    """One fenced code block: where it is, its language, its text and the example marker before it."""

    path: Path  # the page
    line: int  # 1-based line of the opening fence
    lang: str  # the info string's first word, lower case ("" for none)
    code: str
    marker: str | None = None  # skip | standalone | file | None
    argument: str = ""  # the marker's reason (skip) or path (file)

    @property
    def where(self) -> str:
        rel = self.path.relative_to(ROOT) if self.path.is_relative_to(ROOT) else self.path
        first = next((line for line in self.code.splitlines() if line.strip()), "")
        return f"{rel}:{self.line} (```{self.lang} block starting {first.strip()[:70]!r})"


def pages() -> list[Path]:
    """The README and every Markdown page of docs/ (the build folder aside)."""
    docs = sorted(p for p in DOCS.rglob("*.md") if "_build" not in p.relative_to(DOCS).parts)
    return [ROOT / "README.md", *docs]


def blocks(path: Path, text: str | None = None) -> list[Block]:
    """The fenced code blocks of a Markdown page, in order, with their markers (MyST directives such as
    ```` ```{toctree} ```` are not code blocks)."""
    lines = (path.read_text(encoding="utf-8") if text is None else text).splitlines()
    out: list[Block] = []
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        fence, info = m.group("fence"), m.group("info").strip()
        body = []
        j = i + 1
        while j < len(lines) and not re.match(rf"^ {{0,3}}{re.escape(fence[0])}{{{len(fence)},}}\s*$", lines[j]):
            body.append(lines[j][len(m.group("indent")):] if lines[j].startswith(m.group("indent")) else lines[j])
            j += 1
        lang = info.split()[0].lower() if info else ""
        if not lang.startswith("{"):
            prev = next((lines[k] for k in range(i - 1, -1, -1) if lines[k].strip()), "")
            mk = MARKER.match(prev)
            out.append(Block(path, i + 1, lang, "\n".join(body) + "\n", mk.group(1) if mk else None,
                             mk.group(2).strip() if mk else ""))
        i = j + 1
    return out


def find_blocks(marker: str, lang: str = "python") -> list[Block]:
    """The blocks of the README and the docs in ``lang`` that contain ``marker``, at least one (a test's semantic
    checks find the example they check this way, wherever the text moves it)."""
    found = [b for p in pages() for b in blocks(p) if b.lang in ({lang} | (PYTHON if lang in PYTHON else set()))
             and marker in b.code]
    assert found, f"no ```{lang} block of README.md or docs/ contains {marker!r}"
    return found


# ---- Python blocks -------------------------------------------------------------------------------------------


def run_python(block: Block, namespace: dict, folder: Path, index: int) -> None:
    """Run a Python block in ``namespace`` (a page's shared one, or a fresh one), from a real file: Warp reads a
    kernel's source from its file, so the block is written to ``folder`` and compiled with that file name."""
    path = folder / f"_doc_block_{index}.py"
    path.write_text(block.code, encoding="utf-8")
    code = compile(block.code, str(path), "exec")
    exec(code, namespace)  # noqa: S102  (the example's text, as a user pastes it)


def new_namespace() -> dict:
    """A namespace as ``python script.py`` gives (``__name__ == "__main__"``, so guarded examples run)."""
    return {"__name__": "__main__", "__builtins__": __builtins__}


# ---- shell blocks --------------------------------------------------------------------------------------------


def commands(block: Block) -> list[tuple[int, str]]:
    """(line number, command) of a shell block: ``$ `` lines of a console block (other lines are output), every
    line of the others; comments dropped, ``\\`` continuations joined, ``&&`` chains split."""
    out: list[tuple[int, str]] = []
    pending, start = "", 0
    for k, raw in enumerate(block.code.splitlines()):
        line = raw.rstrip()
        if not pending:
            if block.lang in ("console", "shell-session"):
                if not line.startswith("$ "):
                    continue
                line = line[2:]
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            start = block.line + 1 + k
        if line.endswith("\\"):
            pending += line[:-1] + " "
            continue
        full = pending + line
        pending = ""
        for part in _split_and(_strip_comment(full)):
            if part.strip():
                out.append((start, part.strip()))
    return out


def _strip_comment(line: str) -> str:
    """The line without a trailing ``# comment`` (outside quotes)."""
    lex = shlex.shlex(line, posix=True, punctuation_chars=False)
    lex.whitespace_split = True
    lex.commenters = "#"
    try:
        tokens = list(lex)
    except ValueError:
        return line
    if not tokens:
        return ""
    # cut the original text after the last token (keeps quoting intact)
    hash_at = [m.start() for m in re.finditer(r"(?<=\s)#", line)]
    for pos in hash_at:
        try:
            shlex.split(line[:pos])
        except ValueError:
            continue  # inside quotes
        return line[:pos].rstrip()
    return line


def _split_and(line: str) -> list[str]:
    parts, quote, cur, i = [], None, "", 0
    while i < len(line):
        c = line[i]
        if quote:
            quote = None if c == quote else quote
        elif c in "'\"":
            quote = c
        elif line.startswith("&&", i):
            parts.append(cur)
            cur, i = "", i + 2
            continue
        cur += c
        i += 1
    return [*parts, cur]


@dataclass
class Shell:
    """Runs a page's commands in-process from ``cwd`` (a folder laid out like a fresh clone)."""

    cwd: Path
    env: dict = field(default_factory=dict)
    log: list = field(default_factory=list)

    def run(self, command: str) -> tuple[int, str]:
        """(exit code, output) of one command line; ``CMD || true`` (an example that shows an error on purpose)
        runs CMD and succeeds unless CMD cannot run here."""
        allowed_to_fail = re.fullmatch(r"(.*?)\s*\|\|\s*true", command.strip())
        if allowed_to_fail:
            code, out = self.run(allowed_to_fail.group(1))
            return (code if code == 127 else 0), out
        argv = shlex.split(command)
        env = {}
        while argv and re.match(r"^[A-Za-z_]\w*=", argv[0]):
            key, value = argv.pop(0).split("=", 1)
            env[key] = value
        if not argv:
            self.env.update(env)
            return 0, ""
        if argv[0] == "export":
            for item in argv[1:]:
                key, _, value = item.partition("=")
                self.env[key] = value
            return 0, ""
        redirect = None
        if ">" in argv:
            k = argv.index(">")
            redirect, argv = argv[k + 1], argv[:k]
        argv = [a for arg in argv for a in self._glob(arg)]
        prog = argv[0]
        with _environ({**self.env, **env}), _chdir(self.cwd):
            if prog == "cd":
                self.cwd = (self.cwd / argv[1]).resolve()
                return 0, ""
            if prog == "warpscatter" or prog.endswith("/warpscatter"):
                code, out = self._cli(argv[1:])
            elif prog in ("python", "python3") or prog.endswith(("/python", "/python3")):
                code, out = self._python(argv[1:])
            elif prog in ("mkdir", "ls", "cat", "cp", "mv", "rm", "head", "tail", "echo", "test", "touch"):
                code, out = self._tool(argv)
            else:
                return 127, (f"`{prog}` cannot run in the test: put <!-- example: skip REASON --> before the block "
                             "if it must stay")
        if redirect is not None:
            (self.cwd / redirect).write_text(out, encoding="utf-8")
        return code, out

    def _glob(self, arg: str) -> list[str]:
        if any(c in arg for c in "*?[") and not arg.startswith("-") and "=" not in arg:
            hits = sorted(glob.glob(arg, root_dir=self.cwd))
            return hits or [arg]
        return [arg]

    def _cli(self, args: list[str]) -> tuple[int, str]:
        from click.testing import CliRunner

        from warpscatter.cli.main import main

        args = shrink_cli_args(args)
        self.log.append(["warpscatter", *args])
        result = CliRunner().invoke(main, args, catch_exceptions=True)
        out = result.output
        if result.exception is not None and not isinstance(result.exception, SystemExit):
            import traceback

            out += "".join(traceback.format_exception(result.exception))
        return result.exit_code, out

    def _python(self, args: list[str]) -> tuple[int, str]:
        if args[:1] == ["-m"] and len(args) > 1:
            target, rest, run = args[1], args[2:], runpy.run_module
            if target in ("pip", "venv", "pytest"):
                return 127, f"`python -m {target}` cannot run in the test: mark the block skip with a reason"
            rest = shrink_module_args(target, rest)
        elif args and args[0].endswith(".py"):
            target, rest, run = str(self.cwd / args[0]), args[1:], runpy.run_path
        else:
            return 127, f"unsupported python invocation {args}"
        self.log.append(["python", *args[:2], *rest])
        buf = io.StringIO()
        old_argv = sys.argv
        sys.argv = [target, *rest]
        code = 0
        try:
            with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
                run(target, run_name="__main__")
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
            if isinstance(exc.code, str):
                buf.write(exc.code)
        except Exception:  # noqa: BLE001  (reported with the block's location)
            import traceback

            buf.write(traceback.format_exc())
            code = 1
        finally:
            sys.argv = old_argv
        return code, buf.getvalue()

    def _tool(self, argv: list[str]) -> tuple[int, str]:
        import subprocess

        proc = subprocess.run(argv, cwd=self.cwd, capture_output=True, text=True, check=False,
                              env={**os.environ, **self.env})
        return proc.returncode, proc.stdout + proc.stderr


@contextlib.contextmanager
def _environ(values: dict):
    old = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@contextlib.contextmanager
def _chdir(path: Path):
    old = os.getcwd()
    os.chdir(path)
    try:
        yield
    finally:
        os.chdir(old)


# ---- small renders -------------------------------------------------------------------------------------------

#: The longest image side a doc example renders at in the tests (the text prints real sizes, e.g. 960x540).
MAX_SIDE = 64
#: The largest shadow map an example gets in the tests (animations keep their frames: the pages pick frames with
#: --frames, and a frame at MAX_SIDE pixels is cheap).
MAX_SHADOW_MAP = 256


def shrink_config_data(data):
    """A copy of config data (a dict as YAML reads it) with the camera at most MAX_SIDE pixels on its longer side
    (aspect kept; the default size too) and shadow maps at most MAX_SHADOW_MAP texels wide. Anything that is not
    such a dict is returned unchanged (validation reports it)."""
    if not isinstance(data, dict):
        return data
    data = dict(data)
    camera = data.get("camera")
    if isinstance(camera, dict):
        from warpscatter.config import CameraConfig

        camera = dict(camera)
        w = camera.get("width", CameraConfig.model_fields["width"].default)
        h = camera.get("height", CameraConfig.model_fields["height"].default)
        if _is_int(w) and _is_int(h) and max(w, h) > MAX_SIDE:
            s = MAX_SIDE / max(w, h)
            camera["width"], camera["height"] = max(2, round(w * s)), max(2, round(h * s))
        data["camera"] = camera
    render = data.get("render")
    if isinstance(render, dict):
        data["render"] = _cap_key(render, "resolution", MAX_SHADOW_MAP)
    return data


def _cap_key(node, key: str, cap: int):
    if isinstance(node, dict):
        return {k: (min(v, cap) if k == key and _is_int(v) else _cap_key(v, key, cap)) for k, v in node.items()}
    return node


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def shrink_configs(monkeypatch) -> None:
    """Wrap ``Config.model_validate`` (monkeypatch) so that every config validated from now on is shrunk
    (:func:`shrink_config_data`): the data it validates, never the text of the example."""
    from warpscatter.config import Config

    original = Config.model_validate.__func__

    def model_validate(cls, obj, *args, **kwargs):
        return original(cls, shrink_config_data(obj), *args, **kwargs)

    monkeypatch.setattr(Config, "model_validate", classmethod(model_validate))


def run_examples(marker: str, tmp_path: Path, monkeypatch) -> list[tuple[Block, dict]]:
    """Run each Python block of the README and the docs that contains ``marker`` (on its own) from a fresh clone
    folder under ``tmp_path``, at small sizes; (block, its namespace) for a test's own checks."""
    found = find_blocks(marker)
    clone = clone_folder(tmp_path / "clone")
    monkeypatch.chdir(clone)
    shrink_configs(monkeypatch)
    out = []
    for k, block in enumerate(found):
        namespace = new_namespace()
        try:
            run_python(block, namespace, tmp_path, k)
        except Exception as exc:
            raise AssertionError(f"{block.where} raised {type(exc).__name__}: {exc}") from exc
        out.append((block, namespace))
    return out


def shrink_cli_args(args: list[str]) -> list[str]:
    """``bench`` runs its ``--quick`` suites with one repeat and no warm-up, ``gallery`` its ``--quick`` set; other
    commands are unchanged (their configs are shrunk on validation)."""
    if args[:1] == ["gallery"] and "--quick" not in args and not any(a in ("-h", "--help") for a in args):
        return [*args, "--quick"]
    if args[:1] == ["bench"] and not any(a in ("--list", "-h", "--help") for a in args):
        has_suite = len([a for a in args[1:] if not a.startswith("-")]) >= 1
        extra = ["--quick"] if "--quick" not in args else []
        if not any(a.startswith("--repeats") for a in args):
            extra += ["--repeats", "1"]
        if not any(a.startswith("--warmup") for a in args):
            extra += ["--warmup", "0"]
        return [*args, *extra] if has_suite or extra else args
    return args


def shrink_module_args(module: str, args: list[str]) -> list[str]:
    """``python -m warpscatter.runs.gallery`` runs with ``--quick``."""
    if module.endswith(".gallery") and "--quick" not in args and not any(a in ("-h", "--help") for a in args):
        return [*args, "--quick"]
    return args


def clone_folder(tmp: Path) -> Path:
    """A folder that looks like the root of a fresh clone: configs/, docs/ and the README copied (so that what an
    example writes, a config's ``output.dir: ../out``, a regenerated page or picture, lands in ``tmp``, never in the
    repository) and assets/ linked (read only)."""
    shutil.copytree(ROOT / "configs", tmp / "configs")
    shutil.copytree(DOCS, tmp / "docs", ignore=shutil.ignore_patterns("_build", "__pycache__"))
    shutil.copy2(ROOT / "README.md", tmp / "README.md")
    (tmp / "assets").symlink_to(ROOT / "assets", target_is_directory=True)
    return tmp
