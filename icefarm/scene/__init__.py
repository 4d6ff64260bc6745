"""Scenes and rendering: a job's scene spec (``scene.json``), the Mitsuba 3 XML and POV-Ray files
written from it, and their renders.

Importing this package imports neither mitsuba nor drjit: `variants.pick_variant` (or
`variants.prepare_llvm`) must run before they are, to choose Dr.Jit's libLLVM.
"""

from .camera import Camera, world_frame
from .config import RenderConfig, load_render_config, render_config_to_dict
from .geometry import smooth_normals
from .images import image_size
from .legacy import spec_from_xml
from .material import Material, material_from_dict
from .render import RenderResult, render_job
from .spec import TINT_DISTANCE_M, Ground, IceShading, SceneSpec, read_spec
from .variants import pick_variant, prepare_llvm, set_thread_count
from .write import JobScene, SceneFiles, build_spec, job_scene, write_scenes

__all__ = ["TINT_DISTANCE_M", "Camera", "Ground", "IceShading", "JobScene", "Material", "RenderConfig", "RenderResult",
           "SceneFiles", "SceneSpec", "build_spec", "image_size", "job_scene", "load_render_config",
           "material_from_dict", "pick_variant", "prepare_llvm", "read_spec", "render_config_to_dict", "render_job",
           "set_thread_count", "smooth_normals", "spec_from_xml", "world_frame", "write_scenes"]
