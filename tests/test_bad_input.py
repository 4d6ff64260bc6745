"""Bad input a pipeline TD feeds a farm: unwritable or odd output folders, bad scheduler
addresses, huge or malformed manifests, flat meshes and meshes in tiny units. Each gets one
clear line (or simply works), never a traceback, a hang or a half-made sweep folder."""

import os
import resource
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
import yaml
from click.testing import CliRunner

from icefarm import params
from icefarm.cli import main
from icefarm.job.pipeline import JobSpec, Stage, run_job
from icefarm.mesh import prepare

ICEFARM = Path(sys.executable).parent / "icefarm"
MEMORY = 4 << 30  # address space of a command that must not expand a huge sweep


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def one_error_line(result, *words) -> str:
    """The command failed with exactly one ``error:`` line naming ``words``, and no traceback."""
    assert result.exit_code not in (0, 1), result.output  # 2: bad input, not a failed job
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), result.stderr
    assert "Traceback" not in result.output and len(lines[0]) < 800, lines[0][:2000]
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


def unprivileged(command: list[str]) -> list[str]:
    """``command`` without root's power to write anywhere (as a user would run it)."""
    if os.geteuid() != 0:
        return command
    if shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv: a read-only folder cannot be tested")
    return ["setpriv", "--bounding-set=-dac_override,-dac_read_search,-fowner", "--", *command]


# --------------------------------------------------------------------------- output folders

@pytest.mark.slow  # starts a process
@pytest.mark.parametrize("command", ["sweep", "run"])
def test_an_unwritable_output_folder_is_one_line(tmp_path, ball, command, write_manifest):
    path = write_manifest()
    readonly = tmp_path / "readonly"
    readonly.mkdir()
    readonly.chmod(0o555)
    try:
        args = ([str(ICEFARM), "sweep", str(path), "-o", str(readonly / "out"), "--until", "water"]
                if command == "sweep" else
                [str(ICEFARM), "run", str(ball), "--size-m", "0.3", "-o", str(readonly / "job"), "--no-render"])
        proc = subprocess.run(unprivileged(args), capture_output=True, text=True, timeout=300)
    finally:
        readonly.chmod(0o755)
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and lines[0].startswith("error: cannot write the output folder"), proc.stderr
    assert "Permission denied" in lines[0]
    assert not any(readonly.iterdir())


@pytest.mark.slow  # starts processes (a sweep's pool)
def test_overwrite_of_a_symlinked_sweep_folder_is_refused_in_one_line(tmp_path, write_manifest):
    path = write_manifest()
    out = tmp_path / "out"
    assert cli("sweep", path, "-o", out, "--until", "water", "--workers", "1").exit_code == 0
    (tmp_path / "elsewhere").mkdir()
    (out / "t").rename(tmp_path / "elsewhere" / "t")
    (out / "t").symlink_to(tmp_path / "elsewhere" / "t")
    one_error_line(cli("sweep", path, "-o", out, "--until", "water", "--overwrite"), "symbolic link")
    assert (tmp_path / "elsewhere" / "t" / "jobs.csv").is_file() and (out / "t").is_symlink()


def test_a_bad_scheduler_address_is_one_line_and_makes_nothing(tmp_path, write_manifest):
    pytest.importorskip("distributed")
    path = write_manifest()
    out = tmp_path / "out"
    one_error_line(cli("sweep", path, "-o", out, "--backend", "dask", "--scheduler", "notanaddress"),
                   "notanaddress", "tcp://HOST:PORT")
    assert not out.exists()


@pytest.mark.slow  # dials a dask cluster: waits out two connection timeouts
def test_an_unreachable_scheduler_is_one_line_and_leaves_nothing_behind(tmp_path, write_manifest):
    pytest.importorskip("distributed")
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    path = write_manifest()
    out = tmp_path / "out"
    for _ in range(2):  # a plain rerun is not blocked by anything the first left
        one_error_line(cli("sweep", path, "-o", out, "--backend", "dask", "--scheduler",
                           f"tcp://127.0.0.1:{port}", "--scheduler-timeout", "1"), "cannot reach")
        assert not (out / "t").exists()


# --------------------------------------------------------------------------- manifests

