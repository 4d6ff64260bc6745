"""The Blender add-on (`icefarm/dcc/blender_addon.py`) as a zip that Blender installs.

Blender installs a legacy add-on from a ``.py`` file or from a zip holding a package; the zip
keeps the add-on's module name (``icefarm_blender``) apart from whatever else sits in the
user's add-on folder. Install it with Edit > Preferences > Add-ons > Install from Disk, or
``bpy.ops.preferences.addon_install(filepath=ZIP)`` then
``bpy.ops.preferences.addon_enable(module="icefarm_blender")``.
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

__all__ = ["ADDON_MODULE", "ADDON_SOURCE", "write_blender_addon"]

ADDON_MODULE = "icefarm_blender"
ADDON_SOURCE = Path(__file__).resolve().parent / "blender_addon.py"


def write_blender_addon(path: str | os.PathLike[str]) -> Path:
    """Write the add-on as the zip ``path`` (``icefarm_blender/__init__.py`` inside) and
    return its path; its folder is made when missing."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        archive.writestr(f"{ADDON_MODULE}/__init__.py", ADDON_SOURCE.read_text(encoding="utf-8"))
    return out
