"""Timing reports (report.md / report.csv of a sweep) and the Table 2 reproduction."""

import csv
import json
import math

import pytest
import trimesh
import yaml

from icefarm.bench import table2
from icefarm.errors import InputError
from icefarm.params import resolve
from icefarm.report import build_report


def _job(sweep, obj, job, *, seconds=None, reused=(), stats=None, error=None, voxel=0.0008):
    path = sweep / "jobs" / obj / job
    path.mkdir(parents=True)
    (path / "params.yaml").write_text(yaml.safe_dump(resolve({"surface.voxel_size": voxel}).as_dict()))
    if error is not None:
        (path / "error.json").write_text(json.dumps(error))
        return
    timings = {"seconds": seconds, **(stats or {}), "reused": list(reused)}
    (path / "timings.json").write_text(json.dumps(timings))
    (path / "done.json").write_text(json.dumps({"job": obj, **timings}))


def _seconds(water, drips, traj, surface, render=None, prepare=0.05):
    out = {"prepare": prepare, "water": water, "drips": drips, "trajectories": traj, "surface": surface}
    if render is not None:
        out["render"] = render
    return out


@pytest.fixture
def sweep(tmp_path):
    """Two objects x two done jobs (one with stages 1-2 from the cache), one failed job, one unstarted."""
    sweep = tmp_path / "out" / "demo"
    stats = {"input_faces": 1000, "flow_faces": 1000, "icicles": 12, "branches": 15, "render_variant": "llvm_ad_rgb",
             "renderer": "mitsuba"}
    _job(sweep, "cube", "c1", seconds=_seconds(0.2, 0.1, 0.3, 2.0, render=1.5),
         stats={**stats, "ice_faces": 5000, "render_seconds": 1.2, "scene_seconds": 0.1,
                "render_integrator": "icepath"})
    _job(sweep, "cube", "c2", seconds=_seconds(0.001, 0.002, 0.3, 4.0, render=2.5), reused=["water", "drips"],
         stats={**stats, "ice_faces": 7000}, voxel=0.0006)
    stats2 = {**stats, "input_faces": 3000, "icicles": 40, "proxy_faces": 900, "proxy_reason": "4 components"}
    _job(sweep, "teapot", "t1", seconds={"proxy": 1.25, **_seconds(0.4, 0.2, 0.5, 3.0)},
         stats={**stats2, "ice_faces": 9000})
    _job(sweep, "teapot", "t2", seconds={"proxy": 0.01, **_seconds(0.6, 0.2, 0.7, 5.0)}, reused=["proxy"],
         stats={**stats2, "ice_faces": 11000}, voxel=0.0006)
    _job(sweep, "teapot", "t3", error={"stage": "surface", "message": "surface.voxel_size = 1e-05 m is too fine",
                                       "traceback": "Traceback ...", "seconds": {"prepare": 0.05}}, voxel=0.00001)
    (sweep / "jobs" / "teapot" / "t4").mkdir()  # planned, never started
    return sweep


