"""Scenes and rendering: Mitsuba 3 XML and POV-Ray files for a job, and their renders.

Importing this package imports neither mitsuba nor drjit: `variants.pick_variant` (or
`variants.prepare_llvm`) must run before they are, to choose Dr.Jit's libLLVM.
"""

from .config import RenderConfig, load_render_config, render_config_to_dict
from .material import material_from_dict
from .render import RenderResult, render_job
from .variants import pick_variant, prepare_llvm
from .write import SceneFiles, write_scenes

__all__ = ["RenderConfig", "RenderResult", "SceneFiles", "load_render_config", "material_from_dict",
           "pick_variant", "prepare_llvm", "render_config_to_dict", "render_job", "write_scenes"]
