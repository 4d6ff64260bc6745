import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh
import yaml

SHARED_MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"


@pytest.fixture
def shared_mesh():
    """Path of a mesh in ../shared/meshes; skips when the folder is not beside the repo."""

    def get(name: str) -> Path:
        path = SHARED_MESHES / name
        if not path.is_file():
            pytest.skip(f"{path} not available")
        return path

    return get


@pytest.fixture
def sphere() -> trimesh.Trimesh:
    """A 0.3 m icosphere centred on the origin."""
    return trimesh.creation.icosphere(subdivisions=4, radius=0.15)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(7)


@pytest.fixture(scope="module")
def mi():
    """Mitsuba on a JIT variant (the ice integrator needs one); skips where there is none."""
    from icefarm.scene.variants import pick_variant

    variant = pick_variant("auto")
    if variant == "scalar_rgb":
        pytest.skip("no JIT variant here: the ice integrator needs llvm_ad_rgb or cuda_ad_rgb")
    import mitsuba

    mitsuba.set_variant(variant)
    return mitsuba


# ------------------------------------------------------------------ stage 4 by hand
# (icefarm's stages are imported when a helper runs, not when the tests are collected)

# Gravity -Y (y up, as the generators and the shared meshes). The test modules keep their
# own one-line `G = np.array([0.0, -1.0, 0.0])`: they use it at module level (helpers,
# reference implementations, module-scoped fixtures), where a fixture does not reach, and
# pytest advises against importing conftest; a module's own array also keeps an in-place
# edit from leaking into other modules.
G = np.array([0.0, -1.0, 0.0])


def _groups(**changes):
    """Resolved surface and glaze groups with ``group__name`` changes."""
    from icefarm import params

    p = params.resolve({k.replace("__", "."): v for k, v in changes.items()})
    return p.surface, p.glaze


def _sphere(radius=0.15):
    return trimesh.creation.icosphere(subdivisions=4, radius=radius)


def _water(mesh, wet):
    """Water on ``mesh`` by hand: ``wet`` vertices, dUp/dDown from their heights along ``G``."""
    from icefarm.stages.water import WaterResult

    h = mesh.vertices @ -G
    top, bottom = h[wet].max(), h[wet].min()
    n = len(h)
    return WaterResult(supply=wet, water=np.where(wet, 0.1, 0.0), top=np.zeros(n, int),
                       d_up=np.where(wet, top - h, 0.0), bottom=np.zeros(n, int),
                       d_down=np.where(wet, h - bottom, 0.0), hits=np.zeros((0, 3)))


def _dry(mesh):
    """Water that wets nothing on ``mesh``."""
    from icefarm.stages.water import WaterResult

    n = len(mesh.vertices)
    z = np.zeros(n)
    return WaterResult(np.zeros(n, bool), z, z.astype(int), z, z.astype(int), z, np.zeros((0, 3)))


def _drips(mesh, points, water=0.1):
    """Drip points on ``mesh`` nearest ``points``, each with ``water``."""
    from icefarm.stages.drips import DripResult

    points = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(points) == 0:
        return DripResult(np.zeros(0, int), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, int))
    closest, _, face = trimesh.proximity.closest_point(mesh, points)
    return DripResult(np.zeros(0, int), closest, mesh.face_normals[face],
                      np.full(len(points), water), face)


def _straight(starts, lengths, step=0.004):
    """One straight trunk per start, hanging along gravity."""
    from icefarm.stages.trajectories import TrajectoryResult

    pts, off = [], [0]
    for s, length in zip(np.asarray(starts, float).reshape(-1, 3), lengths):
        n = max(int(np.ceil(length / step)), 1)
        pts.append(s + np.linspace(0.0, length, n + 1)[:, None] * G)
        off.append(off[-1] + n + 1)
    k = len(off) - 1
    return TrajectoryResult(np.concatenate(pts), np.array(off), np.arange(k), np.full(k, -1))


def _no_icicles():
    """Trajectories without a branch."""
    from icefarm.stages.trajectories import TrajectoryResult

    return TrajectoryResult(np.zeros((0, 3)), np.zeros(1, int), np.zeros(0, int), np.zeros(0, int))


def _ice(obj, water, drips, traj, surface, glaze, seed=0):
    """Stage 4 on ``obj`` (its own collision mesh) under gravity -Y."""
    from icefarm.stages.surface import IceInputs, build_ice

    return build_ice(IceInputs(obj, obj, water, drips, traj), surface, glaze, G, np.random.default_rng(seed))


@pytest.fixture
def surface_kit() -> SimpleNamespace:
    """Stage 4's inputs made by hand, and stage 4 itself, under gravity ``G`` (-Y).

    ``sphere(radius)``, ``water(mesh, wet)`` (the ``wet`` vertices wet, dUp and dDown from
    their heights), ``dry(mesh)`` (a `WaterResult` that wets nothing), ``drips(mesh, points,
    water)``, ``straight(starts, lengths)`` (one straight trunk per start), ``no_icicles()``,
    ``groups(**changes)`` (resolved surface and glaze groups, ``surface__name=value``) and
    ``ice(obj, water, drips, traj, surface, glaze, seed)``.
    """
    return SimpleNamespace(G=G, sphere=_sphere, water=_water, dry=_dry, drips=_drips, straight=_straight,
                           no_icicles=_no_icicles, groups=_groups, ice=_ice)


