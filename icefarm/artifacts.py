"""Reading and writing a job's artifacts (the job-folder contract: `icefarm.jobdir`), always atomically."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
import yaml

from .errors import InputError
from .jobdir import DONE, DRIPS, ERROR, ICE_BANDS, LATER, TRAJECTORIES, WATER, file_digest
from .stages.drips import DripResult
from .stages.trajectories import TrajectoryResult


def current_umask() -> int:
    """This process's umask, read without changing it (``os.umask`` can only set it, and a
    set-and-restore would race other threads creating files)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)  # no /proc: set and restore at once
    os.umask(mask)
    return mask


def atomic_write(path: Path, data: bytes | str) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename: never half a file.

    The file gets the mode a plain ``open`` would give it (0666 less the umask), not the
    temporary file's 0600: a shared output folder stays readable to its group.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            os.fchmod(f.fileno(), 0o666 & ~current_umask())
            f.write(data.encode() if isinstance(data, str) else data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


# Files of a job folder that done.json does not list: itself, a failure's report, and
# what `icefarm render` and `icefarm export` add later (renders/, export/).
_UNLISTED = (DONE, ERROR)


def list_artifacts(job_dir: Path) -> dict[str, dict]:
    """``{relative path: {"size": bytes, "sha256": hex}}`` for every file of a finished job,
    for done.json: a later ``--resume`` checks them (`icefarm.jobdir.check_done`)."""
    job_dir = Path(job_dir)
    out = {}
    for path in sorted(job_dir.rglob("*")):
        rel = path.relative_to(job_dir)
        if (not path.is_file() or path.is_symlink() or rel.parts[0] in LATER
                or str(rel) in _UNLISTED or any(part.startswith(".") for part in rel.parts)):
            continue
        out[rel.as_posix()] = {"size": path.stat().st_size, "sha256": file_digest(path)}
    return out


def write_json(path: Path, value: Any) -> None:
    atomic_write(path, json.dumps(value, indent=1, default=_plain) + "\n")


def write_yaml(path: Path, value: Any) -> None:
    atomic_write(path, yaml.safe_dump(value, sort_keys=False))


def _plain(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot write {type(value).__name__} as JSON")


def write_mesh(path: Path, mesh: trimesh.Trimesh) -> None:
    """PLY, with the mesh's ``vertex_attributes`` as extra vertex properties."""
    atomic_write(path, mesh.export(file_type="ply"))


def read_ice_mesh(path: Path):
    """A job's ice.ply as `trimesh.load` reads it, with its ripple bands (`ICE_BANDS`, which
    trimesh leaves in the raw PLY data) back in ``vertex_attributes`` when it has them."""
    mesh = trimesh.load(path, process=False)
    raw = mesh.metadata.get("_ply_raw", {}).get("vertex", {}).get("data")
    if isinstance(mesh, trimesh.Trimesh) and raw is not None and ICE_BANDS in (raw.dtype.names or ()) \
            and len(raw) == len(mesh.vertices):
        mesh.vertex_attributes[ICE_BANDS] = np.asarray(raw[ICE_BANDS], dtype=np.float32)
    return mesh


def water_colors(supply: np.ndarray, water: np.ndarray) -> np.ndarray:
    """``(n, 4) uint8``: the paper's Figures 2-3 in one: supply red, water a blue ramp.

    Dry vertices are white, supply vertices red; wet vertices outside the supply go from
    light to dark blue with their water coefficient.
    """
    colors = np.full((len(water), 4), 255, dtype=np.uint8)
    top = float(water.max()) if len(water) and water.max() > 0 else 1.0
    ramp = np.clip(water / top, 0, 1)[:, None]
    wet = (water > 0) & ~supply
    light, dark = np.array([200, 225, 255]), np.array([10, 40, 160])
    colors[wet, :3] = (light + (dark - light) * ramp[wet]).astype(np.uint8)
    colors[supply, :3] = [220, 30, 30]
    return colors


def write_water_ply(path: Path, mesh: trimesh.Trimesh, supply: np.ndarray, water: np.ndarray) -> None:
    """The flow surface with vertex properties ``supply``, ``water`` and a colour code."""
    out = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    out.visual.vertex_colors = water_colors(supply, water)
    out.vertex_attributes["supply"] = supply.astype(np.uint8)
    out.vertex_attributes["water"] = water.astype(np.float32)
    write_mesh(path, out)


def read_water_ply(path: Path, vertex_count: int) -> tuple[np.ndarray, np.ndarray]:
    """``supply`` and ``water`` from a (possibly hand-painted) water.ply."""
    try:
        loaded = trimesh.load(path, process=False)
        data = loaded.metadata["_ply_raw"]["vertex"]["data"]
        supply, water = np.asarray(data["supply"]).astype(bool), np.asarray(data["water"], dtype=np.float64)
    except Exception as exc:
        raise InputError(f"{path}: not a {WATER} with vertex properties supply and water ({exc})") from None
    if len(water) != vertex_count:
        raise InputError(f"{path}: {len(water)} vertices, but the flow surface has {vertex_count}")
    return supply, water


def drips_to_json(drips: DripResult) -> dict:
    growth = [None] * len(drips.water) if drips.growth is None else drips.growth
    return {
        "drip_points": [
            {"position": p.tolist(), "normal": n.tolist(), "water": float(w), "face": int(f),
             **({} if t is None else {"growth": round(float(t), 6)})}
            for p, n, w, f, t in zip(drips.positions, drips.normals, drips.water, drips.faces, growth)
        ],
        "region_faces": drips.region_faces.tolist(),
    }


def drips_from_json(path: Path) -> DripResult:
    try:
        data = json.loads(Path(path).read_text())
        points = data["drip_points"]
        return DripResult(
            region_faces=np.asarray(data.get("region_faces", []), dtype=np.int64),
            positions=np.asarray([p["position"] for p in points], dtype=np.float64).reshape(-1, 3),
            normals=np.asarray([p["normal"] for p in points], dtype=np.float64).reshape(-1, 3),
            water=np.asarray([p["water"] for p in points], dtype=np.float64),
            faces=np.asarray([p.get("face", -1) for p in points], dtype=np.int64),
            growth=(np.asarray([p["growth"] for p in points], dtype=np.float64)
                    if points and all("growth" in p for p in points) else None),
        )
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{path}: not a {DRIPS} ({exc})") from None


def trajectories_to_json(traj: TrajectoryResult) -> dict:
    icicles: dict[int, dict] = {}
    # Parents are named by their place in their icicle's list of branches. An icicle's
    # branches need not be contiguous in the trajectories (the car's, the 3 m house's, the
    # overflowing fountain's are not), and naming them by the distance from the icicle's
    # first branch wrote parents past the list's end.
    icicle_of = np.asarray(traj.branch_icicle, dtype=np.int64)
    local = np.zeros(traj.n_branches, dtype=np.int64)
    for i in np.unique(icicle_of):
        own = np.flatnonzero(icicle_of == i)
        local[own] = np.arange(len(own))
    cut = traj.cut
    for b in range(traj.n_branches):
        i = int(traj.branch_icicle[b])
        entry = icicles.setdefault(i, {"id": len(icicles), "drip_point": i, "branches": []})
        parent = int(traj.branch_parent[b])
        entry["branches"].append({
            "parent": -1 if parent < 0 else int(local[parent]),
            "points": np.round(traj.branch(b), 6).tolist(),
        })
        if cut[b] > 0:  # the ground stopped it: meters it would have grown on
            entry["branches"][-1]["cut"] = round(float(cut[b]), 6)
        if traj.branch_growth is not None:  # a physical storm's own growth ratio
            entry["branches"][-1]["growth"] = round(float(traj.branch_growth[b]), 6)
    return {"icicles": list(icicles.values())}


def trajectories_from_json(path: Path) -> TrajectoryResult:
    try:
        data = json.loads(Path(path).read_text())
        points, offsets, icicle, parent, cut, growth = [], [0], [], [], [], []
        for entry in data["icicles"]:
            base = len(icicle)
            for branch in entry["branches"]:
                pts = np.asarray(branch["points"], dtype=np.float64).reshape(-1, 3)
                points.append(pts)
                offsets.append(offsets[-1] + len(pts))
                icicle.append(int(entry["drip_point"]))
                parent.append(-1 if branch["parent"] < 0 else base + int(branch["parent"]))
                cut.append(float(branch.get("cut", 0.0)))
                growth.append(branch.get("growth"))
        return TrajectoryResult(
            points=np.concatenate(points) if points else np.zeros((0, 3)),
            branch_offsets=np.asarray(offsets, dtype=np.int64),
            branch_icicle=np.asarray(icicle, dtype=np.int64),
            branch_parent=np.asarray(parent, dtype=np.int64),
            branch_cut=np.asarray(cut, dtype=np.float64) if any(cut) else None,
            branch_growth=np.asarray(growth, dtype=np.float64) if growth and None not in growth else None,
        )
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{path}: not a {TRAJECTORIES} ({exc})") from None


def landing_to_json(landing, heights=None, columns=None) -> dict:
    """landing.json: where the water dripping off the tips lands (`icefarm.stages.landing`),
    with each point's stalagmite height (meters; 0: a mound only) and whether it is a column
    when ``heights`` and ``columns`` (k,) are given."""
    points = []
    for i in range(len(landing.water)):
        entry = {"position": np.round(landing.positions[i], 6).tolist(),
                 "normal": np.round(landing.normals[i], 6).tolist(),
                 "water": round(float(landing.water[i]), 6), "tip": np.round(landing.tips[i], 6).tolist(),
                 "gap": round(float(landing.gaps[i]), 6), "icicle": int(landing.icicles[i]),
                 "on_ground": bool(landing.on_ground[i])}
        if heights is not None:
            entry["stalagmite_height"] = round(float(heights[i]), 6)
            entry["column"] = bool(columns[i])
        points.append(entry)
    return {"landing_points": points, "branch_landing": np.asarray(landing.branch_landing).tolist()}
