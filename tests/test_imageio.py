"""Image files (warpscatter.io.images): EXR round trips, sRGB previews, row order, atomic all-or-nothing writes."""

import threading

import numpy as np
import OpenImageIO as oiio
import pytest

from warpscatter import __version__
from warpscatter.io import images as imageio
from warpscatter.io.images import (
    DEFAULT_EXR_COMPRESSION,
    EXR_COMPRESSIONS,
    ImageWriteError,
    read_image,
    srgb_decode,
    srgb_encode,
    write_exr,
    write_outputs,
    write_png,
)


def files_in(folder):
    return sorted(p.name for p in folder.iterdir()) if folder.exists() else []


# ---- sRGB ------------------------------------------------------------------------------------------


def test_srgb_reference_values():
    # IEC 61966-2-1: linear 0.5 -> 0.735357, 0.0031308 -> 0.04045 (the branch point), 0 -> 0, 1 -> 1.
    enc = srgb_encode(np.array([0.0, 0.0031308, 0.18, 0.5, 1.0]))
    np.testing.assert_allclose(enc, [0.0, 0.04045, 0.461356, 0.735357, 1.0], atol=2e-6)
    assert srgb_encode(np.array([-1.0, 7.0])).tolist() == [0.0, 1.0]  # clamped


def test_srgb_round_trip_and_monotone():
    x = np.linspace(0.0, 1.0, 10001, dtype=np.float32)
    enc = srgb_encode(x)
    assert np.all(np.diff(enc) >= 0)
    err = np.abs(srgb_decode(enc) - x).max()
    assert err < 1e-6  # measured 6.0e-8 (float32 output)


# ---- EXR -------------------------------------------------------------------------------------------


def test_exr_round_trip_is_exact(tmp_path, rng):
    rgb = (rng.random((5, 7, 3)) * 1e3 - 10).astype(np.float32)
    rgb[0, 0] = [1e-30, 3.4e38, -0.0]
    write_exr(tmp_path / "a.exr", rgb)
    back = read_image(tmp_path / "a.exr")
    assert back.dtype == np.float32 and back.shape == (5, 7, 3)
    assert np.array_equal(back, rgb)


def test_exr_gray_is_single_channel(tmp_path, rng):
    depth = rng.random((4, 6)).astype(np.float32) * 50
    write_exr(tmp_path / "d.exr", depth)
    back = read_image(tmp_path / "d.exr")
    assert back.shape == (4, 6, 1) and np.array_equal(back[:, :, 0], depth)
    assert oiio.ImageInput.open(str(tmp_path / "d.exr")).spec().nchannels == 1


def test_exr_converts_float64(tmp_path, rng):
    a = rng.random((3, 3, 3))
    write_exr(tmp_path / "f.exr", a)
    assert np.array_equal(read_image(tmp_path / "f.exr"), a.astype(np.float32))


# ---- PNG -------------------------------------------------------------------------------------------


def _exr_header(path):
    spec = oiio.ImageInput.open(str(path)).spec()
    return spec.get_string_attribute("compression"), spec.channelnames, spec.get_string_attribute("Software")


@pytest.mark.parametrize("compression", EXR_COMPRESSIONS)
def test_exr_compressions_are_lossless(tmp_path, rng, compression):
    rgb = (rng.standard_normal((37, 53, 3)) * 10.0 ** rng.integers(-30, 30, (37, 53, 3))).astype(np.float32)
    rgb[:8] = 0.25  # a constant block (compresses) next to noise (does not)
    rgb[0, 0] = [1e-45, 3.4e38, -0.0]  # denormal, near-max, negative zero
    depth = rng.random((37, 53)).astype(np.float32) * 100
    write_exr(tmp_path / "a.exr", rgb, compression=compression)
    write_exr(tmp_path / "d.exr", depth, compression=compression)
    back = read_image(tmp_path / "a.exr")
    assert back.view(np.uint32).tobytes() == rgb.view(np.uint32).tobytes()  # bit for bit, -0.0 included
    assert np.array_equal(read_image(tmp_path / "d.exr")[:, :, 0].view(np.uint32), depth.view(np.uint32))
    assert _exr_header(tmp_path / "a.exr") == (compression, ("R", "G", "B"), f"warpscatter {__version__}")
    assert _exr_header(tmp_path / "d.exr") == (compression, ("Y",), f"warpscatter {__version__}")