# ------------------------------------------------------------------ scenes to render

TINY_RENDER = {"resolution": [48, 36], "spp": 4, "max_depth": 6}


def _box_with_icicles(gravity=(0.0, -1.0, 0.0)):
    """A 30 cm box and five cones hanging from its underside along ``gravity``."""
    g = np.asarray(gravity, dtype=float) / np.linalg.norm(gravity)
    box = trimesh.creation.box(extents=(0.3, 0.1, 0.2))
    box.apply_translation((0.0, 0.05, 0.0))
    cones = []
    for i, x in enumerate(np.linspace(-0.12, 0.12, 5)):
        cone = trimesh.creation.cone(radius=0.012, height=0.06 + 0.03 * (i % 3), sections=24)
        cone.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))  # tip -Y
        cone.apply_translation((x, 0.0, 0.05 * (1 if i % 2 else -1)))
        cones.append(cone)
    ice = trimesh.util.concatenate(cones)
    # Rotate the Y-up test scene so that -Y goes to gravity.
    turn = trimesh.geometry.align_vectors((0.0, -1.0, 0.0), g)
    for mesh in (box, ice):
        mesh.apply_transform(turn)
    return box, ice


def _tiny_config(base=None, **changes):
    """`TINY_RENDER` (48 x 36 pixels, 4 spp) with ``changes``, over ``base`` (the preview config)."""
    from icefarm.scene.config import load_render_config, render_config_from_dict

    return render_config_from_dict({**TINY_RENDER, **changes}, base=base or load_render_config("preview"))


def _assert_not_blank(pixels: np.ndarray) -> None:
    rgb = pixels[..., :3]
    assert np.isfinite(rgb).all()
    assert rgb.max() > 0.05, "image is black"
    assert rgb.std() > 0.01, "image is flat"


@pytest.fixture
def box_with_icicles():
    """``box_with_icicles(gravity=(0, -1, 0))``: a 30 cm box and five cones hanging from it, as (box, ice)."""
    return _box_with_icicles


@pytest.fixture
def tiny_config():
    """``tiny_config(base=None, **changes)``: a render config of 48 x 36 pixels and 4 spp."""
    return _tiny_config


@pytest.fixture
def assert_not_blank():
    """``assert_not_blank(pixels)``: finite, not black, not flat."""
    return _assert_not_blank


# ------------------------------------------------------------------ quick jobs and sweeps

FAST = {"water": {"rays": 300}, "drips": {"count": 4}, "proxy": {"mode": "never"}}  # stage-only jobs in seconds


def _write_ball(folder: Path) -> Path:
    path = folder / "ball.ply"
    trimesh.creation.icosphere(subdivisions=2, radius=1.0).export(path)
    return path


def _write_tiny_render(folder: Path) -> Path:
    """``folder/tiny.yaml``: the preview config at `TINY_RENDER`, without its denoiser, for a manifest."""
    from icefarm.scene.config import CONFIG_DIR

    path = folder / "tiny.yaml"
    config = yaml.safe_load((CONFIG_DIR / "preview.yaml").read_text())
    path.write_text(yaml.safe_dump({**config, **TINY_RENDER, "denoise": "none"}))
    return path


@pytest.fixture
def ball(tmp_path) -> Path:
    """``tmp_path/ball.ply``: an icosphere of radius 1 (subdivisions 2), for jobs and manifests."""
    return _write_ball(tmp_path)


@pytest.fixture(scope="session")
def sweep_kit() -> SimpleNamespace:
    """For fixtures wider than a test: ``fast`` (`FAST`), ``ball(folder)`` (writes the `ball`
    fixture's mesh there) and ``tiny_render(folder)`` (writes a tiny render config there,
    `TINY_RENDER` without a denoiser); each writer returns the path."""
    return SimpleNamespace(fast=FAST, ball=_write_ball, tiny_render=_write_tiny_render)


@pytest.fixture
def write_manifest(tmp_path, ball):
    """``write_manifest(sweep=None, *, grid=None, objects=None, name="t", seed=1, defaults=None, **extra)``.

    Writes ``tmp_path/<name>.yaml``: a manifest without render whose defaults are `FAST`
    (updated by ``defaults``), on ``ball.ply`` at 0.3 m unless ``objects`` are given;
    ``grid`` (``{"group.name": [values]}``) is a grid sweep, ``sweep`` any sweep. Returns its path.
    """

    def write(sweep: dict | None = None, *, grid: dict | None = None, objects: list | None = None, name: str = "t",
              seed: int = 1, defaults: dict | None = None, **extra) -> Path:
        data = {"name": name, "seed": seed, "render": None, "defaults": {**FAST, **(defaults or {})},
                "objects": objects or [{"id": "ball", "mesh": ball.name, "size_m": 0.3}], **extra}
        if grid:
            sweep = {"method": "grid", "parameters": {k: {"values": v} for k, v in grid.items()}}
        if sweep:
            data["sweep"] = sweep
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        return path

    return write


def _wait_for(predicate, what: str, timeout: float = 120.0):
    """Poll ``predicate`` until it returns something true (a generous deadline, not a timing)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


@pytest.fixture(scope="session")
def wait_for():
    """``wait_for(predicate, what, timeout=120)``: ``predicate()``'s first true value, or a failure naming ``what``."""
    return _wait_for
