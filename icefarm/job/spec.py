"""A job asked for by a library call or the command line, its input checked once: `job_spec`
turns a mesh (a file, ``generator:NAME`` or a mesh in memory, `write_input`), a storm by name
or by values, a seed, a placement and exclusion boxes into the `JobSpec` that
`icefarm.job.pipeline.run_job` runs.
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, cast

import numpy as np
import trimesh

from ..errors import InputError
from ..generators import GENERATOR_PREFIX
from ..params import flatten, idle_keys, resolve
from ..placement import PLACEMENTS
from .pipeline import Box, JobSpec

__all__ = ["IN_MEMORY", "MeshInput", "job_spec", "mesh_source", "write_input"]

IN_MEMORY = "mesh"  # object id of a job grown on a mesh in memory

MeshInput = trimesh.Trimesh | str | os.PathLike
"""What `grow` takes as the object: a mesh in memory (meters, +Y up), the path of any file
``icefarm run`` reads (USD, glTF/GLB, OBJ, PLY, STL, OFF, ...) or ``generator:NAME``."""


def job_spec(mesh: str | os.PathLike[str], *, size_m: float | None = None, storm: str | Mapping[str, Any] = "moderate",
             kind: str = "freezing_rain", params: Mapping[str, Any] | None = None, seed: int = 0,
             placement: str = "ground", exclude: Sequence[tuple[Sequence[float], Sequence[float]]] = (),
             render: str | os.PathLike[str] | None = None, warn_stacklevel: int = 2) -> JobSpec:
    """The `icefarm.job.pipeline.JobSpec` of a job on a file or a generator, its input checked
    once, as `grow` checks it: for a caller that runs the job into a folder of its own
    (`icefarm.job.pipeline.run_job`), as ``icefarm run`` does.

    Parameters
    ----------
    mesh : path or str
        A file ``icefarm run`` reads, or ``generator:NAME``.
    size_m, storm, kind, params, seed, placement, exclude
        As `grow` takes them.
    render : str or path, optional
        A render config name or YAML path (checked here, a path made absolute); None: no
        render.
    warn_stacklevel : int
        Where the warnings point (a parameter the storm's mode does not read, an unlikely
        size): 2, the caller.

    Returns
    -------
    JobSpec

    Raises
    ------
    InputError
        As `grow` raises it for its input.
    """
    source, name, _ = mesh_source(mesh)
    if isinstance(mesh, trimesh.Trimesh):
        raise InputError("job_spec takes a file or generator:NAME; grow() takes a mesh in memory")
    size = _checked_size(size_m, warn_stacklevel + 1)
    if size is None:
        from ..asset_io import missing_size

        if why := missing_size(source):
            raise InputError(f"{why}: pass the object's real height in meters with size_m")
    if placement not in PLACEMENTS:
        raise InputError(f"placement {placement!r}: one of {', '.join(PLACEMENTS)}")
    given = {**_storm_values(storm), **flatten(dict(params or {}))}
    from ..asset_io import with_asset_gravity

    resolved = resolve(with_asset_gravity(source, {"storm.kind": kind, **given}))
    # Warned about: what the caller set that the storm's mode does not read (the defaults
    # of ``storm`` and ``kind`` stand for no choice)
    chosen = [key for key in given if not (key == "storm.intensity" and storm == "moderate")]
    chosen += ["storm.kind"] if kind != "freezing_rain" else []
    for line in idle_keys(chosen, resolved.storm.mode):
        warnings.warn(line, UserWarning, stacklevel=warn_stacklevel)
    if render is not None:
        from ..scene.config import load_render_config

        load_render_config(render)  # a bad config fails now, in one line, not after the stages
        if Path(render).expanduser().is_file():
            render = str(Path(render).expanduser().resolve())
    return JobSpec(object_id=name, mesh=source, size_m=size, params=resolved, seed=int(seed),
                   render=None if render is None else str(render), exclude=_boxes(exclude), placement=placement)


def mesh_source(mesh: MeshInput) -> tuple[str, str, trimesh.Trimesh | None]:
    """``(source, name, in memory)``: the path or ``generator:NAME`` a job reads (empty for
    a mesh in memory, written later), its object id, and the mesh in memory if it is one."""
    if isinstance(mesh, trimesh.Trimesh):
        if len(mesh.faces) == 0 or not np.isfinite(mesh.vertices).all():
            raise InputError("the mesh is empty or has non-finite vertices")
        return "", IN_MEMORY, mesh
    if isinstance(mesh, trimesh.Scene):
        raise InputError("a trimesh.Scene: pass one mesh (scene.to_geometry() or scene.dump(concatenate=True))")
    if not isinstance(mesh, (str, os.PathLike)):
        raise InputError(f"mesh must be a trimesh.Trimesh, a path or generator:NAME, not {type(mesh).__name__}")
    text = os.fspath(mesh)
    if isinstance(text, str) and text.startswith(GENERATOR_PREFIX):
        return text, text[len(GENERATOR_PREFIX):], None
    path = Path(text)
    if not path.is_file():
        raise InputError(f"mesh file not found: {text}")
    return str(path.resolve()), path.stem, None


def _checked_size(size_m: float | None, stacklevel: int) -> float | None:
    if size_m is None:
        return None
    try:
        size = float(size_m)
    except (TypeError, ValueError):
        size = math.nan
    if not (math.isfinite(size) and size > 0):
        raise InputError(f"size_m {size_m!r}: the object's real height in meters is a number above 0")
    from ..asset_io import size_hint

    if hint := size_hint(size):
        warnings.warn(hint, UserWarning, stacklevel=stacklevel)
    return size


def _storm_values(storm: str | Mapping[str, Any]) -> dict[str, Any]:
    """``storm`` as flat ``storm.*`` values: a name is ``storm.intensity``."""
    if isinstance(storm, str):
        return {"storm.intensity": storm}
    if not isinstance(storm, Mapping):
        raise InputError(f"storm must be an intensity (light, moderate, severe) or a mapping of storm.* "
                         f"values, not {type(storm).__name__}")
    return {key if str(key).startswith("storm.") else f"storm.{key}": value for key, value in storm.items()}


def write_input(mesh: trimesh.Trimesh, folder: Path) -> Path:
    """A mesh in memory as a GLB in ``folder``: glTF carries meters, so the job keeps its size
    (``size_m`` None) as it would a GLB's."""
    path = folder / f"{IN_MEMORY}.glb"
    plain = trimesh.Trimesh(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces), process=False)
    path.write_bytes(cast(bytes, plain.export(file_type="glb")))  # a GLB exports as bytes
    return path


def _boxes(exclude: Sequence[tuple[Sequence[float], Sequence[float]]]) -> tuple[Box, ...]:
    """``exclude`` as the job's `Box` es, each corner three finite numbers."""
    boxes = []
    for box in exclude:
        try:
            lo, hi = (np.asarray(corner, dtype=np.float64) for corner in box)
        except (TypeError, ValueError):
            lo = hi = np.zeros(0)
        if lo.shape != (3,) or hi.shape != (3,) or not (np.isfinite(lo).all() and np.isfinite(hi).all()):
            raise InputError(f"exclude box {box!r}: two corners of three numbers, meters, lowest first")
        boxes.append(Box(tuple(lo.tolist()), tuple(hi.tolist())))
    return tuple(boxes)