@pytest.mark.slow  # starts processes
def test_jobs_are_counted_before_a_sweep_is_expanded(tmp_path, write_manifest):
    huge = {"method": "grid", "parameters": {key: {"values": values} for key, values in (
        ("water.rays", list(range(100, 200))), ("drips.count", list(range(1, 101))),
        ("trajectories.curve_angle", list(range(0, 100))), ("surface.noise", [i * 1e-5 for i in range(100)]),
        ("surface.ripple_amplitude", [i * 1e-5 for i in range(100)]))}}  # 10^10 jobs
    path = write_manifest(huge)
    random = write_manifest({"method": "random", "count": 10**9,
                             "parameters": {"drips.count": {"min": 1, "max": 50}}}, name="r")
    for args, words in ((["validate", path], ("10,000,000,000 jobs", "--max-jobs")),
                        (["sweep", path, "-o", tmp_path / "out", "--dry-run"], ("10,000,000,000 jobs",)),
                        (["sweep", random, "-o", tmp_path / "out"], ("1,000,000,000 jobs",))):
        # In a process of its own with little memory: expanding such a sweep would take it all.
        proc = subprocess.run([str(ICEFARM), *map(str, args)], capture_output=True, text=True, timeout=300,
                              preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_AS, (MEMORY, MEMORY)))
        lines = [line for line in proc.stderr.splitlines() if line.strip()]
        assert proc.returncode == 2 and len(lines) == 1 and lines[0].startswith("error:"), proc.stderr[-2000:]
        assert all(word in lines[0] for word in words), lines[0]
    small = write_manifest({"method": "grid", "parameters": {"drips.count": {"values": [2, 3, 4]}}}, name="s")
    one_error_line(cli("validate", small, "--max-jobs", "2"), "3 jobs")
    assert cli("validate", small, "--max-jobs", "3").exit_code == 0
    assert not (tmp_path / "out").exists()


def alias_bomb(levels: int = 6, width: int = 10) -> str:
    """Anchors a0 .. a5 under keys of their own: ``*a5`` expands to 10^6 items."""
    lines = ["x0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    for i in range(1, levels):
        lines.append(f"x{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * width) + "]")
    return "\n".join(lines)


@pytest.mark.parametrize("where", ["name", "seed", "drips.count", "exclude", "values"])
def test_a_yaml_alias_bomb_gets_a_short_message(tmp_path, ball, where):
    bomb = f"*a{5}"  # 10^6 items once expanded
    body = {"name": f"name: {bomb}\nobjects: [{{id: ball, mesh: ball.ply, size_m: 0.3}}]",
            "seed": f"seed: {bomb}\nobjects: [{{id: ball, mesh: ball.ply, size_m: 0.3}}]",
            "drips.count": f"defaults: {{drips: {{count: {bomb}}}}}\n"
                           f"objects: [{{id: ball, mesh: ball.ply, size_m: 0.3}}]",
            "exclude": f"objects: [{{id: ball, mesh: ball.ply, size_m: 0.3, exclude: [{bomb}, {bomb}]}}]",
            "values": f"objects: [{{id: ball, mesh: ball.ply, size_m: 0.3}}]\n"
                      f"sweep: {{method: grid, parameters: {{drips.count: {{values: {bomb}}}}}}}"}[where]
    path = tmp_path / "bomb.yaml"
    path.write_text(f"{alias_bomb()}\n{body}\n")  # x0 .. x5: unknown keys, also reported
    result = cli("validate", path)
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert len(result.output) < 5000, result.output[:300]


def test_a_manifest_that_is_not_utf8_is_one_line(tmp_path, write_manifest):
    path = write_manifest()
    path.write_bytes(path.read_bytes().replace(b"name: t", b"name: t\n# caf\xe9 (latin-1)"))
    one_error_line(cli("validate", path), "not UTF-8", "line 2")
    one_error_line(cli("sweep", path, "-o", tmp_path / "out"), "not UTF-8")


def test_duplicate_yaml_keys_are_refused(tmp_path, ball):
    path = tmp_path / "dup.yaml"
    path.write_text("name: dup\nobjects:\n  - {id: ball, mesh: ball.ply, size_m: 0.3}\n"
                    "defaults:\n  drips:\n    count: 4\n    count: 40\n")
    result = cli("validate", path)
    assert result.exit_code == 2 and "'count' twice" in result.output and "line 6" in result.output
    merged = tmp_path / "merged.yaml"  # keys brought in by a merge may be overridden
    merged.write_text("base: &base {id: ball, mesh: ball.ply, size_m: 0.3}\n"
                      "name: merged\nobjects:\n  - {<<: *base, size_m: 0.5}\n")
    output = cli("validate", merged).output
    assert "base: unknown key" in output and "twice" not in output  # only the anchor's own key is refused


def test_a_missing_water_source_is_caught_by_validate(tmp_path, write_manifest):
    path = write_manifest(defaults={"water": {"rays": 300, "source": "rain.ply"}})
    one_line = cli("validate", path)
    assert one_line.exit_code == 2 and "water.source 'rain.ply'" in one_line.output
    assert str(tmp_path / "rain.ply") in one_line.output
    trimesh.creation.box().export(tmp_path / "rain.ply")
    assert cli("validate", path).exit_code == 0
    bad_set = cli("validate", path, "--set", "water.source=nowhere.ply")
    assert bad_set.exit_code == 2 and "nowhere.ply" in bad_set.output


# --------------------------------------------------------------------------- meshes

def tilted(mesh: trimesh.Trimesh, degrees: float = 30) -> trimesh.Trimesh:
    mesh = mesh.copy()
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.radians(degrees), [1, 0, 0]))
    return mesh


