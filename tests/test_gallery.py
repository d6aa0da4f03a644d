"""The gallery (``warpscatter gallery``): every bundled config renders, every image is written and listed with what
made it, the docs' gallery page names only images that exist and that the gallery writes."""

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from warpscatter.api import load_config
from warpscatter.cli.gallery import gallery
from warpscatter.runs.gallery import (
    COMPARED,
    REFERENCE_NAME,
    SHOWCASES,
    Entry,
    GalleryResult,
    Sizes,
    bundled_configs,
    downscale,
    images_named,
    write_manifest,
)

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
IMAGES = DOCS / "images"

#: A bench JSON of two suites' worth of rows, as `warpscatter bench` writes them (a few fields of each row).
BENCH = {
    "format": "warpscatter-bench/2", "suite": "moments",
    "meta": {"cpu": "test cpu", "threads": 2, "repeats": 1, "quick": True, "timestamp": "2026-01-01T00:00:00Z"},
    "rows": [{"name": f"colonnade: {m}", "params": {"scene": "colonnade"}, "median_ms": t, "rel_l1": e}
             for m, t, e in (("raymarch shadow_map 128", 40.0, 0.02), ("fourier", 25.0, 0.04),
                             ("moments6", 20.0, 0.05))],
}


@pytest.fixture(scope="module")
def quick_gallery(tmp_path_factory):
    """One ``--quick`` gallery with bench charts (the CLI command in-process): (exit code, output, folder)."""
    base = tmp_path_factory.mktemp("gallery")
    bench = base / "bench-out"
    bench.mkdir()
    (bench / "bench-moments.json").write_text(json.dumps(BENCH))
    out = base / "images"
    result = CliRunner().invoke(gallery, ["-o", str(out), "--quick", "--bench-dir", str(bench)])
    return result.exit_code, result.output, out


def _manifest(out: Path) -> dict:
    return json.loads((out / "gallery.json").read_text())


def test_every_bundled_config_renders(quick_gallery):
    code, output, out = quick_gallery
    assert code == 0, output
    manifest = _manifest(out)
    assert manifest["failures"] == {}
    listed = {e["path"]: e for e in manifest["images"]}
    for config in bundled_configs():
        entry = listed[f"configs/{config.stem}.png"]
        assert (out / entry["path"]).is_file()
        assert entry["method"] == load_config(config).method  # each config with its own method, read at run time
        assert entry["config"] == config.stem and entry["version"] and entry["size"][0] <= 48
    assert listed["quickstart.png"]["section"] == "hero"


def test_every_image_is_written_and_listed(quick_gallery):
    code, output, out = quick_gallery
    assert code == 0, output
    manifest = _manifest(out)
    listed = {e["path"] for e in manifest["images"]}
    written = {p.relative_to(out).as_posix() for p in out.rglob("*.png")}
    assert written == listed  # every image listed, nothing listed that is not there
    expected = {"quickstart.png", "compare_quickstart.png", "bench/bench-moments.png",
                "bench/bench-moments-error-time.png", f"methods/{REFERENCE_NAME}.png"}
    expected |= {f"methods/{m}.png" for m in COMPARED} | {f"methods/{m}.png" for _, m in SHOWCASES}
    assert expected <= listed
    assert not [p for p in out.rglob(".*") if p.is_file()]  # no temporaries left behind
    for e in manifest["images"]:
        assert set(e) >= {"config", "method", "overrides", "size", "seconds", "rel_l1", "version", "commit"}
        assert e["bytes"] == (out / e["path"]).stat().st_size
    errors = [e["rel_l1"] for e in manifest["images"] if e["section"] == "methods" and e["path"].split("/")[1]
              .removesuffix(".png") in COMPARED]
    assert len(errors) == len(COMPARED) and all(0.0 <= x < 1.0 for x in errors)