def _csv_rows(path):
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def test_report_rows_totals_medians_and_cache_marks(sweep):
    md_path, csv_path = build_report(sweep)
    assert md_path == sweep / "report.md" and csv_path == sweep / "report.csv"
    rows = _csv_rows(csv_path)
    jobs = {r["job"]: r for r in rows if r["kind"] == "job"}
    objects = {r["object"]: r for r in rows if r["kind"] == "object"}
    assert set(jobs) == {"c1", "c2", "t1", "t2", "t3", "t4"} and set(objects) == {"cube", "teapot"}

    # A fully computed job: Table 2 total is the four stages, not prepare or render.
    assert float(jobs["c1"]["total_s"]) == pytest.approx(2.6)
    assert float(jobs["c1"]["render_s"]) == 1.5 and jobs["c1"]["render_variant"] == "llvm_ad_rgb"
    # The render step split: Mitsuba's render and the scene overhead, as the job measured them.
    assert float(jobs["c1"]["mitsuba_s"]) == 1.2 and float(jobs["c1"]["scene_s"]) == 0.1
    assert jobs["c1"]["render_integrator"] == "icepath" and jobs["c2"]["scene_s"] == ""
    # Cached stages are marked, never reported as measured times; the total counts computed stages.
    assert jobs["c2"]["water_s"] == "cached" and jobs["c2"]["drips_s"] == "cached"
    assert float(jobs["c2"]["total_s"]) == pytest.approx(4.3)
    assert jobs["c2"]["varied"] == "surface.voxel_size=0.0006"
    assert jobs["t2"]["proxy_s"] == "cached" and float(jobs["t1"]["proxy_s"]) == 1.25

    # Object medians: over the jobs that computed each stage; total = sum of stage medians.
    cube = objects["cube"]
    assert float(cube["water_s"]) == pytest.approx(0.2) and float(cube["drips_s"]) == pytest.approx(0.1)
    assert float(cube["surface_s"]) == pytest.approx(3.0)
    assert float(cube["total_s"]) == pytest.approx(0.2 + 0.1 + 0.3 + 3.0)
    assert float(cube["ice_faces"]) == 6000 and cube["jobs"] == "2" and cube["failed"] == "0"
    teapot = objects["teapot"]
    assert float(teapot["total_s"]) == pytest.approx(0.5 + 0.2 + 0.6 + 4.0)
    assert float(teapot["proxy_s"]) == 1.25 and teapot["failed"] == "1"

    # The failed job keeps its stage and message; the unstarted one is pending.
    assert jobs["t3"]["status"] == "failed" and jobs["t3"]["failed_stage"] == "surface"
    assert "too fine" in jobs["t3"]["error"] and jobs["t3"]["total_s"] == ""
    assert jobs["t4"]["status"] == "pending"

    md = md_path.read_text()
    assert "6 jobs: 4 done, 1 failed, 1 not finished" in md
    c2_line = next(line for line in md.splitlines() if "| c2 |" in line)
    assert c2_line.count("cached") == 3 and "4.300 + cached" in c2_line
    failed = md.split("## Failed jobs")[1]
    assert "| teapot | t3 |" in failed and "surface" in failed and "too fine" in failed
    summary = md.split("## Per object (medians)")[1].split("## Per job")[0]
    assert "| cube | 2 | 0 |" in summary and "3.600" in summary and "llvm_ad_rgb" in summary


def test_report_all_cached_stage_and_single_job_folder(tmp_path):
    sweep = tmp_path / "s"
    _job(sweep, "cube", "a", seconds=_seconds(0.001, 0.001, 0.001, 1.0), reused=["water", "drips", "trajectories"])
    md, csv_path = build_report(sweep)
    cube = next(r for r in _csv_rows(csv_path) if r["kind"] == "object")
    assert cube["water_s"] == "cached" and float(cube["total_s"]) == 1.0
    assert "1.000 + cached" in md.read_text()
    md, _ = build_report(sweep / "jobs" / "cube" / "a")  # one job folder works too
    assert "| cube | a |" in md.read_text()


def test_report_refuses_folders_without_jobs(tmp_path):
    with pytest.raises(InputError, match="no job folders"):
        build_report(tmp_path)
    with pytest.raises(InputError, match="not a folder"):
        build_report(tmp_path / "missing")


# --------------------------------------------------------------------------- Table 2

def test_paper_table2_totals_add_up():
    assert [r.key for r in table2.PAPER_TABLE2] == list("abcdefg")
    for row in table2.PAPER_TABLE2:
        parts = sum(row.seconds[s] for s in table2.STAGES)
        assert parts == pytest.approx(row.seconds["total"], abs=0.6)  # the paper rounds (g: 37.8 vs 37.8)
    assert set(table2.ROW_OBJECTS) == set("abcdefg")


def test_parse_rows():
    assert table2.parse_rows(None) == list("abcdefg")
    assert table2.parse_rows("g, (a)") == ["a", "g"]
    with pytest.raises(InputError, match="choose among"):
        table2.parse_rows("a,z")


def test_calibrate_voxel_converges_and_backs_off_refused_grids():
    target = 50_000

    def measure(voxel):
        if voxel < 0.0004:
            raise InputError("too fine")
        return round(0.08 / voxel**2)  # faces grow as 1 / voxel**2

    voxel, faces = table2.calibrate_voxel(measure, target, (0.0001, 0.003))
    assert abs(math.log(faces / target)) <= math.log(table2.CALIBRATION_TOLERANCE)
    voxel, faces = table2.calibrate_voxel(measure, 10**7, (0.0001, 0.003), runs=6)
    assert voxel >= 0.0004 and faces > 0  # the finest accepted grid, not an error