def grid_plane(n: int = 24) -> trimesh.Trimesh:
    """A unit square in the XZ plane, n x n quads: fine enough to need no proxy."""
    x, z = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    vertices = np.column_stack([x.ravel(), np.zeros(x.size), z.ravel()])
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()
    faces = np.concatenate([np.column_stack([a, a + 1, a + n + 1]), np.column_stack([a + 1, a + n + 2, a + n + 1])])
    return trimesh.Trimesh(vertices, faces, process=False)


FLAT = {  # the coarse ones need a proxy: about 1 s each (slow), the triangle's is small
    "plane": lambda: tilted(trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]], [[0, 1, 2], [0, 2, 3]])),
    "fine plane": lambda: tilted(grid_plane()),
    "triangle": lambda: tilted(trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 0, 1]], [[0, 1, 2]])),
    "level plane": lambda: trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]], [[0, 1, 2], [0, 2, 3]]),
}


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in ("plane", "level plane") else n
                                  for n in FLAT])
def test_flat_meshes_run_with_the_default_proxy_mode(tmp_path, name):
    path = tmp_path / "flat.ply"
    FLAT[name]().export(path)
    p = params.resolve({"water.rays": 2000, "drips.count": 4, "proxy.face_budget": 5000})  # a coarse flow mesh
    spec = JobSpec("flat", str(path), 0.3, p, seed=2, placement="hanging")
    outcome = run_job(spec, tmp_path / "job", until=Stage.TRAJECTORIES)
    assert outcome.status == "done", outcome.error
    prepared = prepare(path, 0.3)
    assert prepared.problems.watertight  # a thin slab: water runs over it and round its rims
    if name != "level plane":  # water stays on a level plane: nothing to drip
        drips = yaml.safe_load((tmp_path / "job" / "drips.json").read_text())["drip_points"]
        assert drips, "water that runs down a tilted sheet drips off its lower rim"


def test_units_do_not_matter(tmp_path):
    ball = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    ball.export(tmp_path / "ball.ply")
    reference = prepare(tmp_path / "ball.ply", 0.3)
    for factor in (1e-9, 1e-3, 1e6):
        tiny = ball.copy()
        tiny.vertices = tiny.vertices * factor
        path = tmp_path / f"ball{factor:g}.ply"
        tiny.export(path)
        prepared = prepare(path, 0.3)
        assert len(prepared.mesh.faces) == len(reference.mesh.faces)
        assert np.allclose(prepared.mesh.vertices, reference.mesh.vertices, atol=1e-9)
        assert prepared.scale == pytest.approx(reference.scale / factor)
