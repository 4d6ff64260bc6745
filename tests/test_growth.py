"""Growth over time (icefarm.job.frames): prefixes of the full growth, one seed, N frames."""

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from icefarm import params as P
from icefarm.artifacts import trajectories_from_json
from icefarm.cli import main
from icefarm.farm.manifest import load_manifest
from icefarm.job.frames import read_frames
from icefarm.job.pipeline import JobSpec, run_job
from icefarm.stages.drips import DripResult
from icefarm.stages.growth import frame_fractions, stage4_inputs_at, trajectories_at
from icefarm.stages.surface.icicles import icicle_balls
from icefarm.stages.trajectories import TrajectoryResult

FRAMES = 3
VOXEL = 0.003


def _lengths(traj: TrajectoryResult) -> np.ndarray:
    return np.array([np.linalg.norm(np.diff(traj.branch(b), axis=0), axis=1).sum() if len(traj.branch(b)) > 1
                     else 0.0 for b in range(traj.n_branches)])


def _is_prefix(a: TrajectoryResult, b: TrajectoryResult) -> bool:
    """Every branch of ``a`` is a prefix of the same branch of ``b``: the same points, but the
    last, which lies on b's polyline (a prefix that ends between two points)."""
    for i in range(a.n_branches):
        pa, pb = a.branch(i), b.branch(i)
        if len(pa) == 0:
            continue
        if len(pa) > len(pb) or not np.array_equal(pa[:-1], pb[:len(pa) - 1]):
            return False
        if len(pa) >= 2:  # the last point on b's segment from point len(pa) - 2 on
            seg, end = pb[len(pa) - 1] - pb[len(pa) - 2], pa[-1] - pb[len(pa) - 2]
            if np.linalg.norm(np.cross(seg, end)) > 1e-9 or end @ seg < -1e-12 or end @ seg > seg @ seg + 1e-12:
                return False
    return True


@pytest.fixture
def forked() -> TrajectoryResult:
    """A 10 cm trunk of 1 cm steps and a 5 cm branch leaving it 4 cm down, 2 cm cut off the trunk."""
    trunk = np.c_[np.zeros(11), -0.01 * np.arange(11), np.zeros(11)]
    branch = trunk[4] + np.c_[0.01 * np.arange(6), -0.01 * np.arange(6), np.zeros(6)] / np.sqrt(2)
    return TrajectoryResult(points=np.vstack([trunk, branch]), branch_offsets=np.array([0, 11, 17]),
                            branch_icicle=np.array([0, 0]), branch_parent=np.array([-1, 0]),
                            branch_cut=np.array([0.02, 0.0]))


def test_trajectories_at_grows_prefixes_from_nothing_to_the_whole(forked):
    assert len(trajectories_at(forked, 0.0).points) == 0
    assert trajectories_at(forked, 1.0) is forked
    fractions = np.linspace(0, 1, 21)
    frames = [trajectories_at(forked, f) for f in fractions]
    lengths = np.array([_lengths(t) for t in frames])
    assert (np.diff(lengths, axis=0) >= -1e-12).all()
    assert all(_is_prefix(a, b) for a, b in zip(frames, frames[1:]))
    cuts = np.array([t.cut for t in frames])
    assert (np.diff(cuts, axis=0) >= -1e-12).all() and cuts[-1] == pytest.approx([0.02, 0.0])
    # The trunk grows f (10 + 2) cm until the ground stops it at 10 cm, then gathers its cut.
    assert lengths[5, 0] == pytest.approx(0.25 * 0.12) and frames[5].cut[0] == 0
    assert lengths[18, 0] == pytest.approx(0.10) and frames[18].cut[0] == pytest.approx(0.9 * 0.12 - 0.10)
    # The branch is born when the trunk reaches 4 cm (f = 1/3), then grows in from nothing.
    assert len(trajectories_at(forked, 0.33).branch(1)) == 0
    assert _lengths(trajectories_at(forked, 2 / 3))[1] == pytest.approx(0.5 * 0.05)
    np.testing.assert_array_equal(trajectories_at(forked, 0.5).branch(1)[0], forked.branch(1)[0])
    with pytest.raises(ValueError):
        trajectories_at(forked, 1.5)


