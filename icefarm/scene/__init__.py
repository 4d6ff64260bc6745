"""Scenes and rendering: a job's scene spec (``scene.json``), the Mitsuba 3 XML and POV-Ray files
written from it, and their renders.

Importing this package imports neither mitsuba nor drjit: `variants.pick_variant` (or
`variants.prepare_llvm`) must run before they are, to choose Dr.Jit's libLLVM.
"""

from .camera import Camera, world_frame
from .config import IceLook, RenderConfig, ice_at_impurity, ice_medium, load_render_config, render_config_to_dict
from .geometry import smooth_normals, winds_inward
from .images import image_size
from .legacy import spec_from_xml
from .material import Material, material_from_dict
from .render import RenderResult, render_job
from .spec import Ground, SceneSpec, Sun, read_spec
from .variants import pick_variant, prepare_llvm, set_thread_count
from .write import JobScene, SceneFiles, build_spec, job_scene, read_scene_spec, write_scenes

__all__ = ["Camera", "Ground", "IceLook", "JobScene", "Material", "RenderConfig", "RenderResult", "SceneFiles",
           "SceneSpec", "Sun", "build_spec", "ice_at_impurity", "ice_medium", "image_size", "job_scene",
           "load_render_config", "material_from_dict", "pick_variant", "prepare_llvm", "read_scene_spec", "read_spec",
           "render_config_to_dict", "render_job", "set_thread_count", "smooth_normals", "spec_from_xml",
           "winds_inward", "world_frame", "write_scenes"]
