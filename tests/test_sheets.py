"""Contact sheets and the HTML gallery, on a fake sweep folder of small synthetic renders."""

import hashlib
import json
import re
import shutil
import subprocess
from pathlib import Path
from urllib.parse import unquote

import numpy as np
import pytest
import yaml

from icefarm import params as P, sheets as S
from icefarm.errors import InputError

oiio = pytest.importorskip("OpenImageIO")

CURVE = (5.0, 0.0, 2.0)  # deliberately unsorted: the sheet sorts rows by value
DIVISION = (0.3, 0.0, 0.1)
FAILED = (2.0, 0.1)  # the middle cell
CELL_W = 96  # renders are 64 x 48, so cells are 96 x 72 and upsampled by fit


def job_id(*parts) -> str:
    return hashlib.sha1(repr(parts).encode()).hexdigest()[:10]


def write_render(job_dir: Path, colour, width: int = 64, height: int = 48) -> None:
    """A linear EXR (half) with a gradient in ``colour``, and its sRGB PNG."""
    x = np.linspace(0.2, 1.0, width)[None, :, None]
    y = np.linspace(1.0, 0.5, height)[:, None, None]
    rgb = (np.asarray(colour, dtype=np.float32)[None, None, :] * x * y).astype(np.float32)
    buf = oiio.ImageBuf(oiio.ImageSpec(width, height, 3, "half"))
    buf.set_pixels(oiio.ROI(0, width, 0, height, 0, 1, 0, 3), rgb)
    assert buf.write(str(job_dir / "render.exr"))
    png = oiio.ImageBufAlgo.colorconvert(buf, "lin_rec709", "sRGB")
    png.set_write_format("uint8")
    assert png.write(str(job_dir / "render.png"))


def make_job(root: Path, obj: str, values: dict, colour=None, state="done", size=(64, 48)) -> Path:
    path = root / "jobs" / obj / job_id(obj, sorted(values.items()))
    path.mkdir(parents=True)
    (path / "params.yaml").write_text(yaml.safe_dump(P.resolve({"surface.mode": "tubes"}, values).as_dict()))
    if state == "failed":
        (path / "error.json").write_text(json.dumps({
            "stage": "surface", "message": "ValueError: no icicle survived the collision test",
            "traceback": "Traceback (most recent call last):\n  ...", "seconds": {"prepare": 0.1, "water": 0.2}}))
        return path
    if state == "unfinished":
        return path
    write_render(path, colour, *size)
    (path / "scene.xml").write_text('<scene version="3.0.0"/>\n')
    (path / "ice.ply").write_text("ply\nformat ascii 1.0\nelement vertex 0\nend_header\n")
    (path / "timings.json").write_text(json.dumps({
        "seconds": {"prepare": 0.05, "water": 0.2, "surface": 1.5, "render": 0.6},
        "ice_faces": 1234, "icicles": 7, "reused": ["water"]}))
    (path / "done.json").write_text("{}")
    return path


@pytest.fixture
def run_dir(tmp_path: Path) -> Path:
    """A 3 x 3 sweep of two trajectory parameters on "cube" (the middle job failed) and a
    one-parameter sweep on "bowl" (one job unfinished, one render of another aspect)."""
    root = tmp_path / "lookdev"
    root.mkdir()
    (root / "manifest.resolved.yaml").write_text(yaml.safe_dump({"name": "lookdev", "sweep": {"method": "grid"}}))
    for i, c in enumerate(CURVE):
        for j, d in enumerate(DIVISION):
            colour = (0.1 + 0.4 * i, 0.1 + 0.4 * j, 0.9 - 0.1 * (i + j))
            make_job(root, "cube", {"trajectories.curve_angle": c, "trajectories.division_probability": d},
                     colour, state="failed" if (c, d) == FAILED else "done")
    make_job(root, "bowl", {"drips.count": 16}, (0.8, 0.2, 0.1), size=(64, 32))
    make_job(root, "bowl", {"drips.count": 4}, (0.1, 0.8, 0.2))
    make_job(root, "bowl", {"drips.count": 8}, state="unfinished")
    return root


def linear_to_srgb(v: np.ndarray) -> np.ndarray:
    v = np.clip(v, 0.0, 1.0)
    return np.where(v <= 0.0031308, v * 12.92, 1.055 * v ** (1 / 2.4) - 0.055)


def pixels(path: Path) -> np.ndarray:
    buf = oiio.ImageBuf(str(path))
    return np.asarray(buf.get_pixels(oiio.FLOAT))


def fitted(exr: Path, width: int, height: int) -> np.ndarray:
    """The reference: ImageBufAlgo.fit of the job's EXR into the cell, letterboxed."""
    roi = oiio.ROI(0, width, 0, height, 0, 1, 0, 3)
    buf = oiio.ImageBufAlgo.fit(oiio.ImageBuf(str(exr)), filtername=S.FIT_FILTER, fillmode="letterbox", roi=roi)
    return np.asarray(buf.get_pixels(oiio.FLOAT, roi=buf.roi_full))