def test_stage4_inputs_scale_the_water_driven_sizes():
    drips = DripResult(np.arange(3), np.zeros((2, 3)), np.ones((2, 3)), np.array([0.2, 0.4]), np.array([0, 1]))
    glaze = P.resolve({"glaze.min_radius": 0.001}).glaze
    half, g = stage4_inputs_at(drips, glaze, 0.5)
    assert half.water == pytest.approx([0.1, 0.2]) and half.positions is drips.positions
    assert g.min_radius == pytest.approx(0.0005) and g.scale == pytest.approx(glaze.scale / 2)
    assert stage4_inputs_at(drips, glaze, 1.0) == (drips, glaze)
    assert frame_fractions(4)[-1] == 1.0 and len(frame_fractions(1)) == 1


def test_a_frame_stream_draws_for_the_bases_what_the_full_growth_draws(forked):
    """After the icicles' noise, every frame's stream stands where the full growth's does."""
    from icefarm.stages.growth import noise_draws

    surface = P.typed("surface", P.resolve().surface)
    states = []
    for f in (0.4, 0.7, 1.0):
        traj = trajectories_at(forked, f)
        rng = np.random.default_rng([5, 3])
        rng.bit_generator.advance((noise_draws(forked, surface) - noise_draws(traj, surface)) % 2**128)
        icicle_balls(traj, surface, rng)
        states.append(rng.bit_generator.state["state"])
    assert states[0] == states[1] == states[2]


