"""Light 3D previews of a sweep's jobs for the gallery, and the viewer that shows them.

The gallery opens straight from disk (``file://``), where a browser fetches no file, so a
job's preview GLB (`icefarm.export.gltf.write_glb` with its meshes decimated to `PREVIEW_FACES`)
travels as a base64 ``data:`` URI inside a small script, ``sheets/models/<object>-<job>.js``,
that the page loads only when asked to orbit that job. The viewer is Google's
``<model-viewer>`` (the ``@google/model-viewer`` npm package, `.ci/setup.sh` installs it
with ``package.json``), copied next to the page as ``sheets/vendor/model-viewer.min.js``.
"""

from __future__ import annotations

import base64
import os
import shutil
import tempfile
from pathlib import Path

from ..artifacts import atomic_write
from ..jobdir import ICE, OBJECT, PARAMS, SCENE_XML
from .model import JobInfo, RunInfo

# Faces of a preview GLB, all meshes together (ice, object, ground): a few MB at most.
PREVIEW_FACES = 60_000
MODELS_DIR, VENDOR_DIR = "models", "vendor"
VIEWER_FILE = "model-viewer.min.js"
_VIEWER_IN_PACKAGE = ("@google", "model-viewer", "dist", "model-viewer-umd.min.js")


def model_viewer_js() -> Path | None:
    """``model-viewer-umd.min.js`` (self-contained, loads from ``file://``) from a
    ``node_modules`` folder: ``$ICEFARM_NODE_MODULES``, the source checkout's, or the
    current folder's; None when none has it."""
    roots = [os.environ.get("ICEFARM_NODE_MODULES"), Path(__file__).resolve().parents[2] / "node_modules",
             Path.cwd() / "node_modules"]
    for root in roots:
        if root and Path(root, *_VIEWER_IN_PACKAGE).is_file():
            return Path(root, *_VIEWER_IN_PACKAGE)
    return None


def model_id(job: JobInfo) -> str:
    return f"{job.object_id}-{job.job_id}"


def write_models(run: RunInfo, sheets_dir: Path) -> tuple[Path | None, dict[str, Path]]:
    """Write the viewer and a preview model script per rendered job under ``sheets_dir``.

    Returns
    -------
    viewer : Path or None
        ``sheets/vendor/model-viewer.min.js``; None when ``@google/model-viewer`` is not
        installed (the gallery then says how to get it).
    models : dict
        `model_id` to its ``sheets/models/<id>.js``; a script newer than its job's
        ``ice.ply`` and ``scene.xml`` is kept as it is.
    """
    from ..export.gltf import write_glb

    viewer = None
    source = model_viewer_js()
    if source is not None:
        viewer = sheets_dir / VENDOR_DIR / VIEWER_FILE
        if not viewer.is_file() or viewer.stat().st_size != source.stat().st_size:
            viewer.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(source, viewer)
    models: dict[str, Path] = {}
    for jobs in run.objects.values():
        for job in jobs:
            inputs = [job.file(n) for n in (ICE, OBJECT, SCENE_XML, PARAMS)]
            if any(p is None for p in inputs):
                continue
            script = sheets_dir / MODELS_DIR / f"{model_id(job)}.js"
            newest = max(p.stat().st_mtime for p in inputs)
            if not script.is_file() or script.stat().st_mtime < newest:
                with tempfile.TemporaryDirectory(prefix="icefarm-preview-") as tmp:
                    glb = write_glb(job.path, Path(tmp) / "preview.glb", max_faces=PREVIEW_FACES)
                    data = base64.b64encode(glb.read_bytes()).decode("ascii")
                script.parent.mkdir(parents=True, exist_ok=True)
                atomic_write(script, f'(window.icefarmModels = window.icefarmModels || {{}})["{model_id(job)}"] = '
                                     f'"data:model/gltf-binary;base64,{data}";\n')
            models[model_id(job)] = script
    return viewer, models
