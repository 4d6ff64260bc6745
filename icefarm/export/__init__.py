"""Export and re-render: what a job rendered, read back from its scene spec, written for other tools.

`rendered` (`read_rendered`: the job's cameras, sun, sky, ground and surfaces from its
``scene.json``, or from the ``scene.xml`` of a job from before it through `icefarm.scene.legacy`),
`usd` (``scene.usda`` and USDZ), `gltf` (GLB), `growth_usd` (the growth's time-sampled USD) and
`rerender` (`render_again`, ``icefarm render``: a finished job's scene written and rendered anew).
"""
