"""Export and re-render: what a job rendered, read back from its scene spec, written for other tools.

Every exporter reads the job's `icefarm.scene.SceneSpec` (`icefarm.scene.read_scene_spec`: its
``scene.json``, or the ``scene.xml`` of a job from before it) and the job's meshes: `looks`
(the spec's materials and sun as PBR values and lights, pure functions), `meshes` (``object.ply``
and ``ice.ply`` with their normals, the water per vertex), `usd` (``scene.usda`` and USDZ),
`ice_layer` (``ice_layer.usda``: the ice over a USD input's own file), `gltf` (GLB),
`growth_usd` (the growth's time-sampled USD) and `rerender` (`render_again`, ``icefarm render``:
a finished job's scene written and rendered anew).

The package's face: the names the rest of icefarm imports from it, listed in `__all__` and
loaded on first use (`lazy_loader`, as scikit-image does), so that importing one module of
the package imports no other.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach(__name__, submod_attrs={
    "gltf": ["write_glb"],
    "growth_usd": ["write_growth_usd"],
    "ice_layer": ["IceLayer", "write_ice_layer"],
    "rerender": ["RENDER_FILES", "estimate_seconds", "meshed_coarser", "render_again"],
    "usd": ["UsdInputs", "read_usd_inputs", "write_job_usd", "write_usd", "write_usdz"],
})