def test_exr_default_compression_and_bad_names(tmp_path):
    assert DEFAULT_EXR_COMPRESSION == "none" and DEFAULT_EXR_COMPRESSION in EXR_COMPRESSIONS
    write_exr(tmp_path / "a.exr", np.ones((2, 2, 3)))
    assert _exr_header(tmp_path / "a.exr")[0] == "none"
    for bad in ("dwaa", "b44", "pxr24", "ZIP", ""):  # lossy or unknown
        with pytest.raises(ValueError, match="compression: must be one of none, rle, zips, zip, piz"):
            write_exr(tmp_path / "b.exr", np.ones((2, 2, 3)), compression=bad)
    assert files_in(tmp_path) == ["a.exr"]


def test_png_table_encoding_matches_the_direct_formula():
    # _srgb8 (table look-up) must give exactly round(255 * srgb_encode(clamp(v, 0, 1))) for every float32: checked
    # here on every step of the code (the threshold and its neighbours) and on random and special values; checked
    # exhaustively (all 1,065,353,217 float32 values in [0, 1]) when it was written.
    tables = imageio._srgb8_tables()
    assert tables is not None
    steps = tables[1][tables[1] != 0xFFFFFFFF].astype(np.int64)
    assert len(steps) == 255  # codes 1 .. 255, one step each
    near = (steps[:, None] + np.arange(-3, 4)[None, :]).ravel().astype(np.uint32).view(np.float32)
    rng = np.random.default_rng(5)
    values = np.concatenate([
        near,
        rng.uniform(-0.1, 1.1, 200_000).astype(np.float32),
        (10.0 ** rng.uniform(-45, 0, 200_000)).astype(np.float32),
        np.array([0.0, -0.0, 1.0, np.nextafter(1, 2, dtype=np.float32), -1e-45, 1e-45, 3.4e38, np.inf, -np.inf],
                 np.float32),
    ])
    assert np.array_equal(imageio._srgb8(values), imageio._srgb8_reference(values))
    assert imageio._srgb8(values.reshape(-1, 1, 1)).shape == (len(values), 1, 1)


def test_png_with_alpha_keeps_alpha_linear(tmp_path, rng):
    rgba = rng.uniform(-0.2, 1.3, (4, 6, 4)).astype(np.float32)
    rgba[0, :, 3] = 1.0
    colour = np.rint(255 * np.clip(srgb_encode(rgba[:, :, :3] * np.float32(0.7)), 0, 1)).astype(np.uint8)
    alpha = np.rint(np.clip(rgba[:, :, 3], 0, 1) * 255).astype(np.uint8)
    assert np.array_equal(imageio._png_pixels(rgba, 0.7), np.dstack([colour, alpha]))  # what OpenImageIO gets
    write_png(tmp_path / "a.png", rgba, exposure=0.7)
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)  # the values as stored (OpenImageIO premultiplies otherwise)
    inp = oiio.ImageInput.open(str(tmp_path / "a.png"), config)
    raw = inp.read_image(format="uint8")
    assert inp.spec().channelnames == ("R", "G", "B", "A")
    assert inp.spec().get_string_attribute("Software") == f"warpscatter {__version__}"
    inp.close()
    assert np.array_equal(raw[:, :, 3], alpha)
    # OpenImageIO takes colour as premultiplied and divides it by alpha when it writes a PNG: where alpha is 1
    # the stored colour is the preview's
    assert np.array_equal(raw[0, :, :3], colour[0])