@pytest.fixture(scope="module")
def grown(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("growth")
    config = tmp / "tiny.yaml"
    config.write_text("resolution: [40, 30]\nspp: 2\nmax_depth: 4\n")
    p = P.resolve({"storm.mode": "relative", "drips.count": 4, "surface.voxel_size": VOXEL, "glaze.mode": "coat",
                   "growth.frames": FRAMES})
    outcome = run_job(JobSpec("roof", "generator:roof", 0.4, p, seed=3, render=str(config)), tmp / "job")
    assert outcome.status == "done", outcome.error
    return tmp / "job"


@pytest.mark.slow  # a rendered growth job (module fixture)
def test_each_frame_holds_the_one_before(grown):
    rows = read_frames(grown / "growth")
    assert [r["index"] for r in rows] == list(range(1, FRAMES + 1)) and rows[-1]["fraction"] == 1.0
    volumes = [r["volume_m3"] for r in rows]
    assert volumes[0] > 0 and all(b >= a for a, b in zip(volumes, volumes[1:]))
    meshes = [trimesh.load(grown / "growth" / f"ice_{i:04d}.ply", process=False) for i in range(1, FRAMES + 1)]
    rng = np.random.default_rng(0)
    for a, b in zip(meshes, meshes[1:]):
        assert b.is_watertight
        points = a.vertices[rng.choice(len(a.vertices), 1000, replace=False)]
        # inside the next frame, up to the icicles' noise (drawn anew for re-spaced balls)
        # and marching cubes
        assert trimesh.proximity.signed_distance(b, points).min() > -(P.resolve().surface.noise + VOXEL / 4)
    traj = trajectories_from_json(grown / "trajectories.json")
    frames = [trajectories_at(traj, r["fraction"]) for r in rows]
    assert all(_is_prefix(a, b) for a, b in zip(frames, frames[1:]))
    assert rows[0]["tip_radius_mm"] == pytest.approx(2.44, abs=0.5)


@pytest.mark.slow  # a rendered growth job (module fixture)
def test_the_last_frame_is_the_jobs_ice(grown):
    from icefarm.artifacts import read_ice_mesh
    from icefarm.jobdir import ICE_BANDS

    last = read_ice_mesh(grown / "growth" / f"ice_{FRAMES:04d}.ply")
    ice = read_ice_mesh(grown / "ice.ply")
    np.testing.assert_array_equal(last.vertices, ice.vertices)
    np.testing.assert_array_equal(last.faces, ice.faces)
    # milky under the same ripple crests (the job's water is impure)
    np.testing.assert_array_equal(last.vertex_attributes[ICE_BANDS], ice.vertex_attributes[ICE_BANDS])


@pytest.mark.slow  # a rendered growth job (module fixture)
def test_frames_movie_and_usd(grown):
    import imageio_ffmpeg
    import OpenImageIO as oiio

    sizes = {oiio.ImageBuf(str(grown / "growth" / f"frame_{i:04d}.png")).spec().width for i in range(1, FRAMES + 1)}
    assert sizes == {40}
    reader = imageio_ffmpeg.read_frames(str(grown / "growth" / "growth.mp4"))
    meta = next(reader)
    assert meta["size"] == (40, 30) and sum(1 for _ in reader) == FRAMES
    script = ("import sys, json; from pxr import Usd, UsdGeom; s = Usd.Stage.Open(sys.argv[1]); "
              "a = s.GetPrimAtPath('/Growth/Ice').GetAttribute('points'); "
              "print(json.dumps([a.GetTimeSamples(), UsdGeom.GetStageMetersPerUnit(s), UsdGeom.GetStageUpAxis(s), "
              "s.GetStartTimeCode(), s.GetEndTimeCode(), len(a.Get(s.GetEndTimeCode()))]))")
    out = subprocess.run([sys.executable, "-c", script, str(grown / "growth" / "growth.usda")],
                         capture_output=True, text=True, check=True)
    samples, meters, up, start, end, points = json.loads(out.stdout)
    assert samples == list(range(1, FRAMES + 1)) and meters == 1 and up == "Y" and (start, end) == (1, FRAMES)
    assert points == len(trimesh.load(grown / "ice.ply", process=False).vertices)
    done = json.loads((grown / "done.json").read_text())
    assert done["growth_frames"] == FRAMES and "growth/growth.mp4" in done["artifacts"]


@pytest.mark.parametrize("bad", ["0", "-2", "241"])
def test_bad_frame_counts_get_one_line(bad, tmp_path):
    result = CliRunner().invoke(main, ["run", "generator:roof", "--size-m", "0.4", "-o", str(tmp_path),
                                       "--growth-frames", bad])
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "--growth-frames" in lines[0]


def test_help_and_manifest_name_growth(tmp_path):
    assert "--growth-frames" in CliRunner().invoke(main, ["run", "--help"]).output
    text = "objects: [{mesh: 'generator:roof', size_m: 0.4%s}]\ndefaults: {growth: {frames: 5}}\n"
    (tmp_path / "a.yaml").write_text(text % ", growth: {frames: 12}")
    manifest = load_manifest(tmp_path / "a.yaml")
    assert manifest.objects[0].params["growth.frames"] == 12 and manifest.defaults["growth.frames"] == 5
    for bad in (", growth: {frames: 300}", ", growth: 12", ", growth: {frame: 3}"):
        (tmp_path / "b.yaml").write_text(text % bad)
        with pytest.raises(Exception, match=r"objects\[0\]\.growth"):
            load_manifest(tmp_path / "b.yaml")


@pytest.mark.slow  # a rendered growth job (module fixture)
def test_growth_usd_is_value_clips_with_normals_the_ice_glass_and_the_ground(grown):
    """One small layer per frame, stitched as value clips; the animation opens looking as
    the render did: normals, the ice's MaterialX glass, the ground, cameras and lights."""
    script = textwrap.dedent("""
        import sys, json
        from pxr import Usd, UsdGeom, UsdShade
        s = Usd.Stage.Open(sys.argv[1])
        ice = s.GetPrimAtPath('/Growth/Ice')
        clips = Usd.ClipsAPI(ice)
        normals = UsdGeom.Mesh(ice).GetNormalsAttr()
        material = UsdShade.MaterialBindingAPI(ice).ComputeBoundMaterial()[0]
        mtlx = material.ComputeSurfaceSource('mtlx')[0]
        print(json.dumps({
            "clips": [a.path for a in clips.GetClipAssetPaths()],
            "errors": [str(e) for e in s.GetCompositionErrors()],
            "normals": normals.GetTimeSamples(), "n_normals": len(normals.Get(s.GetEndTimeCode())),
            "points": len(UsdGeom.Mesh(ice).GetPointsAttr().Get(s.GetEndTimeCode())),
            "mtlx": mtlx.GetIdAttr().Get() if mtlx else None,
            "ground": s.GetPrimAtPath('/Growth/Ground').IsA(UsdGeom.Mesh),
            "cameras": [p.GetName() for p in s.GetPrimAtPath('/Growth/Cameras').GetChildren()],
            "sun": s.GetPrimAtPath('/Growth/Lights/Sun').IsValid()}))
    """)
    out = subprocess.run([sys.executable, "-c", script, str(grown / "growth" / "growth.usda")],
                         capture_output=True, text=True, check=True)
    facts = json.loads(out.stdout)
    assert facts["clips"] == [f"./ice_{i:04d}.usdc" for i in range(1, FRAMES + 1)]
    assert all((grown / "growth" / f"ice_{i:04d}.usdc").is_file() for i in range(1, FRAMES + 1))
    assert facts["errors"] == []
    assert facts["normals"] == list(range(1, FRAMES + 1)) and facts["n_normals"] == facts["points"]
    assert facts["mtlx"] == "ND_open_pbr_surface_surfaceshader"
    assert facts["ground"] and facts["sun"] and "three_quarter" in facts["cameras"]
