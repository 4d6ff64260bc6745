"""The HTML gallery of a run: every sheet and every job, opened straight from disk."""

from __future__ import annotations

import datetime as _dt
import html
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any
from urllib.parse import quote

from .. import jobdir as jd, params as P
from ..artifacts import atomic_write
from .labels import assignment, axis_title, canonical, fixed_changes, format_value, short_name, varying_keys
from .model import SHEETS_DIR, JobInfo, JobState, RunInfo, SheetResult
from .previews import model_id, write_models
from .read import scan_run

# gallery

_CSS = """
body{font:14px/1.4 system-ui,sans-serif;margin:0 2em 3em;background:#1e1e21;color:#e8e8e8}
a{color:#8cc4ff} h1{margin:.6em 0 .1em} h2{margin-top:1.6em;border-bottom:1px solid #444}
.muted{color:#9a9aa0} code{font-size:12px}
.sheet img{max-width:100%;height:auto;border:1px solid #444;display:block}
.jobs{display:grid;grid-template-columns:repeat(auto-fill,minmax(300px,1fr));gap:14px}
.job{background:#2a2a2e;border:1px solid #3a3a40;border-radius:6px;padding:8px}
.job.failed{border-color:#a33;background:#3a2424} .job.unfinished{border-color:#777;opacity:.85}
.job img{width:100%;height:auto;display:block;background:#000}
.ph{aspect-ratio:4/3;display:flex;align-items:center;justify-content:center;text-align:center;
    background:#444;color:#eee;font-weight:bold;padding:4px}
.failed .ph{background:#7f1a1a}
dl.vary{display:grid;grid-template-columns:auto 1fr;gap:0 .8em;margin:.5em 0;font-size:15px}
dl.vary dt{color:#9a9aa0} dl.vary dd{margin:0;font-weight:bold}
table{border-collapse:collapse;font-size:12px} td,th{padding:1px 6px;text-align:left}
th{color:#9a9aa0;font-weight:normal} tr.changed td{color:#ffd479}
.error{color:#ff9d9d} pre{white-space:pre-wrap;font-size:11px;max-height:20em;overflow:auto}
details{margin:.3em 0} summary{cursor:pointer;color:#9a9aa0}
button.orbit{margin:.4em 0;background:#34506e;color:#e8e8e8;border:1px solid #5a7ea6;border-radius:4px;cursor:pointer}
model-viewer{width:100%;aspect-ratio:4/3;background:#111;display:block}
"""

# Orbit a job in 3D: the viewer and the job's model script load on demand (from file://
# only scripts load, hence the models as data: URIs); #3d=<id> in the address opens one.
_ORBIT = """
function icefarmLoad(src, done, fail) {
  var s = document.createElement('script'); s.src = src; s.onload = done; s.onerror = fail;
  document.head.appendChild(s);
}
function icefarmOrbit(button) {
  var id = button.dataset.id, host = button.closest('article');
  var note = function (text) { button.textContent = text; document.body.dataset.orbit = text; };
  if (!button.dataset.viewer) {
    note('3D needs @google/model-viewer: npm install, then build the sheets again'); return;
  }
  note('loading 3D...');
  var show = function () {
    var viewer = document.createElement('model-viewer');
    viewer.setAttribute('camera-controls', ''); viewer.setAttribute('exposure', '1');
    viewer.setAttribute('loading', 'eager');  // it was asked for: not deferred until scrolled to
    viewer.setAttribute('alt', '3D view of ' + id);
    viewer.addEventListener('load', function () { note('3D: drag to orbit'); document.body.dataset.orbitLoaded = id; });
    viewer.addEventListener('error', function () { note('3D view failed to load'); });
    viewer.setAttribute('src', window.icefarmModels[id]);
    var old = host.querySelector('img, .ph');
    host.insertBefore(viewer, old ? old.parentNode === host ? old : old.parentNode : host.firstChild);
    if (old) { (old.parentNode === host ? old : old.parentNode).style.display = 'none'; }
    viewer.scrollIntoView();
  };
  var model = function () { icefarmLoad(button.dataset.model, show, function () { note('3D model missing'); }); };
  if (window.customElements && customElements.get('model-viewer')) { model(); }
  else { icefarmLoad(button.dataset.viewer, model, function () { note('3D viewer missing'); }); }
}
window.addEventListener('load', function () {
  var want = /#3d=([^&]+)/.exec(location.hash);
  if (want) {
    var b = document.querySelector('button.orbit[data-id="' + decodeURIComponent(want[1]) + '"]');
    if (b) { icefarmOrbit(b); }
  }
});
"""