def test_png_row_zero_is_top(tmp_path):
    img = np.zeros((4, 6, 3), np.float32)
    img[0, :, 0] = 1.0  # top row red
    img[3, :, 2] = 1.0  # bottom row blue
    write_png(tmp_path / "p.png", img)
    back = read_image(tmp_path / "p.png")
    assert back.shape == (4, 6, 3)
    assert np.array_equal(back[0], np.tile([1.0, 0.0, 0.0], (6, 1)))
    assert np.array_equal(back[3], np.tile([0.0, 0.0, 1.0], (6, 1)))
    # the file itself, read with OpenImageIO directly: first scanline red
    raw = oiio.ImageBuf(str(tmp_path / "p.png")).get_pixels(oiio.UINT8)
    assert raw[0, 0].tolist() == [255, 0, 0] and raw[3, 0].tolist() == [0, 0, 255]


def test_png_is_srgb_encoded_with_exposure(tmp_path):
    img = np.full((2, 2, 3), 0.25, np.float32)
    write_png(tmp_path / "e.png", img, exposure=2.0)
    raw = oiio.ImageBuf(str(tmp_path / "e.png")).get_pixels(oiio.UINT8)
    assert np.all(raw == 188)  # round(255 * srgb_encode(0.5)) = round(187.52)
    write_png(tmp_path / "c.png", np.full((2, 2, 3), 3.0, np.float32))
    assert np.all(oiio.ImageBuf(str(tmp_path / "c.png")).get_pixels(oiio.UINT8) == 255)  # clamped


def test_png_read_decodes_to_linear(tmp_path, rng):
    lin = rng.random((8, 8, 3)).astype(np.float32)
    write_png(tmp_path / "r.png", lin)
    err = np.abs(read_image(tmp_path / "r.png") - lin).max()
    # half an 8-bit step (1/510) times the largest slope of srgb_decode (2.4 / 1.055 = 2.275 at 1): 0.00446
    assert err < 0.00446  # measured 0.00427


def test_write_png_rejects_bad_exposure(tmp_path):
    with pytest.raises(ValueError, match="exposure"):
        write_png(tmp_path / "x.png", np.zeros((2, 2, 3)), exposure=0)
    assert files_in(tmp_path) == []


# ---- failures --------------------------------------------------------------------------------------


def test_non_finite_values_rejected(tmp_path):
    img = np.zeros((3, 4, 3), np.float32)
    img[1, 2, 0] = np.nan
    with pytest.raises(ValueError, match=r"1 non-finite value\(s\).*row 1, column 2"):
        write_exr(tmp_path / "n.exr", img)
    img[1, 2, 0] = np.inf
    with pytest.raises(ValueError, match="non-finite"):
        write_png(tmp_path / "n.png", img)
    with pytest.raises(ValueError, match="non-finite"):
        write_exr(tmp_path / "big.exr", np.full((2, 2), 1e300))  # overflows float32
    assert files_in(tmp_path) == []


def test_bad_shapes_rejected(tmp_path):
    for bad in (np.zeros((4,)), np.zeros((2, 2, 5)), np.zeros((0, 3, 3))):
        with pytest.raises(ValueError, match="expected an"):
            write_exr(tmp_path / "s.exr", bad)


def test_missing_folder_fails_cleanly(tmp_path):
    target = tmp_path / "no" / "such" / "a.exr"
    with pytest.raises(ImageWriteError, match=f"cannot write {target}"):
        write_exr(target, np.zeros((2, 2, 3)))
    assert not (tmp_path / "no").exists()


def test_folder_that_is_a_file_fails_cleanly(tmp_path):
    (tmp_path / "blocker").write_text("x")
    with pytest.raises(ImageWriteError, match="blocker"):
        write_outputs(tmp_path / "blocker" / "out", "r", {"color": np.zeros((2, 2, 3))})
    assert files_in(tmp_path) == ["blocker"]


def test_unknown_format_fails_cleanly(tmp_path):
    with pytest.raises(ImageWriteError, match="cannot write"):
        write_exr(tmp_path / "a.notaformat", np.zeros((2, 2, 3)))
    assert files_in(tmp_path) == []


def test_failure_mid_write_leaves_no_temp_file(tmp_path, monkeypatch):
    real = imageio._write_oiio

    def half_then_fail(path, pixels, *args, **kwargs):
        real(path, pixels, *args, **kwargs)  # the temporary file exists now ...
        assert path.exists() and path.name.startswith(".a.tmp-") and path.suffix == ".exr"
        raise ImageWriteError("disk full")  # ... and the write fails afterwards

    monkeypatch.setattr(imageio, "_write_oiio", half_then_fail)
    with pytest.raises(ImageWriteError, match=f"cannot write {tmp_path / 'a.exr'}: disk full"):
        write_exr(tmp_path / "a.exr", np.zeros((2, 2, 3)))
    assert files_in(tmp_path) == []


