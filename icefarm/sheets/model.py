"""What a contact sheet is made of: the layout constants, the colours, the records of a run and its jobs, the grid."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from pathlib import Path

from ..jobdir import SHEETS_DIR, VIEWS, JobFolder, JobState, read_views

__all__ = ["JobState", "SHEETS_DIR"]  # a job's state and the sheets' folder are the job folder's (icefarm.jobdir)

# Layout, in pixels.
MARGIN = 16
GAP = 8
HEADER_H = 124
LABEL_H = 40
ROW_HEAD_W = 120
COL_HEAD_H = 28
MIN_WIDTH = 640
DEFAULT_ASPECT = 0.75  # cell height / width when no render can be read
WRAP_AFTER = 8  # a one-parameter sweep longer than this wraps into a grid
ICE_VIEW_BELOW_PX = 4.0  # icicles narrower than this in a cell: show the job's ice view there
VIEWS_FILE = VIEWS  # written beside the renders (`icefarm.jobdir.write_views`)
# fit's filter: no negative lobes (no ringing around highlights, no negative linear values)
# and 4x faster than its default lanczos3 (40 ms against 170 ms for 320x240 into 160x120).
FIT_FILTER = "blackman-harris"

FONT = "DroidSans"
FONT_BOLD = "DroidSans-Bold"
TITLE_SIZE = 22
TEXT_SIZE = 14
LABEL_SIZE = 13

# Colours as the sRGB display values they should show (converted to linear before drawing).
BACKGROUND_SRGB = (0.12, 0.12, 0.13)
TEXT_SRGB = (0.92, 0.92, 0.92)
DIM_TEXT_SRGB = (0.62, 0.62, 0.64)
FAILED_SRGB = (0.50, 0.10, 0.10)
UNFINISHED_SRGB = (0.30, 0.30, 0.34)
EMPTY_SRGB = (0.18, 0.18, 0.19)



class Arrangement(enum.Enum):
    """How the cells of a sheet are laid out."""

    ROWS_COLUMNS = "rows x columns"  # two varying parameters
    ROW = "row"  # one varying parameter (wrapped into a grid when long)
    JOB_ORDER = "grid in job order"  # none, three or more, random or zip sweeps


@dataclass(frozen=True)
class SheetResult:
    """One object's contact sheet.

    Attributes
    ----------
    object_id : str
    png, exr : Path
        ``RUN_DIR/sheets/<object>.png`` (sRGB) and ``.exr`` (linear).
    rows, cols : int
        Grid size in cells.
    cells : int
        Jobs placed on the sheet (empty grid slots not counted).
    failed : int
        Jobs shown as failed (error.json).
    """

    object_id: str
    png: Path
    exr: Path
    rows: int
    cols: int
    cells: int
    failed: int


@dataclass(frozen=True)
class JobInfo:
    """One job of the sweep folder, as read from disk.

    Attributes
    ----------
    path : Path or None
        The job folder; None for a job listed in jobs.csv whose folder does not exist.
    values : dict
        Flat ``{"group.name": value}``: the full parameters (params.yaml), or only the
        swept values of jobs.csv when params.yaml is missing.
    has_params : bool
        ``values`` came from params.yaml.
    folder : JobFolder or None
        What the job folder holds (`icefarm.jobdir.read_job`); None without a folder.
    """

    object_id: str
    job_id: str
    path: Path | None
    state: JobState
    values: dict
    has_params: bool
    folder: JobFolder | None = None

    def file(self, name: str) -> Path | None:
        """``path / name`` if that file exists."""
        if self.path is None or not (self.path / name).is_file():
            return None
        return self.path / name

    def views(self) -> list[dict]:
        """The job's ``views.json`` (one entry per rendered view, `icefarm.jobdir.read_views`), or []
        without a usable one."""
        return [] if self.path is None else read_views(self.path)

    @property
    def seconds(self) -> float | None:
        """The job's total time (`icefarm.jobdir.JobFolder.total_seconds`); None without a folder."""
        return self.folder.total_seconds if self.folder is not None else None


@dataclass(frozen=True)
class RunInfo:
    """A sweep folder: its name, method, swept keys and jobs per object (in job order)."""

    run_dir: Path
    name: str
    method: str | None
    swept: tuple[str, ...]
    objects: dict[str, list[JobInfo]]


@dataclass(frozen=True)
class Grid:
    """Where each job goes on a sheet.

    Attributes
    ----------
    slots : list
        ``(row, col, job)`` for every placed job.
    row_key, col_key : str or None
        The two parameters of a rows x columns grid.
    row_values, col_values : list
        Their values, sorted, one per row / column.
    """

    arrangement: Arrangement
    rows: int
    cols: int
    varying: tuple[str, ...]
    slots: list
    row_key: str | None = None
    col_key: str | None = None
    row_values: tuple = ()
    col_values: tuple = ()
