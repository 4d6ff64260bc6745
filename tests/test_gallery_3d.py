"""The gallery orbits a real job in 3D: <model-viewer> with a light GLB, loaded from disk."""

from __future__ import annotations

import re
import shutil
import subprocess

import pytest
import trimesh

from icefarm import params, sheets as S
from icefarm.job.pipeline import JobSpec, run_job
from icefarm.sheets.previews import PREVIEW_FACES, model_viewer_js


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    """A sweep folder holding one rendered job of an icosphere with icicles and glaze."""
    root = tmp_path_factory.mktemp("gallery3d")
    trimesh.creation.icosphere(subdivisions=4, radius=0.15).export(root / "sphere.ply")
    (root / "tiny.yaml").write_text("resolution: [40, 30]\nspp: 2\nmax_depth: 4\n")
    p = params.resolve({"water.rays": 2000, "drips.count": 8, "drips.drip_limit": 80})
    spec = JobSpec("sphere", str(root / "sphere.ply"), 0.3, p, seed=3, render=str(root / "tiny.yaml"))
    run = root / "run"
    assert run_job(spec, run / "jobs" / "sphere" / "j0").status == "done"
    return run


@pytest.mark.slow
def test_each_rendered_job_gets_a_light_model_script_and_an_orbit_button(sweep):
    S.build_sheets(sweep, cell_width=64)
    script = sweep / "sheets" / "models" / "sphere-j0.js"
    text = script.read_text()
    assert text.startswith('(window.icefarmModels = window.icefarmModels || {})["sphere-j0"] = '
                           '"data:model/gltf-binary;base64,')
    page = (sweep / "sheets" / "index.html").read_text()
    assert 'class="orbit" data-id="sphere-j0" data-model="models/sphere-j0.js"' in page
    # light: the preview's faces stay near the budget whatever the job's ice holds
    import base64
    import io

    glb = base64.b64decode(text.split("base64,")[1].split('"')[0])
    scene = trimesh.load(io.BytesIO(glb), file_type="glb")
    assert sum(len(g.faces) for g in scene.geometry.values()) <= 1.1 * PREVIEW_FACES
    assert {"ice", "object", "ground"} <= set(scene.geometry)
    # built again with nothing changed, the script is kept as it was
    before = script.stat().st_mtime_ns
    S.build_sheets(sweep, cell_width=64)
    assert script.stat().st_mtime_ns == before


@pytest.mark.slow
def test_the_page_from_disk_orbits_the_job_in_headless_chromium(sweep, tmp_path):
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.skip("chromium is not installed (apt-get install chromium)")
    if model_viewer_js() is None:
        pytest.skip("@google/model-viewer is not installed (npm install, as .ci/setup.sh does)")
    S.build_sheets(sweep, cell_width=64)
    page = sweep / "sheets" / "index.html"
    cmd = [chromium, "--headless", "--no-sandbox", "--use-gl=angle", "--use-angle=swiftshader",
           "--enable-unsafe-swiftshader", "--disable-quic", "--no-first-run", "--disable-background-networking",
           "--disable-component-update", "--disable-sync", f"--user-data-dir={tmp_path / 'profile'}",
           "--virtual-time-budget=15000", "--dump-dom", page.as_uri() + "#3d=sphere-j0"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    body = re.search(r"<body[^>]*>", done.stdout)
    assert body, f"no DOM from chromium (rc {done.returncode}): {done.stderr[-2000:]}"
    attrs = dict(re.findall(r'data-([a-z-]+)="([^"]*)"', body.group(0)))
    assert attrs.get("orbit-loaded") == "sphere-j0", attrs
    assert "<model-viewer" in done.stdout