def test_overwrite_replaces_existing_file(tmp_path):
    write_exr(tmp_path / "a.exr", np.zeros((2, 2, 3)))
    write_exr(tmp_path / "a.exr", np.ones((3, 1, 3)))
    assert read_image(tmp_path / "a.exr").shape == (3, 1, 3)
    assert files_in(tmp_path) == ["a.exr"]


def test_read_missing_file(tmp_path):
    with pytest.raises(OSError, match="cannot read"):
        read_image(tmp_path / "none.exr")


# ---- the output set --------------------------------------------------------------------------------


def render_images(rng, h=3, w=5):
    return {
        "color": rng.random((h, w, 3)).astype(np.float32),
        "scattering": rng.random((h, w, 3)).astype(np.float32),
        "surface": rng.random((h, w, 3)).astype(np.float32),
        "depth": rng.random((h, w)).astype(np.float32) * 10,
    }


def test_write_outputs_contract(tmp_path, rng):
    images = render_images(rng)
    out = tmp_path / "nested" / "out"
    files = write_outputs(out, "gate", images, ["color", "scattering", "surface", "depth"], exposure=1.5)
    names = ["gate.exr", "gate.png", "gate.scattering.exr", "gate.surface.exr", "gate.depth.exr"]
    assert files == [out / n for n in names]
    assert files_in(out) == sorted(names)
    assert np.array_equal(read_image(out / "gate.exr"), images["color"])
    assert np.array_equal(read_image(out / "gate.scattering.exr"), images["scattering"])
    assert np.array_equal(read_image(out / "gate.surface.exr"), images["surface"])
    depth = read_image(out / "gate.depth.exr")
    assert depth.shape == (3, 5, 1) and np.array_equal(depth[:, :, 0], images["depth"])
    raw = oiio.ImageBuf(str(out / "gate.png")).get_pixels(oiio.UINT8)
    expect = np.rint(255 * srgb_encode(images["color"] * 1.5)).astype(np.uint8)
    assert np.array_equal(raw, expect)


@pytest.mark.parametrize("compression", ["zips", "rle"])
def test_write_outputs_compression(tmp_path, rng, compression):
    images = render_images(rng)
    files = write_outputs(tmp_path, "r", images, ["scattering", "surface", "depth"], compression=compression)
    for f in files:
        if f.suffix == ".exr":
            aov = f.name.split(".")[1] if f.name.count(".") == 2 else "color"
            assert _exr_header(f)[0] == compression
            assert np.array_equal(read_image(f).reshape(images[aov].shape), images[aov])
    with pytest.raises(ValueError, match="compression: must be one of"):
        write_outputs(tmp_path / "o", "r", images, compression="dwaa")
    assert not (tmp_path / "o").exists()


def test_write_outputs_only_requested_aovs(tmp_path, rng):
    files = write_outputs(tmp_path, "r", render_images(rng), ["depth"])
    assert [f.name for f in files] == ["r.exr", "r.png", "r.depth.exr"]
    assert files_in(tmp_path) == ["r.depth.exr", "r.exr", "r.png"]


def test_write_outputs_all_or_nothing(tmp_path, rng, monkeypatch):
    # The fourth file (in output order) fails; the others are written (concurrently) and then removed too.
    real = imageio._write_oiio
    calls = []

    def fail_on_fourth(path, *args, **kwargs):
        calls.append(path.name)
        if path.name.startswith(".r.surface.tmp-"):
            raise ImageWriteError("no space left on device")
        real(path, *args, **kwargs)
        assert path.exists()  # the temporary file is there before the failure is handled

    monkeypatch.setattr(imageio, "_write_oiio", fail_on_fourth)
    with pytest.raises(ImageWriteError, match="r.surface.exr: no space left"):
        write_outputs(tmp_path, "r", render_images(rng), ["scattering", "surface", "depth"])
    assert sorted(n.split(".tmp-")[0] for n in calls) == [".r", ".r", ".r.depth", ".r.scattering", ".r.surface"]
    assert files_in(tmp_path) == []  # neither finished outputs nor temporaries


