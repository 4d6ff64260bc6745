"""The Python API (`icefarm.api`): ice grown on a mesh in memory, its typed result against the
job's own figures, a job folder that ``icefarm render`` reads, and errors in the command line's
words."""

from __future__ import annotations

import ast
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

import icefarm
from icefarm import api
from icefarm.errors import InputError
from icefarm.stages.trajectories import TrajectoryResult

ROOT = Path(__file__).resolve().parents[1]
# A coarser lattice and pure water (no ripples to carve): the hanging box's ice in about 3 s
# instead of 15; the icicles, glaze and figures are the same kind.
QUICK = {"surface.voxel_size": 0.002, "surface.impurity": 0.0}
WHERE = np.array([2.0, 1.0, -0.5])  # the box stands here in its asset


@pytest.fixture(scope="module")
def box_ice() -> api.Ice:
    box = trimesh.creation.box((0.3, 0.3, 0.3))
    box.apply_translation(WHERE)
    return icefarm.grow(box, placement="hanging", params=QUICK, seed=3)


@pytest.fixture(scope="module")
def tiny_config(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("configs") / "tiny.yaml"
    path.write_text("resolution: [64, 48]\nspp: 2\ndenoise: none\nviews: [three_quarter]\n")
    return path


@pytest.mark.slow  # grows ice on a 0.3 m box (about 3 s, shared by the module's slow tests)
def test_icicles_hang_below_their_roots_from_the_object(box_ice):
    icicles, g = box_ice.icicles, box_ice.gravity
    assert len(icicles) >= 3 and len(icicles) == box_ice.figures["icicles"]
    assert icicles.roots.shape == icicles.tips.shape == (len(icicles), 3) and icicles.lengths.shape == (len(icicles),)
    assert np.all((icicles.tips - icicles.roots) @ g > 0)
    assert np.all(icicles.lengths > 0)
    # an axis is never shorter than the drop from its root to its tip
    assert np.all(icicles.lengths >= (icicles.tips - icicles.roots) @ g - 1e-6)
    assert np.allclose(icicles.lengths, box_ice.figures["trunk_lengths_m"], atol=1e-4)
    for i, axis in enumerate(icicles.axes):
        assert np.allclose(axis[0], icicles.roots[i]) and np.allclose(axis[-1], icicles.tips[i])
    # roots on the object (centred on the origin in the job's frame): on its lower rims
    obj = box_ice.object_mesh
    assert np.allclose(obj.bounds, [[-0.15] * 3, [0.15] * 3], atol=1e-6)
    _, distance, _ = trimesh.proximity.closest_point(obj, icicles.roots)
    assert distance.max() < 0.01


@pytest.mark.slow  # grows ice on a 0.3 m box (shared)
def test_the_ice_lies_around_the_object_with_the_jobs_figures(box_ice):
    ice, obj = box_ice.mesh, box_ice.object_mesh
    assert isinstance(ice, trimesh.Trimesh) and len(ice.faces) == box_ice.figures["ice_faces"] > 1000
    lo, hi = obj.bounds
    assert np.all(ice.bounds[0] < lo) and np.all(ice.bounds[1] > hi)  # glaze all round
    reach = box_ice.icicles.lengths.max() + 0.05  # icicles below, glaze a few centimetres thick
    assert np.all(ice.vertices > lo - reach) and np.all(ice.vertices < hi + reach)
    for key in ("fringe_free_share", "fringe_length_contrast", "glaze_coverage", "glaze_p50_mm", "storm_kind",
                "icicles", "ice_faces"):
        assert key in box_ice.figures, key
    assert box_ice.figures["glaze_coverage"] > 0.5 and box_ice.figures["glaze_p50_mm"] > 1
    assert {"prepare", "water", "drips", "trajectories", "surface"} <= set(box_ice.seconds)
    assert box_ice.params.surface.voxel_size == 0.002 and box_ice.params.storm.intensity == "moderate"
    assert box_ice.placement == "hanging" and box_ice.seed == 3


@pytest.mark.slow  # grows ice on a 0.3 m box (shared)
def test_glaze_per_vertex_and_the_way_back_to_the_asset(box_ice):
    glaze, obj = box_ice.glaze_thickness, box_ice.object_mesh
    assert glaze is not None and glaze.shape == (len(obj.vertices),)
    assert np.all(np.isfinite(glaze)) and np.all(glaze >= 0) and 0.001 < glaze.max() < 0.05  # meters
    back = obj.copy().apply_transform(box_ice.input_transform)
    assert np.allclose(back.bounds, [WHERE - 0.15, WHERE + 0.15], atol=1e-6)


@pytest.mark.slow  # writes the grown box's job (shared), then renders it at 64x48, 2 spp, twice
def test_write_makes_a_job_that_icefarm_render_renders(box_ice, tiny_config, tmp_path):
    from icefarm import jobdir
    from icefarm.cli import main

    folder = tmp_path / "job"
    folder.mkdir()
    (folder / jobdir.RENDER_PNG).write_text("an earlier job's")  # cleared, as icefarm run -o clears it
    assert api.write(box_ice, folder) == folder
    written = {p.name for p in folder.iterdir()}
    assert {jobdir.PARAMS, jobdir.ICE, jobdir.TRAJECTORIES, jobdir.OBJECT, jobdir.SCENE_XML, jobdir.SCENE_SPEC,
            jobdir.VIEWS, jobdir.TIMINGS, jobdir.DONE} <= written and jobdir.RENDER_PNG not in written
    assert jobdir.check_done(folder) is None
    job = jobdir.read_job(folder)
    assert job.state is jobdir.JobState.DONE and job.stats == box_ice.figures
    assert len(trimesh.load(folder / jobdir.ICE, process=False).faces) == len(box_ice.mesh.faces)

    result = CliRunner().invoke(main, ["render", str(folder), "--render", str(tiny_config)])
    assert result.exit_code == 0, result.output
    assert (folder / jobdir.RENDERS_DIR / "tiny" / jobdir.RENDER_PNG).is_file()

    rendered = box_ice.render(tmp_path / "rendered", tiny_config)
    assert [f.name for f in rendered.files[:2]] == [jobdir.RENDER_EXR, jobdir.RENDER_PNG]
    assert all(f.is_file() for f in rendered.files) and jobdir.check_done(tmp_path / "rendered") is None
    assert jobdir.read_job(tmp_path / "rendered").stats["render_variant"] == rendered.variant


TUBES = {"surface.mode": "tubes"}  # swept tubes, no glaze mesh: a job in about a second


def test_a_file_at_a_real_size_and_the_relative_storm(tmp_path):
    path = tmp_path / "crate.ply"
    trimesh.creation.box((3.0, 3.0, 3.0)).export(path)  # a file without units
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the storm's defaults are no choice to warn about
        ice = icefarm.grow(path, size_m=0.3, params={**TUBES, "storm.mode": "relative"}, placement="hanging")
    assert ice.name == "crate" and ice.params.storm.mode == "relative" and ice.glaze_thickness is None
    assert np.allclose(ice.object_mesh.extents, 0.3, atol=1e-6)
    back = ice.object_mesh.copy().apply_transform(ice.input_transform)
    assert np.allclose(back.bounds, [[-1.5] * 3, [1.5] * 3], atol=1e-5)  # the file's own units
    assert len(ice.icicles) == ice.figures["icicles"]


def test_a_job_spec_for_the_command_line(tmp_path):
    config = tmp_path / "tiny.yaml"
    config.write_text("resolution: [64, 48]\n")
    spec = api.job_spec("generator:sign", storm={"precipitation": 12}, seed=4, render=config,
                        exclude=[((-1, -1, -1), (0, 0, 0))])
    assert spec.mesh == "generator:sign" and spec.object_id == "sign" and spec.seed == 4
    assert spec.params.storm.precipitation == 12 and spec.render == str(config.resolve())
    assert spec.exclude == (((-1.0, -1.0, -1.0), (0.0, 0.0, 0.0)),)
    with pytest.raises(InputError, match="render config 'previw'.*did you mean 'preview'"):
        api.job_spec("generator:sign", render="previw")


@pytest.mark.parametrize("raised, caught, message", [
    (InputError("a painted water.ply with 3 vertices"), InputError, "^a painted water.ply with 3 vertices$"),
    (ValueError("a bug"), RuntimeError, "^job failed after stage prepare: ValueError: a bug"),
])
def test_a_job_that_fails_inside_raises_its_error(raised, caught, message, monkeypatch):
    from icefarm.job import pipeline

    def fail(*args, **kwargs):
        raise raised

    monkeypatch.setattr(pipeline, "run_graph", fail)
    with pytest.raises(caught, match=message) as info:
        icefarm.grow("generator:sign")
    assert "\n" not in str(info.value)
    if caught is RuntimeError:  # the job's traceback in the notes (Python 3.11 and later)
        assert "Traceback" in "".join(getattr(info.value, "__notes__", ["Traceback"]))


# ---------------------------------------------------------------- errors, as the command line says them
def cli_error(args: list[str], tmp_path: Path) -> str:
    """What ``icefarm run ARGS`` says after ``error:`` (it fails before running anything)."""
    from icefarm.cli import main

    result = CliRunner().invoke(main, ["run", *args, "-o", str(tmp_path / "out"), "--no-render"])
    assert result.exit_code == 2, result.output
    line = result.output.strip().splitlines()[-1]
    assert line.startswith("error: "), result.output
    return line[len("error: "):]


@pytest.mark.parametrize("args, kwargs", [
    (["generator:sign", "--set", "storm.intensity=hurricane"], {"storm": "hurricane"}),
    (["generator:sign", "--set", "storm.precipitaton=20"], {"storm": {"precipitaton": 20}}),
    (["generator:sign", "--set", "surface.tip_radiu=0.002"], {"params": {"surface.tip_radiu": 0.002}}),
    (["generator:sign", "--set", "storm.kind=hail"], {"kind": "hail"}),
    (["generator:sign", "--set", "surface.voxel_size=-1"], {"params": {"surface": {"voxel_size": -1}}}),
    (["no/such/mesh.obj", "--size-m", "1"], {"mesh": "no/such/mesh.obj", "size_m": 1}),
    (["generator:sigm"], {"mesh": "generator:sigm"}),
], ids=["storm name", "storm value", "parameter", "kind", "domain", "missing file", "generator"])
def test_bad_input_raises_the_clis_message(args, kwargs, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    expected = cli_error(args, tmp_path)
    kwargs = {"mesh": args[0], **kwargs}
    with pytest.raises(InputError) as caught:
        icefarm.grow(**kwargs)
    assert str(caught.value) == expected


@pytest.mark.parametrize("kwargs, message", [
    ({"mesh": trimesh.Trimesh()}, "the mesh is empty"),
    ({"mesh": trimesh.Trimesh([[0, 0, 0], [0, 0, 0], [0, 0, 0]], [[0, 1, 2]])}, "^the mesh has no extent"),
    ({"mesh": trimesh.creation.box(), "placement": "floating"}, "placement 'floating': one of ground, hanging"),
    ({"mesh": trimesh.creation.box(), "size_m": 0}, "size_m 0: the object's real height"),
    ({"mesh": trimesh.creation.box(), "storm": 3}, "storm must be an intensity"),
    ({"mesh": trimesh.creation.box(), "exclude": [((0, 0), (1, 1, 1))]}, "exclude box"),
    ({"mesh": trimesh.creation.box(), "params": {"growth.frames": 4}}, "growth.frames"),
    ({"mesh": 3}, "mesh must be a trimesh.Trimesh"),
])
def test_bad_input_of_the_api_itself_is_one_clear_line(kwargs, message):
    with pytest.raises(InputError, match=message.replace(".", r"\.")) as caught:
        icefarm.grow(**kwargs)
    assert "\n" not in str(caught.value)


def test_a_parameter_the_storm_does_not_read_warns_before_the_job(monkeypatch):
    def stop(*args, **kwargs):
        raise InputError("stopped before the job")

    monkeypatch.setattr(api, "load_object", stop)
    with pytest.warns(UserWarning, match="drips.count does nothing under storm.mode physical"):
        with pytest.raises(InputError, match="stopped"):
            icefarm.grow("generator:sign", params={"drips.count": 5})


# ---------------------------------------------------------------- the record and the package
def test_icicles_are_the_trunks_that_grew():
    # icicle 0: a trunk of three points and a side branch; icicle 1: a drop that fell at once
    points = np.array([[0, 0, 0], [0, -1, 0], [0, -1, 1], [0, -1, 0], [1, -2, 0], [5, 0, 0]], dtype=float)
    traj = TrajectoryResult(points=points, branch_offsets=np.array([0, 3, 5, 6]), branch_icicle=np.array([0, 0, 1]),
                            branch_parent=np.array([-1, 0, -1]))
    icicles = api.Icicles.from_trajectories(traj, [0, -1, 0])
    assert len(icicles) == 1 and icicles.trunks.tolist() == [0]
    assert icicles.roots.tolist() == [[0, 0, 0]] and icicles.tips.tolist() == [[0, -1, 1]]
    assert icicles.lengths.tolist() == [2.0]
    assert icicles.axis(0).tolist() == points[:3].tolist()


def test_the_package_exports_the_api_lazily_and_types_it():
    assert set(icefarm.__all__) == {"Ice", "Icicles", "grow", "render", "write"}
    assert all(getattr(icefarm, name) is getattr(api, name) for name in icefarm.__all__)
    stub = ast.parse((ROOT / "icefarm" / "__init__.pyi").read_text())
    declared = next(node.value for node in stub.body if isinstance(node, ast.Assign)
                    and getattr(node.targets[0], "id", "") == "__all__")
    assert sorted(ast.literal_eval(declared)) == sorted(icefarm.__all__)
    assert (ROOT / "icefarm" / "py.typed").is_file()
    shipped = (ROOT / "pyproject.toml").read_text().split("[tool.setuptools.package-data]", 1)[1].split("\n[", 1)[0]
    assert '"py.typed"' in shipped and '"*.pyi"' in shipped
    for function in (api.grow, api.write, api.render):
        assert "return" in function.__annotations__ and function.__doc__ and "Parameters" in function.__doc__
