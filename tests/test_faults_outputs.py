"""One writer per output (issue 52, items 2 and 4, the output side): unique temporaries (precompute included), an
advisory lock per output name, a commit manifest that completes or rolls back a set whose writer was SIGKILLed,
reserved names refused, output folders and name lengths checked before any work, sweep file stems unique per case.

Concurrency and kills run in child processes whose ``os.replace`` is patched to sleep (slow renames) or to SIGKILL
the child at a given rename."""

import errno
import json
import os
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from warpscatter.io import output_sets
from warpscatter.io.images import ImageWriteError, read_image, write_outputs
from warpscatter.io.output_sets import remove_stale_temporaries, write_file_atomic

# The new names are read as output_sets.NAME in the tests, so that each test fails on its own against the code before.

ROOT = Path(__file__).resolve().parent.parent
AOVS = ["scattering", "surface", "depth"]
#: The output set in rename order: colour EXR, PNG, the AOVs, the sidecar.
NAMES = ["r.exr", "r.png", "r.scattering.exr", "r.surface.exr", "r.depth.exr", "r.json"]
SMALL = ["--set", "camera.width=32", "--set", "camera.height=18"]


def invoke(*args):
    """The CLI in this process (imported here: the child processes import this module and need no CLI)."""
    from click.testing import CliRunner

    from warpscatter.cli.main import main

    return CliRunner().invoke(main, [str(a) for a in args])


def images(seed: int, h: int = 3, w: int = 5) -> dict:
    rng = np.random.default_rng(seed)
    return {"color": rng.random((h, w, 3)).astype(np.float32), "scattering": rng.random((h, w, 3)).astype(np.float32),
            "surface": rng.random((h, w, 3)).astype(np.float32), "depth": rng.random((h, w)).astype(np.float32)}


def write(folder, seed: int):
    return write_outputs(folder, "r", images(seed), AOVS, sidecar={"seed": seed})


def snapshot(folder) -> dict:
    return {p.name: p.read_bytes() for p in sorted(Path(folder).iterdir())}


def set_seed(folder) -> int | None:
    """The seed of the complete set the folder holds (None: an empty folder); fails on anything else: a partial or
    mixed set, or any other file (temporaries, backups, locks, manifests)."""
    names = sorted(p.name for p in Path(folder).iterdir())
    if not names:
        return None
    assert names == sorted(NAMES), f"not a complete set: {names}"
    seed = json.loads((Path(folder) / "r.json").read_text())["seed"]
    expect = images(seed)
    for name, aov in (("r.exr", "color"), ("r.scattering.exr", "scattering"), ("r.surface.exr", "surface"),
                      ("r.depth.exr", "depth")):
        assert np.array_equal(read_image(Path(folder) / name).reshape(expect[aov].shape), expect[aov]), \
            f"{name} is not of the set of seed {seed} (a torn set)"
    return seed


#: A child writing a set (seed) into a folder, its renames patched by a plan: {"sleep": [seconds before rename 1,
#: 2, ...], "kill": ["replace", k] (SIGKILL at the k-th rename of a temporary) or ["after"] (after the last rename),
#: "go": a file to wait for before writing (the child creates GO.SEED.ready first)}.
CHILD = r"""
import json, os, signal, sys, time
from pathlib import Path
sys.path.insert(0, sys.argv[4])
import test_faults_outputs as t

folder, seed, plan = Path(sys.argv[1]), int(sys.argv[2]), json.loads(sys.argv[3])
real_replace, real_unlink = os.replace, os.unlink
installs = []

def replace(src, dst):
    if ".tmp-" in os.fspath(src) or ".tmp.npz" in os.fspath(src):
        installs.append(dst)
        k = len(installs)
        if plan.get("kill") == ["replace", k]:
            os.kill(os.getpid(), signal.SIGKILL)
        sleeps = plan.get("sleep", [])
        if k <= len(sleeps):
            time.sleep(sleeps[k - 1])
    return real_replace(src, dst)

def unlink(path, *args, **kwargs):
    if plan.get("kill") == ["after"] and len(installs) == len(t.NAMES):
        os.kill(os.getpid(), signal.SIGKILL)
    return real_unlink(path, *args, **kwargs)

os.replace, os.unlink = replace, unlink
if plan.get("go"):
    Path(f"{plan['go']}.{seed}.ready").touch()
    while not os.path.exists(plan["go"]):
        time.sleep(0.005)
t.write(folder, seed)
print("wrote", seed)
"""