# Counts images that did not load, once the page has loaded (read by tests and by people).
_SCRIPT = """
window.addEventListener('load', function () {
  var bad = [];
  Array.prototype.forEach.call(document.images, function (img) {
    if (!(img.complete && img.naturalWidth > 0)) { bad.push(img.getAttribute('src')); }
  });
  document.body.dataset.images = String(document.images.length);
  document.body.dataset.missingImages = String(bad.length);
  document.body.dataset.missingList = bad.join(' ');
  var note = document.getElementById('missing');
  if (note && bad.length) { note.textContent = bad.length + ' image(s) missing: ' + bad.join(', '); }
});
"""


def _href(path: Path, start: Path) -> str:
    return quote(os.path.relpath(path, start).replace(os.sep, "/"))


def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


def _timings_html(job: JobInfo) -> str:
    folder = job.folder
    if folder is None or not (folder.seconds or folder.stats):
        return '<p class="muted">no timings</p>'
    rows = []
    for stage, s in folder.seconds.items():
        if isinstance(s, (int, float)):
            rows.append(f"<tr><th>{_e(stage)}</th><td>{s:.3f} s</td></tr>")
    total = job.seconds
    if total is not None:
        rows.append(f"<tr><th><b>total</b></th><td><b>{total:.2f} s</b></td></tr>")
    for key, value in folder.stats.items():
        if not isinstance(value, (Mapping, list)):
            rows.append(f"<tr><th>{_e(key)}</th><td>{_e(value)}</td></tr>")
    if folder.state is JobState.DONE:
        rows.append(f"<tr><th>reused</th><td>{_e(', '.join(folder.reused) or 'none')}</td></tr>")
    return f"<table class=\"timings\">{''.join(rows)}</table>"


def _params_html(job: JobInfo, varying: Sequence[str]) -> str:
    defaults = P.flatten(P.defaults())
    index = P.param_index()
    rows = []
    for key, value in job.values.items():
        changed = key not in defaults or canonical(defaults[key]) != canonical(value)
        cls = ' class="changed"' if changed or key in varying else ""
        unit = index[key].unit if key in index and index[key].unit != "-" else ""
        rows.append(f"<tr{cls}><th>{_e(key)}</th><td>{_e(format_value('', value))}</td><td>{_e(unit)}</td></tr>")
    source = jd.PARAMS if job.has_params else f"{jd.JOBS_CSV} (no {jd.PARAMS})"
    return (f"<details><summary>all parameters ({_e(source)}; changed from default highlighted)</summary>"
            f"<table>{''.join(rows)}</table></details>")


def _job_html(job: JobInfo, varying: Sequence[str], here: Path, models: Mapping[str, Path] | None = None,
              viewer: Path | None = None) -> str:
    state = job.state.value
    png = job.file(jd.RENDER_PNG)
    if png is not None:
        picture = (f'<a href="{_href(png, here)}"><img src="{_href(png, here)}" '
                   f'alt="render of {_e(job.job_id)}"></a>')
    elif job.state is JobState.FAILED:
        picture = f'<div class="ph">FAILED<br>stage: {_e(job.folder.failed_stage)}</div>'
    else:
        picture = f'<div class="ph">NOT RENDERED<br>{_e(state)}</div>'
    script = (models or {}).get(model_id(job))
    if script is not None:
        picture += (f'<button type="button" class="orbit" data-id="{_e(model_id(job))}" '
                    f'data-model="{_href(script, here)}" data-viewer="{_href(viewer, here) if viewer else ""}" '
                    f'onclick="icefarmOrbit(this)">orbit in 3D</button>')
    vary = "".join(f"<dt>{_e(short_name(k))}</dt><dd>{_e(format_value(k, job.values[k]))}</dd>"
                   for k in varying if k in job.values)
    vary = f'<dl class="vary">{vary}</dl>' if vary else ""
    seconds = job.seconds
    meta = f'job <code>{_e(job.job_id)}</code> · {_e(state)}'
    if seconds is not None:
        meta += f" · <b>{seconds:.2f} s</b>"
    stages = job.folder.seconds if job.folder is not None else {}
    if stages:
        meta += "<br>" + " · ".join(f"{_e(k)} {v:.2f} s" for k, v in stages.items() if isinstance(v, (int, float)))
    error = ""
    if job.state is JobState.FAILED:
        folder = job.folder
        error = (f'<p class="error">failed at stage <b>{_e(folder.failed_stage)}</b>: '
                 f'{_e(folder.message)}</p>')
        if folder.traceback:
            error += f"<details><summary>traceback</summary><pre>{_e(folder.traceback)}</pre></details>"
    links = []
    for name in (jd.SCENE_XML, jd.ICE, jd.RENDER_EXR, jd.RENDER_PNG, jd.SCENE_POV, jd.PARAMS, jd.TIMINGS, jd.ERROR):
        path = job.file(name)
        if path is not None:
            links.append(f'<a href="{_href(path, here)}">{_e(name)}</a>')
        elif name in (jd.SCENE_XML, jd.ICE):
            links.append(f'<span class="muted">{_e(name)} (none)</span>')
    for view in job.views()[1:]:
        stem = view.get("stem")
        path = job.file(f"{stem}.png") if isinstance(stem, str) and "/" not in stem else None
        if path is not None:
            links.append(f'<a href="{_href(path, here)}">{_e(view.get("name") or stem)} view</a>')
    if job.path is not None:
        links.append(f'<a href="{_href(job.path, here)}/">folder</a>')
    return (f'<article class="job {_e(state)}" id="{_e(job.object_id)}-{_e(job.job_id)}">{picture}{vary}'
            f'<p class="muted">{meta}</p>{error}<p class="links">{" · ".join(links)}</p>'
            f"<details><summary>timings and counts</summary>{_timings_html(job)}</details>"
            f"{_params_html(job, varying)}</article>")