def cube_job(run_dir: Path, c: float, d: float) -> Path:
    values = {"trajectories.curve_angle": c, "trajectories.division_probability": d}
    return run_dir / "jobs" / "cube" / job_id("cube", sorted(values.items()))


def test_grid_sheet_size_and_cells_match_the_fitted_renders(run_dir):
    results = {r.object_id: r for r in S.build_sheets(run_dir, cell_width=CELL_W)}
    cube = results["cube"]
    assert (cube.rows, cube.cols, cube.cells, cube.failed) == (3, 3, 9, 1)
    assert cube.exr == run_dir / "sheets" / "cube.exr" and cube.png == run_dir / "sheets" / "cube.png"

    cw, ch = CELL_W, CELL_W * 48 // 64
    width = max(S.MIN_WIDTH, 2 * S.MARGIN + S.ROW_HEAD_W + 3 * cw + 2 * S.GAP)
    height = 2 * S.MARGIN + S.HEADER_H + S.COL_HEAD_H + 3 * (ch + S.LABEL_H) + 2 * S.GAP
    sheet = pixels(cube.exr)
    assert sheet.shape == (height, width, 3)
    assert oiio.ImageBuf(str(cube.exr)).spec().format == oiio.TypeDesc("half")

    failed_lin = np.array(S.srgb_to_linear(S.FAILED_SRGB))
    for r, c in enumerate(sorted(CURVE)):  # rows: curve_angle, sorted; columns: division_probability
        for k, d in enumerate(sorted(DIVISION)):
            x = S.MARGIN + S.ROW_HEAD_W + k * (cw + S.GAP)
            y = S.MARGIN + S.HEADER_H + S.COL_HEAD_H + r * (ch + S.LABEL_H + S.GAP)
            block = sheet[y:y + ch, x:x + cw]
            if (c, d) == FAILED:
                # placeholder: the failure colour at the corners, text in the middle, no render
                for py, px in ((1, 1), (1, cw - 2), (ch - 2, 1), (ch - 2, cw - 2)):
                    np.testing.assert_allclose(block[py, px], failed_lin, atol=2e-3)
                assert np.abs(block - failed_lin).max() > 0.3  # the text is drawn on it
                assert not (cube_job(run_dir, c, d) / "render.exr").exists()
                continue
            expected = fitted(cube_job(run_dir, c, d) / "render.exr", cw, ch)
            np.testing.assert_allclose(block, expected, atol=2e-3, rtol=2e-3)
            # the label strip below the cell holds text, not the render
            assert sheet[y + ch:y + ch + S.LABEL_H, x:x + cw].max() > 0.5


def test_png_is_the_sheet_after_one_display_transform(run_dir):
    cube = {r.object_id: r for r in S.build_sheets(run_dir, cell_width=CELL_W)}["cube"]
    lin, png = pixels(cube.exr), pixels(cube.png)
    assert png.shape == lin.shape
    assert oiio.ImageBuf(str(cube.png)).spec().format == oiio.TypeDesc("uint8")
    # sRGB once: not twice, not never (1/255 for rounding, plus half-float precision)
    assert np.abs(png - linear_to_srgb(lin)).max() <= 1.5 / 255
    # colours come out as the display values they were chosen for
    np.testing.assert_allclose(png[0, 0], S.BACKGROUND_SRGB, atol=1.5 / 255)
    header = png[S.MARGIN:S.MARGIN + 30, S.MARGIN:S.MARGIN + 300]
    assert abs(header.max() - S.TEXT_SRGB[0]) <= 1.5 / 255  # fully covered glyph pixels
    x = S.MARGIN + S.ROW_HEAD_W + 1 * (CELL_W + S.GAP)
    y = S.MARGIN + S.HEADER_H + S.COL_HEAD_H + 1 * (72 + S.LABEL_H + S.GAP)
    np.testing.assert_allclose(png[y + 1, x + 1], S.FAILED_SRGB, atol=1.5 / 255)