def test_a_later_run_keeps_the_bench_charts_and_drops_removed_images(quick_gallery, tmp_path):
    code, output, out = quick_gallery
    assert code == 0, output
    # an earlier run's manifest: its bench charts, and the picture of a config since removed
    folder = tmp_path / "images"
    (folder / "bench").mkdir(parents=True)
    (folder / "configs").mkdir()
    for p in (out / "bench").iterdir():
        (folder / "bench" / p.name).write_bytes(p.read_bytes())
    (folder / "configs" / "removed.png").write_bytes(b"png")
    old = [e for e in _manifest(out)["images"] if e["section"] == "bench"]
    old.append({"path": "configs/removed.png", "section": "configs"})
    (folder / "gallery.json").write_text(json.dumps({"images": old}))
    # a run that renders the configs again, without --bench-dir
    (folder / "configs" / "kept.png").write_bytes(b"png")
    write_manifest(GalleryResult(out_dir=folder, entries=[Entry(path="configs/kept.png", section="configs")]),
                   Sizes())
    paths = {e["path"] for e in _manifest(folder)["images"]}
    assert paths == {"configs/kept.png", "bench/bench-moments.png", "bench/bench-moments-error-time.png"}
    assert not (folder / "configs" / "removed.png").exists()


@pytest.mark.parametrize("args, message", [
    (["--bench-dir", "missing-folder"], "not a folder"),
    (["--bench-dir", "."], "no bench-*.json"),
])
def test_bad_input_exits_2(tmp_path, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(gallery, ["--quick", "-o", str(tmp_path / "out"), *args])
    assert result.exit_code == 2 and message in result.output
    assert not (tmp_path / "out").exists()  # nothing rendered


def test_output_that_is_a_file_exits_2(tmp_path):
    (tmp_path / "file").write_text("x")
    result = CliRunner().invoke(gallery, ["--quick", "-o", str(tmp_path / "file")])
    assert result.exit_code == 2 and "not a directory" in result.output


def test_a_bench_json_that_is_not_one_exits_2(tmp_path):
    (tmp_path / "bench-x.json").write_text("{}")
    result = CliRunner().invoke(gallery, ["--quick", "-o", str(tmp_path / "out"), "--bench-dir", str(tmp_path)])
    assert result.exit_code == 2 and "not a warpscatter bench JSON" in result.output


def test_downscale_is_an_area_average():
    rng = np.random.default_rng(42)
    image = rng.random((36, 64, 3)).astype(np.float32)
    small = downscale(image, 16)  # 4x4 blocks
    assert small.shape == (9, 16, 3)
    np.testing.assert_allclose(small, image.reshape(9, 4, 16, 4, 3).mean(axis=(1, 3)), rtol=1e-6)
    odd = downscale(image, 20)  # fractional footprints keep the mean
    assert odd.shape == (11, 20, 3) and abs(odd.mean() - image.mean()) < 2e-3
    assert downscale(image, 64) is image and downscale(image, 100) is image  # never up


def test_the_gallery_page_names_only_images_the_gallery_writes(quick_gallery):
    code, output, out = quick_gallery
    assert code == 0, output
    page = (DOCS / "gallery.md").read_text()
    named = images_named(page)
    assert named, "docs/gallery.md shows no image"
    written = {p.relative_to(out).as_posix() for p in out.rglob("*.png")}
    for name in named:
        assert name.startswith("images/"), name
        rel = name.removeprefix("images/")
        assert (IMAGES / rel).is_file(), f"docs/gallery.md names {name}, which is not in docs/images"
        if rel.startswith("bench/"):  # charts of a real bench run (the quick run charts a small stand-in suite)
            assert any(w.startswith("bench/") for w in written), "the gallery wrote no bench chart"
            continue
        assert rel in written, f"docs/gallery.md names {name}, which warpscatter gallery does not write"
    assert "warpscatter gallery -o docs/images" in page


def test_the_checked_in_gallery_is_listed():
    manifest = IMAGES / "gallery.json"
    if not manifest.is_file():
        pytest.skip("no gallery checked in")
    images = json.loads(manifest.read_text())["images"]
    assert images
    for e in images:
        assert (IMAGES / e["path"]).is_file(), f"docs/images/gallery.json lists {e['path']}, which is missing"
        assert e["version"] and e["size"]
    assert sum((IMAGES / e["path"]).stat().st_size for e in images) < 8 * 2**20  # a few MB in all
