"""The Blender add-on (the package `icefarm/dcc/blender_addon/`) as a zip that Blender installs.

Blender installs a legacy add-on from a ``.py`` file or from a zip holding a package; the add-on
is a package of several modules, so it goes as a zip, whose top folder is the package, renamed
``icefarm_blender``: the add-on's module name, kept apart from whatever else sits in the user's
add-on folder. Install it with Edit > Preferences > Add-ons > Install from Disk, or
``bpy.ops.preferences.addon_install(filepath=ZIP)`` then
``bpy.ops.preferences.addon_enable(module="icefarm_blender")``.
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

__all__ = ["ADDON_MODULE", "ADDON_PACKAGE", "addon_files", "write_blender_addon"]

ADDON_MODULE = "icefarm_blender"
ADDON_PACKAGE = Path(__file__).resolve().parent / "blender_addon"


def addon_files() -> list[Path]:
    """The add-on package's modules (``__init__.py`` and its submodules), sorted."""
    return sorted(ADDON_PACKAGE.glob("*.py"))


def write_blender_addon(path: str | os.PathLike[str]) -> Path:
    """Write the add-on as the zip ``path`` (``icefarm_blender/__init__.py`` and the package's
    other modules inside) and return its path; its folder is made when missing."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for source in addon_files():
            archive.writestr(f"{ADDON_MODULE}/{source.name}", source.read_text(encoding="utf-8"))
    return out