def test_one_parameter_row_with_unfinished_job_and_letterbox(run_dir):
    bowl = {r.object_id: r for r in S.build_sheets(run_dir, cell_width=CELL_W)}["bowl"]
    assert (bowl.rows, bowl.cols, bowl.cells, bowl.failed) == (1, 3, 3, 0)
    sheet = pixels(bowl.exr)
    ch = 72  # the first render in job order (count=4) is 4:3
    width = max(S.MIN_WIDTH, 2 * S.MARGIN + 3 * CELL_W + 2 * S.GAP)
    assert sheet.shape == (2 * S.MARGIN + S.HEADER_H + ch + S.LABEL_H, width, 3)
    jobs = {v: run_dir / "jobs" / "bowl" / job_id("bowl", [("drips.count", v)]) for v in (4, 8, 16)}
    for k, count in enumerate((4, 8, 16)):  # sorted by value
        x, y = S.MARGIN + k * (CELL_W + S.GAP), S.MARGIN + S.HEADER_H
        block = sheet[y:y + ch, x:x + CELL_W]
        if count == 8:  # unfinished: no done.json, no render
            np.testing.assert_allclose(block[1, 1], S.srgb_to_linear(S.UNFINISHED_SRGB), atol=2e-3)
            continue
        expected = fitted(jobs[count] / "render.exr", CELL_W, ch)
        np.testing.assert_allclose(block, expected, atol=2e-3, rtol=2e-3)
    # the 2:1 render (count=16) is letterboxed: black bars above and below, no stretching
    x = S.MARGIN + 2 * (CELL_W + S.GAP)
    assert sheet[S.MARGIN + S.HEADER_H + 2, x + CELL_W // 2].max() == 0
    assert sheet[S.MARGIN + S.HEADER_H + ch // 2, x + CELL_W // 2].max() > 0.1


def test_varying_keys_fixed_changes_and_jobs_csv_order(run_dir):
    info = S.scan_run(run_dir)
    assert info.name == "lookdev" and info.method == "grid"
    cube = info.objects["cube"]
    vary = S.varying_keys(cube)
    assert vary == ["trajectories.curve_angle", "trajectories.division_probability"]
    assert S.fixed_changes(cube, vary) == {"surface.mode": "tubes"}
    # without jobs.csv: sorted by the varying values
    assert [j.values["trajectories.curve_angle"] for j in cube] == sorted(np.repeat(CURVE, 3))
    # jobs.csv fixes the order of the jobs it lists and the order of the swept keys
    ids = [job_id("bowl", [("drips.count", v)]) for v in (8, 16, 4)]
    (run_dir / "jobs.csv").write_text(
        "job_id,object,drips.count,status\n"
        + "".join(f"{i},bowl,{v},done\n" for i, v in zip(ids, (8, 16, 4)))
        + "missing0000,bowl,32,pending\n")
    bowl = S.scan_run(run_dir).objects["bowl"]
    assert [j.job_id for j in bowl] == ids + ["missing0000"]
    assert bowl[-1].state is S.JobState.PENDING and bowl[-1].path is None
    assert bowl[-1].values == {"drips.count": 32}
    grid = S.plan_grid(bowl, S.varying_keys(bowl))
    assert (grid.arrangement, grid.rows, grid.cols) == (S.Arrangement.ROW, 1, 4)


def test_plan_grid_arrangements():
    def job(i, **values):
        return S.JobInfo("o", f"j{i}", None, S.JobState.DONE, values, True)

    cross = [job(i, a=a, b=b) for i, (a, b) in enumerate([(1, 1), (1, 2), (2, 1), (2, 2), (3, 1)])]
    grid = S.plan_grid(cross, ["a", "b"])
    assert (grid.arrangement, grid.rows, grid.cols) == (S.Arrangement.ROWS_COLUMNS, 3, 2)
    zipped = [job(i, a=i, b=10 * i) for i in range(5)]  # a zip sweep: no cross product
    assert S.plan_grid(zipped, ["a", "b"]).arrangement is S.Arrangement.JOB_ORDER
    assert S.plan_grid(cross, ["a", "b"], method="random").arrangement is S.Arrangement.JOB_ORDER
    long_row = [job(i, a=i) for i in range(12)]
    grid = S.plan_grid(long_row, ["a"])
    assert (grid.arrangement, grid.rows, grid.cols) == (S.Arrangement.ROW, 3, 4)
    three = [job(i, a=i, b=i % 2, c=i % 3) for i in range(7)]
    grid = S.plan_grid(three, ["a", "b", "c"])
    assert (grid.arrangement, grid.rows, grid.cols) == (S.Arrangement.JOB_ORDER, 3, 3)
    assert [(r, c) for r, c, _ in grid.slots][:4] == [(0, 0), (0, 1), (0, 2), (1, 0)]


def gallery_links(page: Path) -> list[str]:
    text = page.read_text()
    return [unquote(u) for u in re.findall(r'(?:href|src)="([^"#]+)"', text)]


def test_gallery_references_every_job_with_relative_links(run_dir):
    S.build_sheets(run_dir, cell_width=CELL_W)
    page = run_dir / "sheets" / "index.html"
    text = page.read_text()
    links = gallery_links(page)
    assert links and not [u for u in links if re.match(r"[a-z]+:|/", u)]  # relative only
    missing = [u for u in links if not (page.parent / u).exists()]
    assert not missing
    resolved = {(page.parent / u).resolve() for u in links}
    for job in (run_dir / "jobs").glob("*/*"):
        assert f'id="{job.parent.name}-{job.name}"' in text
        if (job / "done.json").exists():
            for name in ("render.png", "scene.xml", "ice.ply"):
                assert (job / name).resolve() in resolved, (job, name)
    for name in ("cube.png", "cube.exr", "bowl.png", "bowl.exr"):
        assert (run_dir / "sheets" / name).resolve() in resolved
    assert "failed at stage <b>surface</b>" in text
    assert "no icicle survived the collision test" in text
    assert "<details>" in text and "curve_angle" in text


@pytest.mark.slow
def test_gallery_loads_in_headless_chromium_without_missing_images(run_dir, tmp_path):
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.skip("chromium is not installed (apt-get install chromium)")
    S.build_sheets(run_dir, cell_width=CELL_W)
    page = run_dir / "sheets" / "index.html"
    cmd = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           f"--user-data-dir={tmp_path / 'chromium-profile'}", "--virtual-time-budget=5000",
           "--dump-dom", page.as_uri()]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    body = re.search(r"<body[^>]*>", done.stdout)
    assert body, f"no DOM from chromium (rc {done.returncode}): {done.stderr[-2000:]}"
    attrs = dict(re.findall(r'data-([a-z-]+)="([^"]*)"', body.group(0)))
    # 2 sheets + the renders of the 9 - 1 + 2 finished jobs
    assert attrs.get("images") == "12", attrs
    assert attrs.get("missing-images") == "0", attrs


def test_refuses_a_folder_without_jobs(tmp_path):
    with pytest.raises(InputError, match="no jobs/"):
        S.build_sheets(tmp_path)
    (tmp_path / "jobs").mkdir()
    with pytest.raises(InputError, match="cell width"):
        S.build_sheets(tmp_path, cell_width=0)
    assert S.build_sheets(tmp_path) == []
    assert (tmp_path / "sheets" / "index.html").is_file()


def test_cells_show_the_ice_view_where_the_icicles_would_be_too_thin(tmp_path):
    """A cell shows render_view<i> (frame: ice) when the main view's icicles would be under
    4 px wide at the cell's size; otherwise, or without such a view, the main render."""
    root = tmp_path / "ice"
    (root / "jobs").mkdir(parents=True)
    cases = {0.1: 2.0, 0.2: 12.0, 0.3: None}  # impurity -> icicle_px of the main view (64 px wide)
    paths = {}
    for impurity, px in cases.items():
        path = make_job(root, "cube", {"surface.impurity": impurity}, (0.8, 0.2, 0.1))
        zoom = path / "zoom"
        zoom.mkdir()
        write_render(zoom, (0.1, 0.3, 0.9))  # the ice view: blue
        (zoom / "render.exr").rename(path / "render_view1.exr")
        (zoom / "render.png").rename(path / "render_view1.png")
        (path / "views.json").write_text(json.dumps([
            {"index": 0, "name": "three_quarter", "frame": "all", "stem": "render", "icicle_px": px},
            {"index": 1, "name": "ice", "frame": "ice", "stem": "render_view1", "icicle_px": 20.0}]))
        paths[impurity] = path
    jobs = {j.job_id: j for j in S.scan_run(root).objects["cube"]}
    for impurity, path in paths.items():
        exr, view = S.cell_render(jobs[path.name], CELL_W)
        if impurity == 0.1:  # 2 px at 64 wide: 3 px in a 96 px cell, under 4
            assert (exr.name, view) == ("render_view1.exr", "ice")
        else:
            assert (exr.name, view) == ("render.exr", None)
    # At a cell twice as wide the same icicles are 6 px: the main render again.
    assert S.cell_render(jobs[paths[0.1].name], 192)[0].name == "render.exr"
    # The sheet really shows it, tagged.
    sheet = pixels(S.build_sheets(root, cell_width=CELL_W)[0].exr)
    ch = 72
    for k, impurity in enumerate(sorted(cases)):
        x, y = S.MARGIN + k * (CELL_W + S.GAP), S.MARGIN + S.HEADER_H
        block = sheet[y + 20:y + ch, x:x + CELL_W]  # below the tag
        name = "render_view1.exr" if impurity == 0.1 else "render.exr"
        np.testing.assert_allclose(block, fitted(paths[impurity] / name, CELL_W, ch)[20:], atol=2e-3, rtol=2e-3)
    tag = sheet[S.MARGIN + S.HEADER_H:S.MARGIN + S.HEADER_H + 18, S.MARGIN:S.MARGIN + 60]
    assert tag.max() > 0.5  # the "ice view" text
    page = (root / "sheets" / "index.html").read_text()
    assert "render_view1.png" in page and "ice view" in page
