"""Output sets are all or nothing (issue 17, item 1): whatever fails while a render's files are written or renamed in,
the folder afterwards holds either the complete previous set, byte for byte, or the complete new one, and no
temporary or backup file."""

import errno
import json
import os
import subprocess
import sys

import numpy as np
import OpenImageIO as oiio
import pytest

from warpscatter.io import images as imageio
from warpscatter.io import output_sets
from warpscatter.io.images import ImageWriteError, read_image, write_outputs
from warpscatter.io.output_sets import _host_tag, remove_stale_temporaries

AOVS = ["scattering", "surface", "depth"]
#: The output set in output order: colour EXR, PNG, the AOVs, the sidecar.
NAMES = ["r.exr", "r.png", "r.scattering.exr", "r.surface.exr", "r.depth.exr", "r.json"]


def images(seed: int, h: int = 3, w: int = 5) -> dict:
    rng = np.random.default_rng(seed)
    return {"color": rng.random((h, w, 3)).astype(np.float32), "scattering": rng.random((h, w, 3)).astype(np.float32),
            "surface": rng.random((h, w, 3)).astype(np.float32), "depth": rng.random((h, w)).astype(np.float32)}


def write(folder, seed: int, aovs=AOVS):
    return write_outputs(folder, "r", images(seed), aovs, sidecar={"seed": seed})


def snapshot(folder) -> dict:
    """Every entry of the folder (hidden ones included): file bytes, or ``"<dir>"``."""
    return {p.name: "<dir>" if p.is_dir() else p.read_bytes() for p in sorted(folder.iterdir())}


def assert_set_of(folder, seed: int):
    """The folder holds exactly the complete set written with ``seed`` (pixels and sidecar; EXR headers hold the
    time of writing, so bytes are not compared)."""
    assert sorted(p.name for p in folder.iterdir()) == sorted(NAMES)
    expect = images(seed)
    for name, aov in (("r.exr", "color"), ("r.scattering.exr", "scattering"), ("r.surface.exr", "surface"),
                      ("r.depth.exr", "depth")):
        assert np.array_equal(read_image(folder / name).reshape(expect[aov].shape), expect[aov]), name
    assert json.loads((folder / "r.json").read_text())["seed"] == seed


@pytest.fixture
def sets(tmp_path):
    """(folder, snapshot of the previous set, seed of the new set)."""
    folder = tmp_path / "out"
    write(folder, 1)
    old = snapshot(folder)
    assert sorted(old) == sorted(NAMES)
    return folder, old, 2


def assert_previous_set(folder, old):
    now = snapshot(folder)
    assert sorted(now) == sorted(old), f"files differ: {sorted(now)} != {sorted(old)}"
    for name in old:
        assert now[name] == old[name], f"{name} changed"


def fail_install(monkeypatch, nth: int, exc: BaseException):
    """Make the ``nth`` (1-based) rename of a temporary onto its target raise ``exc``; other renames (restoring
    backups) work."""
    real = os.replace
    installs = []

    def replace(src, dst):
        if ".tmp-" in os.fspath(src):
            installs.append(os.fspath(dst))
            if len(installs) == nth:
                raise exc
        return real(src, dst)

    monkeypatch.setattr(imageio.os, "replace", replace)
    return installs


def test_success_replaces_the_set_and_leaves_no_backup(sets):
    folder, _, new = sets
    write(folder, 2)
    assert_set_of(folder, new)


def test_an_output_the_new_set_does_not_write_is_left_alone(sets):
    folder, old, _ = sets
    write(folder, 2, aovs=["scattering"])
    now = snapshot(folder)
    assert sorted(now) == sorted(NAMES)
    assert now["r.depth.exr"] == old["r.depth.exr"] and now["r.surface.exr"] == old["r.surface.exr"]
    assert now["r.exr"] != old["r.exr"]


def test_directory_squatting_a_target_keeps_the_previous_set(sets):
    # The reproduction: NAME.scattering.exr replaced by a folder, render again.
    folder, _, _ = sets
    (folder / "r.scattering.exr").unlink()
    (folder / "r.scattering.exr").mkdir()
    old = snapshot(folder)
    with pytest.raises(ImageWriteError, match=r"cannot write .*r\.scattering\.exr: .*Is a directory"):
        write(folder, 2)
    assert_previous_set(folder, old)


def test_rename_failure_on_the_third_file_keeps_the_previous_set(sets, monkeypatch):
    folder, old, _ = sets
    installs = fail_install(monkeypatch, 3, OSError(errno.EIO, "Input/output error"))
    with pytest.raises(ImageWriteError, match=r"cannot write .*r\.scattering\.exr: .*Input/output error"):
        write(folder, 2)
    assert len(installs) == 3  # two files were renamed in before the failure, and rolled back
    assert_previous_set(folder, old)