def test_decimate_hits_the_face_count():
    mesh = trimesh.creation.icosphere(subdivisions=4)
    small = table2.decimate(mesh, 500)
    assert abs(len(small.faces) - 500) <= 2 and small.is_watertight
    assert table2.decimate(small, 10_000) is small


def test_table2_rows_keep_the_papers_drip_points_and_the_jobs_ground():
    p = table2._row_params(table2.ROW_OBJECTS["d"], 20, 0.002)
    assert p.drips.distribution == "area" and p.drips.spacing == 0 and p.drips.min_fall == 0
    assert p.proxy.mode == "never" and p.drips.ground_clearance > 0 and p.drips.count == 20


@pytest.mark.slow  # reads ../shared/meshes
def test_table2_smoke_two_rows_reduced(tmp_path, shared_mesh):
    """Rows a (cow) and g (generated house) at 5 % size, one run each: the command cannot rot."""
    pytest.importorskip("icefarm.stages.surface")
    meshes = shared_mesh("cow.obj").parent
    result = table2.run_table2(meshes, tmp_path, repeat=1, rows="g,a", scale=0.05, progress=False)
    assert [r.paper.key for r in result.rows] == ["a", "g"] and result.skipped == ()
    for row in result.rows:
        assert row.ice_faces > 0 and row.icicles >= 1
        assert abs(row.input_faces - table2.MIN_SCALED_POLYGONS) <= 5
        assert all(len(v) == 1 and v[0] >= 0 for v in row.seconds.values())
        assert row.seconds["total"][0] == pytest.approx(sum(row.seconds[s][0] for s in table2.STAGES))
        assert row.voxel_size <= resolve().surface.tip_radius
    lines = _csv_rows(tmp_path / "table2.csv")
    assert [(r["row"], r["status"]) for r in lines] == [("a", "done"), ("g", "done")]
    assert float(lines[1]["paper_surface_s"]) == 36 and float(lines[1]["surface_s"]) > 0
    assert float(lines[1]["total_speedup"]) == pytest.approx(37.8 / float(lines[1]["total_s"]), rel=1e-3)
    md = (tmp_path / "table2.md").read_text()
    assert "| Figure 16 | (a) | (g) |" in md and "131,000" in md and "Total time: speed-up" in md


def test_table2_skips_rows_without_meshes(tmp_path, monkeypatch):
    monkeypatch.setattr(table2, "default_meshes_dir", lambda: None)
    result = table2.run_table2(None, tmp_path, repeat=1, rows="c", progress=False)
    assert result.rows == () and result.skipped[0][0] == "c" and "dragon.obj" in result.skipped[0][1]
    assert "(c): needs dragon.obj" in (tmp_path / "table2.md").read_text()
    assert _csv_rows(tmp_path / "table2.csv")[0]["status"] == "skipped"
    with pytest.raises(InputError, match="not a folder"):
        table2.run_table2(tmp_path / "nowhere", tmp_path, rows="a", progress=False)
    with pytest.raises(InputError, match="repeat"):
        table2.run_table2(None, tmp_path, repeat=0, progress=False)


def test_the_report_and_the_sheets_list_jobs_in_the_order_of_jobs_csv(tmp_path):
    """One job order for every reader of a sweep folder: jobs.csv's, then the unlisted ones."""
    from icefarm.report import find_job_dirs
    from icefarm.sheets import scan_run

    for obj, job in (("a", "j1"), ("a", "j2"), ("b", "j3"), ("a", "j9")):
        (tmp_path / "jobs" / obj / job).mkdir(parents=True)
        (tmp_path / "jobs" / obj / job / "params.yaml").write_text(yaml.safe_dump(resolve().as_dict()))
    (tmp_path / "jobs.csv").write_text("job_id,object,status\nj3,b,done\nj2,a,done\nj1,a,pending\n")
    assert [p.name for p in find_job_dirs(tmp_path)] == ["j3", "j2", "j1", "j9"]
    assert [j.job_id for j in scan_run(tmp_path).objects["a"]][:2] == ["j2", "j1"]