def start_child(folder, seed: int, plan: dict) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", CHILD, str(folder), str(seed), json.dumps(plan),
                             str(Path(__file__).parent)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_for(paths, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not all(os.path.exists(p) for p in paths):
        assert time.monotonic() < deadline, f"children did not start: {paths}"
        time.sleep(0.01)


# ---- two renders to one name -----------------------------------------------------------------------------------


def test_two_concurrent_writers_of_one_set_leave_a_complete_set(tmp_path):
    # Old behaviour: A renames r.exr, r.png, then stalls; B renames all six; A renames its last four: a torn set
    # (EXR/PNG of B, AOVs/JSON of A), both exit 0. Now B waits for A's lock: one complete set.
    folder, go = tmp_path / "out", tmp_path / "go"
    folder.mkdir()
    a = start_child(folder, 1, {"go": str(go), "sleep": [0.0, 0.8]})
    b = start_child(folder, 2, {"go": str(go), "sleep": [0.3, 0.0]})
    wait_for([f"{go}.1.ready", f"{go}.2.ready"])
    go.touch()
    for child in (a, b):
        out, err = child.communicate(timeout=120)
        assert child.returncode == 0, err
        assert out.startswith("wrote")
    assert set_seed(folder) in (1, 2)


def test_a_second_writer_waits_then_gives_up_naming_the_first(tmp_path, monkeypatch):
    folder = tmp_path / "out"
    folder.mkdir()
    monkeypatch.setenv("WARPSCATTER_OUTPUT_LOCK_TIMEOUT", "0.3")
    with output_sets.output_lock(folder, "r"):
        t0 = time.monotonic()
        busy = rf"r\.\*: another warpscatter process \(pid {os.getpid()} "
        with pytest.raises(output_sets.OutputBusyError, match=busy):
            write(folder, 1)
        assert 0.25 < time.monotonic() - t0 < 5
    assert output_sets.OutputBusyError.exit_code == 2
    assert not list(folder.iterdir())  # nothing written, the lock file removed on release
    write(folder, 1)
    assert set_seed(folder) == 1


# ---- SIGKILL at every step of a write ---------------------------------------------------------------------------


KILL_POINTS = [["replace", k] for k in range(1, len(NAMES) + 1)] + [["after"]]


@pytest.mark.slow
@pytest.mark.parametrize("previous", [False, True], ids=["first-write", "over-a-set"])
def test_sigkill_at_every_rename_leaves_only_complete_sets(tmp_path, previous):
    # Old behaviour (first write): killed after renaming r.exr and r.png, the clean-up removed the temporaries and
    # kept r.exr and r.png without the rest. Now the manifest lets the clean-up (and the next write) roll it back.
    children = []
    for kill in KILL_POINTS:
        folder = tmp_path / f"{kill[0]}{kill[-1]}"
        folder.mkdir()
        if previous:
            write(folder, 1)
        children.append((folder, kill, start_child(folder, 2, {"kill": kill})))
    for folder, kill, child in children:
        child.communicate(timeout=120)
        assert child.returncode == -signal.SIGKILL, kill
        remove_stale_temporaries(folder)  # what the next write or a read of the folder does first
        seed = set_seed(folder)
        if kill == ["after"]:
            assert seed == 2  # every file was renamed in: the set is complete and stays
        else:
            assert seed == (1 if previous else None), kill
        write(folder, 3)  # the next write: a complete set of its own
        assert set_seed(folder) == 3


def test_the_next_write_rolls_back_a_killed_writers_partial_first_set(tmp_path):
    # Old behaviour: killed after renaming r.exr, r.png, r.scattering.exr and r.surface.exr into an empty folder;
    # the next write (colour only) removed the temporaries and kept the two AOVs of the killed set beside its own.
    folder = tmp_path / "out"
    folder.mkdir()
    child = start_child(folder, 2, {"kill": ["replace", 5]})
    child.communicate(timeout=120)
    assert child.returncode == -signal.SIGKILL
    assert (folder / "r.surface.exr").is_file()  # renamed in before the kill
    write_outputs(folder, "r", images(3), [], sidecar={"seed": 3})  # another set of outputs, same name
    assert sorted(p.name for p in folder.iterdir()) == ["r.exr", "r.json", "r.png"]  # no r.*.exr of seed 2


# ---- names and folders checked before any work -----------------------------------------------------------------


@pytest.mark.parametrize("name", [".quickstart.bak-vm-999999-abcdef", ".r.tmp-host-12-a1b2c3", ".r.commit"])
def test_names_of_the_writers_own_files_are_refused(tmp_path, name):
    with pytest.raises(output_sets.OutputNameError, match="output.name: .* is reserved") as info:
        write_outputs(tmp_path, name, images(1), AOVS)
    assert info.value.exit_code == 2 and isinstance(info.value, ValueError)
    assert not list(tmp_path.iterdir())


def test_render_refuses_a_reserved_name_before_rendering(tmp_path, monkeypatch):
    import warpscatter.pipeline as pipeline

    monkeypatch.setattr(pipeline, "render_images", lambda *a, **k: pytest.fail("rendered"))
    result = invoke("render", "quickstart", "-o", tmp_path, "--name", ".quickstart.bak-vm-999999-abcdef", *SMALL)
    assert result.exit_code == 2, result.output
    assert "output.name" in result.output and "reserved" in result.output and "Traceback" not in result.output
    assert not list(tmp_path.iterdir())


def test_render_under_a_regular_file_is_refused_before_rendering(tmp_path, monkeypatch):
    import warpscatter.pipeline as pipeline

    monkeypatch.setattr(pipeline, "render_images", lambda *a, **k: pytest.fail("rendered"))
    (tmp_path / "afile").write_text("x")
    result = invoke("render", "quickstart", "-o", tmp_path / "afile" / "sub", *SMALL)
    assert result.exit_code == 2, result.output
    assert "output.dir" in result.output and "afile is a file" in result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_render_with_a_name_too_long_for_the_file_system_is_refused_before_rendering(tmp_path, monkeypatch):
    import warpscatter.pipeline as pipeline

    monkeypatch.setattr(pipeline, "render_images", lambda *a, **k: pytest.fail("rendered"))
    result = invoke("render", "quickstart", "-o", tmp_path / "out", "--name", "a" * 230, *SMALL)
    assert result.exit_code == 2, result.output
    assert "output.name" in result.output and "too long" in result.output and "left behind" not in result.output
    assert not list(tmp_path.iterdir())


def test_the_longest_name_that_fits_is_accepted(tmp_path):
    limit = os.pathconf(tmp_path, "PC_NAME_MAX")
    n = next(n for n in range(limit, 0, -1) if not _too_long(tmp_path, "b" * n))
    write_outputs(tmp_path, "b" * n, images(1), AOVS)  # every temporary fits: no error
    assert len(list(tmp_path.iterdir())) == 5
    with pytest.raises(output_sets.OutputNameError, match="too long"):
        write_outputs(tmp_path, "b" * (n + 1), images(1), AOVS)


def _too_long(folder, name) -> bool:
    try:
        output_sets.check_output_target(folder, name, AOVS)
    except output_sets.OutputNameError:
        return True
    return False


def test_a_failed_write_does_not_claim_temporaries_it_never_made(tmp_path):
    # Old behaviour: a name whose temporaries are too long for the file system failed (after the render), then the
    # rollback reported "temporary ... left behind: File name too long" for files that never existed.
    long = "a" * 250

    def write_bytes(tmp):
        tmp.write_bytes(b"x")

    with pytest.raises(ImageWriteError, match="File name too long") as info:
        output_sets._write_all([(tmp_path / f"{long}.exr", write_bytes), (tmp_path / f"{long}.png", write_bytes)])
    assert "left behind" not in str(info.value) and "rollback" not in str(info.value)
    assert not list(tmp_path.iterdir())


# ---- precompute ------------------------------------------------------------------------------------------------


def fake_csm(n: int = 1000):
    """What save_csm reads of a CSM (a lat-long one): arrays of ``n`` segments."""
    lists = SimpleNamespace(seg_start=np.arange(n), seg_depth=np.linspace(0, 1, n), seg_end=np.arange(n))
    return SimpleNamespace(kind="latlong", params=lambda: {"n": n}, map_index=np.arange(8), lists=lists)


@pytest.mark.parametrize("fault", ["interrupt", "disk-full"])
def test_precompute_leaves_no_temporary_on_sigterm_or_a_full_disk(tmp_path, monkeypatch, fault):
    # SIGTERM is a KeyboardInterrupt in the CLI (cli/main.py). Old behaviour: OUT.npz.tmp.npz stayed.
    from warpscatter.csm.compress import save_csm

    def savez(file, **arrays):
        f = file if hasattr(file, "write") else open(file, "wb")
        f.write(b"PK partial")
        f.flush()
        if fault == "interrupt":
            raise KeyboardInterrupt
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(np, "savez", savez)
    with pytest.raises(KeyboardInterrupt if fault == "interrupt" else OSError):
        save_csm(fake_csm(), tmp_path / "g.npz")
    assert not list(tmp_path.iterdir())


@pytest.mark.slow
def test_a_killed_precomputes_temporary_is_cleaned_up(tmp_path):
    code = ("import os, signal, sys; sys.path.insert(0, sys.argv[2]); import test_faults_outputs as t\n"
            "from warpscatter.csm.compress import save_csm\n"
            "os.replace = lambda *a: os.kill(os.getpid(), signal.SIGKILL)\n"
            "save_csm(t.fake_csm(), sys.argv[1])\n")
    child = subprocess.run([sys.executable, "-c", code, str(tmp_path / "g.npz"), str(Path(__file__).parent)],
                           capture_output=True, timeout=120)
    assert child.returncode == -signal.SIGKILL, child.stderr
    left = [p.name for p in tmp_path.iterdir()]
    assert len(left) == 2 and all(output_sets.is_internal_name(n) for n in left), left  # temporary and lock
    remove_stale_temporaries(tmp_path)
    assert not list(tmp_path.iterdir())


#: ``warpscatter precompute`` with hooks: RENAMING (touched at the rename of its temporary, which then waits for the
#: file WAIT_FOR and 0.5 s more), READY (touched once the CSM is built, just before it is written).
PRECOMPUTE = r"""
import os, sys, time
from pathlib import Path
import warpscatter.csm.occluders as occluders
real, prepare = os.replace, occluders.prepare_csm
def replace(src, dst):
    if os.environ.get("RENAMING") and (".tmp-" in os.fspath(src) or ".tmp.npz" in os.fspath(src)):
        Path(os.environ["RENAMING"]).touch()
        deadline = time.monotonic() + 60
        while not os.path.exists(os.environ["WAIT_FOR"]) and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.5)
    return real(src, dst)
def prepare_csm(*args, **kwargs):
    csm = prepare(*args, **kwargs)
    if os.environ.get("READY"):
        Path(os.environ["READY"]).touch()
    return csm
os.replace, occluders.prepare_csm = replace, prepare_csm
sys.argv = ["warpscatter", "precompute", *sys.argv[1:]]
from warpscatter.cli.main import main
main()
"""


@pytest.mark.slow
def test_two_concurrent_precomputes_leave_a_valid_file(tmp_path):
    # Old behaviour: both wrote OUT.npz.tmp.npz; A renamed B's file (whole or partly written) in and B failed, or
    # the file failed its CRC while both printed "wrote". Now each has its own temporary and B waits for A's lock.
    out, renaming, ready = tmp_path / "g.npz", tmp_path / "a-renaming", tmp_path / "b-ready"
    base = [sys.executable, "-c", PRECOMPUTE, str(ROOT / "assets" / "gate.obj"), "-o", str(out), "--resolution", "32"]
    a = subprocess.Popen([*base, "--maps", "8x4"], env={**os.environ, "RENAMING": str(renaming),
                                                        "WAIT_FOR": str(ready)},
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_for([renaming], timeout=120)  # A holds its file, about to rename it in
    b = subprocess.run([*base, "--maps", "4x4"], env={**os.environ, "READY": str(ready)}, capture_output=True,
                       text=True, timeout=120)
    a_out, a_err = a.communicate(timeout=120)
    assert a.returncode == 0 and "wrote" in a_out, a_err
    assert b.returncode == 0 and "wrote" in b.stdout, b.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-renaming", "b-ready", "g.npz"]
    with zipfile.ZipFile(out) as z:
        assert z.testzip() is None
    from warpscatter.csm import load_csm

    assert load_csm(out).num_maps == 16  # B's, written last


@pytest.mark.parametrize("target, message", [
    ("afile/sub/g.npz", "afile is a file"),
    (".g.tmp-host-12-a1b2c3.npz", "reserved"),
    ("x" * 250 + ".npz", "too long"),
])
def test_precompute_refuses_an_unwritable_output_before_any_work(tmp_path, target, message):
    (tmp_path / "afile").write_text("x")
    result = invoke("precompute", ROOT / "assets" / "gate.obj", "-o", tmp_path / target, "--maps", "8x4",
                    "--resolution", "32")
    assert result.exit_code == 2, result.output
    assert "-o: " in result.output and message in result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_write_file_atomic_removes_its_temporary_when_interrupted(tmp_path):
    def interrupted(tmp):
        tmp.write_bytes(b"partial")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_file_atomic(tmp_path / "g.npz", interrupted)
    assert not list(tmp_path.iterdir())


# ---- sweeps ----------------------------------------------------------------------------------------------------


def test_sweep_file_stems_are_unique_stable_and_readable():
    from warpscatter.runs.sweep import file_stems

    labels = ["q/name=x y", "q/name=x_y", "q/name=x,y", "q/steps=8", "Q/steps=8"]
    stems = file_stems(labels)
    assert len({s.casefold() for s in stems}) == len(stems)
    assert [s.rsplit("-", 1)[0] for s in stems] == ["q_name-x_y"] * 3 + ["q_steps-8", "Q_steps-8"]
    assert file_stems(list(reversed(labels))) == list(reversed(stems))  # a stem depends on its label, not order
    assert file_stems(["q/steps=8", "q/steps=16"]) == ["q_steps-8", "q_steps-16"]  # no collision: as before
    long = file_stems(["q/" + "k=v," * 100])[0]
    assert len(long) < 120


@pytest.mark.slow
def test_sweep_cases_whose_labels_map_to_one_stem_write_their_own_sets(tmp_path):
    # Old behaviour: "name=x y" and "name=x_y" both wrote quickstart_name-x_y.*: one set, exit 0.
    from warpscatter.runs.sweep import load_sweep, run_sweep

    path = tmp_path / "sweep.yaml"
    path.write_text(yaml.safe_dump({"configs": [str(ROOT / "configs" / "quickstart.yaml")], "images": True,
                                    "set": {"camera.width": 32, "camera.height": 18, "output.aovs": []},
                                    "grid": {"output.name": ["x y", "x_y"]}}))
    result = run_sweep(load_sweep(path), tmp_path / "out")
    assert not result.failed
    sidecars = sorted((tmp_path / "out" / "sweep").glob("*.json"))
    assert len(sidecars) == 2, sidecars