def test_rename_failure_without_hard_links_keeps_the_previous_set(sets, monkeypatch):
    # File systems without hard links: the previous files are renamed aside instead.
    folder, old, new = sets

    def no_links(*args, **kwargs):
        raise OSError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(imageio.os, "link", no_links)
    fail_install(monkeypatch, 4, OSError(errno.EIO, "Input/output error"))
    with pytest.raises(ImageWriteError, match=r"r\.surface\.exr"):
        write(folder, 2)
    assert_previous_set(folder, old)
    monkeypatch.undo()
    monkeypatch.setattr(imageio.os, "link", no_links)
    write(folder, 2)
    assert_set_of(folder, new)


def test_full_disk_while_renaming_keeps_the_previous_set(sets, monkeypatch):
    folder, old, _ = sets
    fail_install(monkeypatch, 4, OSError(errno.ENOSPC, "No space left on device"))
    with pytest.raises(ImageWriteError, match="No space left on device"):
        write(folder, 2)
    assert_previous_set(folder, old)


def test_full_disk_while_writing_keeps_the_previous_set(sets, monkeypatch):
    folder, old, _ = sets
    real = imageio._write_oiio

    def disk_full(path, *args, **kwargs):
        real(path, *args, **kwargs)
        if path.name.startswith(".r.surface.tmp-"):
            raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(imageio, "_write_oiio", disk_full)
    with pytest.raises(ImageWriteError, match=r"r\.surface\.exr: .*No space left on device"):
        write(folder, 2)
    assert_previous_set(folder, old)


def test_full_disk_at_fsync_keeps_the_previous_set(sets, monkeypatch):
    folder, old, _ = sets
    real = os.fsync
    calls = []

    def fsync(fd):
        calls.append(fd)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(fd)

    monkeypatch.setattr(imageio.os, "fsync", fsync)
    with pytest.raises(ImageWriteError, match="No space left on device"):
        write(folder, 2)
    assert_previous_set(folder, old)


class _FailingOutput:
    """An OpenImageIO ImageOutput whose write_image fails (returns False) for the temporary of one output."""

    def __init__(self, real, fail):
        self._real, self._fail = real, fail

    def __getattr__(self, name):
        return getattr(self._real, name)

    def write_image(self, pixels):
        return False if self._fail else self._real.write_image(pixels)


@pytest.mark.parametrize("how", ["returns_false", "raises"])
def test_openimageio_write_failure_keeps_the_previous_set(sets, monkeypatch, how):
    folder, old, _ = sets
    real_create = oiio.ImageOutput.create

    class Factory:
        @staticmethod
        def create(name):
            out = real_create(name)
            fail = os.path.basename(name).startswith(".r.depth.tmp-")
            if fail and how == "raises":
                raise RuntimeError("encoder crashed")
            return _FailingOutput(out, fail)

    monkeypatch.setattr(imageio.oiio, "ImageOutput", Factory)
    with pytest.raises(ImageWriteError, match=r"cannot write .*r\.depth\.exr"):
        write(folder, 2)
    assert_previous_set(folder, old)


@pytest.mark.parametrize("nth", [1, 3, 6])
def test_keyboard_interrupt_while_renaming_keeps_the_previous_set(sets, monkeypatch, nth):
    folder, old, _ = sets
    fail_install(monkeypatch, nth, KeyboardInterrupt())
    with pytest.raises(KeyboardInterrupt):
        write(folder, 2)
    assert_previous_set(folder, old)


def test_keyboard_interrupt_after_keeping_a_backup_keeps_the_previous_set(sets, monkeypatch):
    # Interrupted between keeping the previous file (hard link) and renaming the new one in.
    folder, old, _ = sets
    real = os.link
    calls = []

    def link(src, dst, **kwargs):
        real(src, dst, **kwargs)
        calls.append(dst)
        if len(calls) == 2:
            raise KeyboardInterrupt

    monkeypatch.setattr(imageio.os, "link", link)
    with pytest.raises(KeyboardInterrupt):
        write(folder, 2)
    assert_previous_set(folder, old)


def test_permission_lost_while_renaming_keeps_the_previous_set(sets, monkeypatch):
    # The folder stops accepting new entries after two files were renamed in (simulated: works as root too).
    folder, old, _ = sets
    real = os.replace
    installs = []

    def replace(src, dst):
        if ".tmp-" in os.fspath(src):
            installs.append(dst)
            if len(installs) >= 3:
                raise PermissionError(errno.EACCES, "Permission denied", os.fspath(dst))
        return real(src, dst)

    monkeypatch.setattr(imageio.os, "replace", replace)
    with pytest.raises(ImageWriteError, match="Permission denied"):
        write(folder, 2)
    assert_previous_set(folder, old)