def test_write_outputs_reports_the_first_failure_in_output_order(tmp_path, rng, monkeypatch):
    real = imageio._write_oiio
    started = threading.Event()

    def png_and_depth_fail(path, *args, **kwargs):
        if path.suffix == ".png":
            assert started.wait(10)  # the depth file fails first in time ...
            raise ImageWriteError("png encoder broke")
        if path.name.startswith(".r.depth."):
            started.set()
            raise ImageWriteError("depth disk full")
        real(path, *args, **kwargs)

    monkeypatch.setattr(imageio, "_write_oiio", png_and_depth_fail)
    with pytest.raises(ImageWriteError, match="r.png: png encoder broke"):  # ... the png comes first in order
        write_outputs(tmp_path, "r", render_images(rng), ["depth"])
    assert files_in(tmp_path) == []


def test_write_outputs_writes_the_files_concurrently(tmp_path, rng, monkeypatch):
    # Every writer waits until all five run at the same time: sequential writing would break the barrier.
    real = imageio._write_oiio
    barrier = threading.Barrier(5, timeout=30)

    def meet_then_write(path, *args, **kwargs):
        barrier.wait()
        real(path, *args, **kwargs)

    monkeypatch.setattr(imageio, "_write_oiio", meet_then_write)
    files = write_outputs(tmp_path, "r", render_images(rng), ["scattering", "surface", "depth"])
    assert len(files) == 5 and files_in(tmp_path) == sorted(f.name for f in files)


def test_write_outputs_interrupted_writer_leaves_nothing(tmp_path, rng, monkeypatch):
    real = imageio._write_oiio

    def interrupted(path, *args, **kwargs):
        real(path, *args, **kwargs)
        if path.name.startswith(".r.scattering."):
            raise KeyboardInterrupt

    monkeypatch.setattr(imageio, "_write_oiio", interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_outputs(tmp_path, "r", render_images(rng), ["scattering", "surface", "depth"])
    assert files_in(tmp_path) == []


def test_write_outputs_rename_failure_removes_renamed(tmp_path, rng, monkeypatch):
    real_replace = imageio.os.replace
    count = []

    def replace_fails_second(src, dst):
        count.append(dst)
        if len(count) == 2:
            raise OSError("rename failed")
        real_replace(src, dst)

    monkeypatch.setattr(imageio.os, "replace", replace_fails_second)
    with pytest.raises(ImageWriteError, match="r.png: rename failed"):
        write_outputs(tmp_path, "r", render_images(rng), ["depth"])
    assert files_in(tmp_path) == []


def test_write_outputs_rejects_nan_before_writing(tmp_path, rng):
    images = render_images(rng)
    images["depth"][2, 4] = np.nan
    with pytest.raises(ValueError, match=r"depth: 1 non-finite value\(s\).*row 2, column 4"):
        write_outputs(tmp_path / "o", "r", images, ["depth"])
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    ("change", "aovs", "message"),
    [
        (lambda im: im.pop("depth"), ["depth"], "no image given for requested aov"),
        (lambda im: im.update(depth=np.zeros((2, 5))), ["depth"], "sizes differ"),
        (lambda im: im.update(depth=np.zeros((3, 5, 3))), ["depth"], "depth: expected an"),
        (lambda im: im.update(color=np.zeros((3, 5))), [], "color: expected an"),
        (lambda im: None, ["normals"], "unknown"),
    ],
)
def test_write_outputs_argument_errors(tmp_path, rng, change, aovs, message):
    images = render_images(rng)
    change(images)
    with pytest.raises(ValueError, match=message):
        write_outputs(tmp_path, "r", images, aovs)
    assert files_in(tmp_path) == []


def test_write_outputs_bad_name(tmp_path, rng):
    with pytest.raises(ValueError, match="name"):
        write_outputs(tmp_path, "../r", render_images(rng))