def _gallery_html(run: RunInfo, sheets: Sequence[SheetResult], models: Mapping[str, Path] | None = None,
                  viewer: Path | None = None) -> str:
    here = run.run_dir / SHEETS_DIR
    by_object = {s.object_id: s for s in sheets}
    total = sum(len(j) for j in run.objects.values())
    failed = sum(j.state is JobState.FAILED for jobs in run.objects.values() for j in jobs)
    unfinished = sum(j.state is JobState.PENDING for jobs in run.objects.values() for j in jobs)
    extra = [f'<a href="{_href(run.run_dir / n, here)}">{n}</a>'
             for n in (jd.MANIFEST, jd.JOBS_CSV, jd.REPORT_MD, jd.REPORT_CSV) if (run.run_dir / n).is_file()]
    nav = " · ".join(f'<a href="#{_e(o)}">{_e(o)}</a>' for o in run.objects)
    body = [f"<h1>{_e(run.name)}</h1>",
            f'<p class="muted">{_e(run.method + " sweep" if run.method else "sweep")} · {len(run.objects)} '
            f"object(s) · {total} jobs · {failed} failed · {unfinished} unfinished · "
            f"built {_e(_dt.datetime.now().strftime('%Y-%m-%d %H:%M'))}"
            + (f" · {' · '.join(extra)}" if extra else "") + "</p>",
            f'<p class="error" id="missing"></p><p>objects: {nav}</p>']
    for obj, jobs in run.objects.items():
        varying = varying_keys(jobs, run.swept)
        body.append(f'<section id="{_e(obj)}"><h2>{_e(obj)}</h2>')
        sheet = by_object.get(obj)
        if sheet is not None:
            body.append(f'<figure class="sheet"><a href="{_href(sheet.png, here)}"><img src="{_href(sheet.png, here)}" '
                        f'alt="contact sheet of {_e(obj)}"></a><figcaption class="muted">{sheet.rows} × {sheet.cols} '
                        f'sheet, {sheet.cells} jobs, {sheet.failed} failed · <a href="{_href(sheet.exr, here)}">'
                        f"linear EXR</a></figcaption></figure>")
        if varying:
            body.append('<p class="muted">varying: ' + ", ".join(_e(axis_title(k)) for k in varying) + "</p>")
        fixed = fixed_changes(jobs, varying)
        if fixed:
            body.append('<p class="muted">fixed, not default: '
                        + ", ".join(_e(assignment(k, v)) for k, v in fixed.items()) + "</p>")
        body.append('<div class="jobs">' + "".join(_job_html(j, varying, here, models, viewer) for j in jobs)
                    + "</div></section>")
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{_e(run.name)} · icefarm sheets</title><style>{_CSS}</style>"
            f"<script>{_SCRIPT}{_ORBIT}</script></head>\n<body>\n" + "\n".join(body) + "\n</body></html>\n")


def write_run_gallery(run: RunInfo, sheets: Sequence[SheetResult]) -> Path:
    path = run.run_dir / SHEETS_DIR / "index.html"
    viewer, models = write_models(run, path.parent)
    atomic_write(path, _gallery_html(run, sheets, models, viewer))
    return path


def write_gallery(run_dir: Path, sheets: list[SheetResult]) -> Path:
    """Write ``RUN_DIR/sheets/index.html``: every sheet, then every job of every object.

    Each job shows its render.png, its varying parameters (all of them in a collapsible
    table), timings, links to scene.xml and ice.ply, and for a failed job the stage and
    message. Links are relative, nothing is fetched from elsewhere, so the page works from
    disk. On load a small inline script sets ``data-missing-images`` on ``<body>`` to the
    count of images that failed to load. Each job that rendered gets an "orbit in 3D"
    button: ``<model-viewer>`` with a light GLB of the job (`icefarm.sheets.previews`);
    ``#3d=<object>-<job>`` in the address opens one.

    Returns
    -------
    Path
        The page.
    """
    run = scan_run(Path(run_dir))
    return write_run_gallery(run, sheets)