def _read_only_folders_stop_writes(tmp_path) -> bool:
    """Whether a folder chmod'ed read-only refuses this process's writes: not as root (os.geteuid() == 0 with
    CAP_DAC_OVERRIDE), nor on Windows; probed rather than guessed from the user id."""
    probe = tmp_path / "probe"
    probe.mkdir()
    probe.chmod(0o555)
    try:
        (probe / "x").write_bytes(b"")
    except PermissionError:
        return True
    finally:
        probe.chmod(0o755)
    return False


def test_folder_made_read_only_after_the_temporaries_keeps_the_previous_set(sets, monkeypatch, tmp_path):
    if not _read_only_folders_stop_writes(tmp_path):
        pytest.skip("read-only folders do not stop this user's writes (root): chmod cannot simulate the fault")
    folder, old, new = sets
    real = output_sets._run_writers

    def then_read_only(jobs, temps):
        result = real(jobs, temps)
        folder.chmod(0o555)
        return result

    monkeypatch.setattr(output_sets, "_run_writers", then_read_only)
    try:
        with pytest.raises(ImageWriteError, match="Permission denied") as info:
            write(folder, 2)
    finally:
        folder.chmod(0o755)
    # Nothing could be renamed: the previous set is whole. The temporaries could not be removed in a read-only
    # folder; the error names them and the next write (or remove_stale_temporaries) clears them.
    assert "temporary" in str(info.value)
    now = snapshot(folder)
    assert {n: now[n] for n in old} == old
    remove_stale_temporaries(folder)
    assert_previous_set(folder, old)
    monkeypatch.undo()
    write(folder, 2)
    assert_set_of(folder, new)


HOST = _host_tag()


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_backups_of_a_writer_killed_while_renaming_are_moved_back(sets):
    # A writer killed (SIGKILL) in the middle of renaming: r.exr was replaced (its previous file kept as a hard-link
    # backup), r.png set aside (renamed: no hard links) with the new one not in yet, the rest still temporaries.
    folder, old, _ = sets
    pid = _dead_pid()
    os.link(folder / "r.exr", folder / f".r.bak-{HOST}-{pid}-abc123.exr")
    (folder / f".r.tmp-{HOST}-{pid}-0a0b0c.exr").write_bytes(b"the new colour image")
    os.replace(folder / f".r.tmp-{HOST}-{pid}-0a0b0c.exr", folder / "r.exr")
    (folder / "r.png").rename(folder / f".r.bak-{HOST}-{pid}-def456.png")
    (folder / f".r.tmp-{HOST}-{pid}-1a1b1c.png").write_bytes(b"the new preview")
    (folder / f".r.scattering.tmp-{HOST}-{pid}-2a2b2c.exr").write_bytes(b"the new scattering")
    cleaned = remove_stale_temporaries(folder)
    assert len(cleaned) == 4
    assert_previous_set(folder, old)


def test_backups_of_a_writer_killed_after_its_last_rename_are_removed(sets):
    # Killed after every new file was renamed in, before deleting the backups: the new set stays.
    folder, _, _ = sets
    pid = _dead_pid()
    for name in NAMES:
        stem, dot, ext = name.rpartition(".")
        os.link(folder / name, folder / f".{stem}.bak-{HOST}-{pid}-abc123.{ext}")
        (folder / name).unlink()
        (folder / name).write_bytes(b"new " + name.encode())
    assert len(remove_stale_temporaries(folder)) == len(NAMES)
    assert snapshot(folder) == {name: b"new " + name.encode() for name in NAMES}


def test_own_temporaries_of_a_write_in_progress_are_kept(tmp_path, monkeypatch):
    # remove_stale_temporaries run (by another thread's write) during a write of this process leaves its files.
    real = output_sets._run_writers
    seen = []

    def cleanup_in_between(jobs, temps):
        result = real(jobs, temps)
        seen.append(remove_stale_temporaries(tmp_path))
        return result

    monkeypatch.setattr(output_sets, "_run_writers", cleanup_in_between)
    write(tmp_path, 1)
    assert seen == [[]]
    assert sorted(snapshot(tmp_path)) == sorted(NAMES)


def test_temporaries_of_another_machine_are_left_alone(tmp_path):
    # a folder shared by several machines: a PID dead here may be a writer running there
    other = tmp_path / ".frame.0007.tmp-othermachine-4000000-a1b2c3.exr"
    other.write_bytes(b"another machine's frame in progress")
    mine = tmp_path / f".frame.0008.tmp-{HOST}-{_dead_pid()}-a1b2c3.exr"
    mine.write_bytes(b"a killed writer's temporary")
    assert remove_stale_temporaries(tmp_path) == [mine] and other.exists()
