"""Scenes and rendering: a job's scene spec (``scene.json``), the Mitsuba 3 XML and POV-Ray files
written from it, and their renders.

Importing this package imports neither mitsuba nor drjit: `variants.pick_variant` (or
`variants.prepare_llvm`) must run before they are, to choose Dr.Jit's libLLVM.
"""

from .config import RenderConfig, load_render_config, render_config_to_dict
from .material import material_from_dict
from .render import RenderResult, render_job
from .spec import SceneSpec, read_spec
from .variants import pick_variant, prepare_llvm
from .write import JobScene, SceneFiles, build_spec, job_scene, write_scenes

__all__ = ["JobScene", "RenderConfig", "RenderResult", "SceneFiles", "SceneSpec", "build_spec", "job_scene",
           "load_render_config", "material_from_dict", "pick_variant", "prepare_llvm", "read_spec",
           "render_config_to_dict", "render_job", "write_scenes"]
