"""The icefarm command the add-on runs: where it is, its ``icefarm run`` command line for one
object's job, and the one-line message of a job that failed.

Only ``bpy.path`` of Blender here: the rest is the standard library.
"""

import os
import shlex
import shutil
from dataclasses import dataclass
from pathlib import Path

import bpy

ENVIRONMENT_VARIABLE = "ICEFARM"
STORM_INTENSITIES = ("light", "moderate", "severe")
STORM_KINDS = ("freezing_rain", "meltwater")
PLACEMENTS = ("ground", "hanging")


class GrowError(Exception):
    """What the operator reports as its one ERROR line: bad input, or a job that failed."""


def find_executable(preference=""):
    """The icefarm command to run: ``preference`` (the add-on's preference), else the
    ``ICEFARM`` environment variable, else ``icefarm`` on the PATH, else a ``.venv``
    beside the repository holding this add-on; None when there is none."""
    for named in (preference, os.environ.get(ENVIRONMENT_VARIABLE, "")):
        if named:
            return bpy.path.abspath(named) if named.startswith("//") else named
    found = shutil.which("icefarm")
    if found:
        return found
    repo = Path(__file__).resolve().parents[3]  # icefarm/dcc/blender_addon/command.py
    for candidate in (repo / ".venv" / "bin" / "icefarm", repo / ".venv" / "Scripts" / "icefarm.exe"):
        if candidate.is_file():
            return str(candidate)
    return None


def setting_assignments(text):
    """The panel's extra settings, ``storm.max_icicles=8 surface.voxel_size=0.003`` (as
    ``--set`` takes them, separated by spaces), as a list of ``GROUP.PARAM=VALUE``."""
    try:
        words = shlex.split(text or "")
    except ValueError as exc:
        raise GrowError(f"icefarm settings {text!r}: {exc}") from None
    for word in words:
        if "=" not in word or "." not in word.partition("=")[0]:
            raise GrowError(f"icefarm setting {word!r}: expected GROUP.PARAM=VALUE (icefarm params lists them)")
    return words


@dataclass(frozen=True)
class JobOptions:
    """What the panel asks of every job: the storm, the seed, the placement, more settings
    and the render.

    Attributes
    ----------
    intensity, kind : str
        ``storm.intensity`` (`STORM_INTENSITIES`) and ``storm.kind`` (`STORM_KINDS`).
    seed : int
    placement : {"ground", "hanging"}
    settings : tuple of str
        More ``GROUP.PARAM=VALUE`` for ``--set``; they come last and win.
    render : str or None
        A render config (``preview``, ``lookdev``, ``final`` or a YAML path); None: no render.
    """

    intensity: str
    kind: str
    seed: int
    placement: str
    settings: tuple = ()
    render: str | None = None


def job_options(settings):
    """The `JobOptions` of the panel's ``settings`` (``scene.icefarm``); raises `GrowError`
    for extra settings that are not ``GROUP.PARAM=VALUE``."""
    return JobOptions(intensity=settings.intensity, kind=settings.kind, seed=settings.seed,
                      placement=settings.placement, settings=tuple(setting_assignments(settings.settings)),
                      render=settings.render_config if settings.render else None)


def job_command(executable, mesh, out, size_m, options):
    """The ``icefarm run`` command line of one job (a list for `subprocess.Popen`).

    Parameters
    ----------
    executable, mesh, out : str
        The icefarm command, the exported object, the job folder.
    size_m : float
        The object's real height in meters (``--size-m``).
    options : JobOptions
        The storm, seed, placement, more settings and render the panel asks for.
    """
    command = [str(executable), "run", str(mesh), "-o", str(out), "--size-m", repr(float(size_m)),
               "--seed", str(int(options.seed)), "--placement", options.placement,
               "--set", f"storm.intensity={options.intensity}", "--set", f"storm.kind={options.kind}"]
    for assignment in options.settings:
        command += ["--set", assignment]
    command += ["--render", options.render] if options.render else ["--no-render"]
    return command


def job_error(stderr, returncode):
    """The failed job's one-line message: the last ``error:`` line icefarm wrote to stderr,
    else its last line, else its exit status."""
    lines = [line.strip() for line in stderr.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("error:")]
    if errors:
        return "icefarm " + errors[-1]
    if lines:
        return f"icefarm failed (exit status {returncode}): {lines[-1]}"
    return f"icefarm failed with exit status {returncode} and no message"
