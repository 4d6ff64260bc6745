"""POV-Ray 3.7 scene description (``scene.pov`` + mesh includes) of one job.

POV-Ray is left-handed: every point and vector is written with its Z negated, which
mirrors the world into POV's convention so the picture matches Mitsuba's. The meshes go
to ``object.inc`` / ``ice.inc`` as ``mesh2`` with normals so ``scene.pov`` stays short and
editable. All views are in ``scene.pov``; ``Declare=View=i`` picks one (0 by default).
"""

from __future__ import annotations

import shutil
import subprocess
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..errors import InputError
from .camera import Camera
from .camera import direction as direction_of
from .config import RenderConfig
from .mitsuba import Ground

FLIP = np.array([1.0, 1.0, -1.0])  # right-handed world -> POV's left-handed one
METAL_COLOURS = {"Al": (0.91, 0.92, 0.92), "Ag": (0.97, 0.96, 0.91), "Au": (1.0, 0.78, 0.34),
                 "Cu": (0.95, 0.64, 0.54), "Cr": (0.55, 0.56, 0.55)}


def _v(v) -> str:
    x, y, z = np.asarray(v, dtype=np.float64) * FLIP
    return f"<{x:.9g}, {y:.9g}, {z:.9g}>"


def _rgb(v) -> str:
    return "rgb <" + ", ".join(f"{float(x):.6g}" for x in v) + ">"


def vector_lines(rows: np.ndarray, decimals: int) -> np.ndarray:
    """ASCII ``<x,y,z>,`` lines for ``rows`` ``(n, 3)`` in fixed point with ``decimals`` digits.

    Digits are built with array arithmetic into a byte buffer (numbers right-aligned,
    space-padded), ten times faster than Python formatting on million-face ice. Returns
    the text as a flat ``uint8`` array, which file objects write without a copy.
    """
    rows = np.asarray(rows, dtype=np.float64).reshape(-1, 3)
    scaled = np.rint(np.abs(rows) * 10.0 ** decimals).astype(np.int64)
    negative = (rows < 0) & (scaled > 0)
    top = int(scaled.max()) if scaled.size else 0
    digits = max(len(str(top)), decimals + 1)  # at least one digit before the point
    point = 1 if decimals else 0
    width = digits + point + 1  # + sign
    buf = np.full(rows.shape + (width,), ord(" "), dtype=np.uint8)
    # Columns used by digits and point: the units digit and the decimals always show.
    shown = np.full(rows.shape, decimals + 1 + point, dtype=np.int8)
    rest = scaled.astype(np.int32 if top < 2 ** 31 else np.int64)
    for k in range(digits):  # k-th digit from the right
        column = width - 1 - k - (point if k >= decimals else 0)
        if k <= decimals:
            rest, digit = np.divmod(rest, 10)
            buf[..., column] = digit.astype(np.uint8) + ord("0")
        else:
            visible = rest > 0
            rest, digit = np.divmod(rest, 10)
            buf[..., column] = np.where(visible, digit.astype(np.uint8) + ord("0"), ord(" "))
            shown += visible
    if point:
        buf[..., width - 1 - decimals] = ord(".")
    sign_column = width - 1 - shown
    r, c = np.nonzero(negative)
    buf[r, c, sign_column[r, c]] = ord("-")
    line = np.empty((len(rows), 3 * width + 6), dtype=np.uint8)
    line[:, 0] = ord("<")
    for i in range(3):
        start = 1 + i * (width + 1)
        line[:, start:start + width] = buf[:, i]
        line[:, start + width] = ord(",") if i < 2 else ord(">")
    line[:, -2:] = (ord(","), ord("\n"))
    return line.reshape(-1)


def write_mesh2(path: str | Path, name: str, vertices: np.ndarray, normals: np.ndarray,
                faces: np.ndarray, inside: bool = False) -> None:
    """Write ``#declare name = mesh2 {...}`` for ``vertices``/``normals`` ``(n, 3)``, ``faces`` ``(m, 3)``.

    Coordinates are written in POV's left-handed frame (Z negated), to a micrometre.
    ``inside`` marks a closed mesh, which POV-Ray then treats as a solid with an interior.
    """
    blocks = (("vertex_vectors", np.asarray(vertices, dtype=np.float64) * FLIP, 6),
              ("normal_vectors", np.asarray(normals, dtype=np.float64) * FLIP, 4),
              ("face_indices", np.asarray(faces), 0))
    with open(path, "wb") as f:
        f.write(f"#declare {name} = mesh2 {{\n".encode())
        for block, rows, decimals in blocks:
            f.write(f"  {block} {{\n    {len(rows)},\n".encode())
            text = memoryview(vector_lines(rows, decimals))
            f.write(text[:-2] if len(text) else text)  # no comma after the last vector
            f.write(b"\n  }\n")
        if inside:
            f.write(b"  inside_vector <0.267, 0.534, 0.801>\n")
        f.write(b"}\n")


def _finish_object(material: dict) -> str:
    kind, rough = material["type"], material["roughness"]
    if kind == "diffuse":
        return (f"texture {{ pigment {{ color {_rgb(material['color'])} }} "
                "finish { ambient 0.02 diffuse 1.0 } }")
    if kind == "plastic":
        return (f"texture {{ pigment {{ color {_rgb(material['color'])} }} "
                f"finish {{ ambient 0.02 diffuse 0.75 specular 0.6 roughness {max(rough, 0.001) ** 2:.6g} "
                "reflection { 0.02, 0.2 fresnel on } conserve_energy } }")
    colour = METAL_COLOURS[material["metal"]]
    return (f"texture {{ pigment {{ color {_rgb(colour)} }} "
            f"finish {{ ambient 0.05 diffuse 0.15 metallic specular 0.8 roughness {max(rough, 0.001) ** 2:.6g} "
            "reflection { 0.75 metallic } } }")


def _ice_material(config: RenderConfig) -> str:
    ice = config.ice
    bumps = (f"\n    normal {{ bumps {min(ice.roughness * 2, 1):.4g} scale 0.0015 }}"
             if ice.roughness > 0 else "")
    return f"""material {{
  texture {{
    pigment {{ color rgbf <1, 1, 1, 1> }}
    finish {{ ambient 0 diffuse 0 specular 0.8 roughness 0.0008
             reflection {{ 0.0, 1.0 fresnel on }} conserve_energy }}{bumps}
  }}
  interior {{ ior {ice.ior:.6g} fade_distance 0.25 fade_power 1001 fade_color {_rgb(ice.tint)} }}
}}"""


def scene_pov(config: RenderConfig, cameras: Sequence[Camera], frame: np.ndarray, *,
              object_inc: str, ice_inc: str | None, sky_file: str, sun_dir: np.ndarray,
              ground: Ground | None, material: dict) -> str:
    """The text of ``scene.pov`` (POV-Ray 3.7); arguments as in `mitsuba.scene_xml`."""
    env = config.environment
    gain = 2.0 ** env.exposure
    aspect = config.width / config.height
    right, up, front = frame
    out = ["// icefarm scene for POV-Ray 3.7; render from this folder with\n",
           f"// povray +Iscene.pov +Orender_povray.png +W{config.width} +H{config.height} +A0.3 -D -V\n",
           "#version 3.7;\n",
           f"global_settings {{ assumed_gamma 1.0 max_trace_level {max(config.max_depth, 5)} "
           "ambient_light rgb 1 }\n",
           "#ifndef (View) #declare View = 0; #end\n",
           "#switch (View)\n"]
    for i, cam in enumerate(cameras):
        out.append(f"#case ({i})\n  camera {{ perspective location {_v(cam.origin)} "
                   f"right x*{aspect:.9g} up y sky {_v(cam.up)} angle {cam.fov_x:.9g} "
                   f"look_at {_v(cam.target)} }}\n  #break\n")
    out.append("#end\n\n")

    # POV's spherical map puts the image's top at +Y and its u = 0 column at +X, turning
    # towards +Z; Mitsuba's envmap (the same image) has u = 0 at -front turning towards
    # right. The pattern is evaluated at (-front, up, right) components of the direction.
    m = np.column_stack([-front * FLIP, up * FLIP, right * FLIP])
    mat = ", ".join(f"{x:.9g}" for x in m.T.ravel()) + ", 0, 0, 0"
    kind = "hdr" if sky_file.lower().endswith(".hdr") else "exr"
    out.append(f"sky_sphere {{\n  pigment {{ image_map {{ {kind} \"{sky_file}\" map_type 1 "
               f"interpolate 2 }} }}\n  matrix <{mat}>\n"
               f"  emission rgb {env.sky_strength * gain:.6g}\n}}\n\n")

    # POV's diffuse term is pigment * light * cos, Mitsuba's albedo / pi * irradiance:
    # lights are divided by pi so both pictures get the same exposure.
    if env.sun_strength > 0:
        sun = np.array([1.0, 0.93, 0.84]) * env.sun_strength * gain / np.pi
        out.append(f"light_source {{ {_v(np.asarray(sun_dir) * 1e4)} color {_rgb(sun)} "
                   "parallel point_at <0, 0, 0> }\n")
    # Without radiosity the sky lights nothing: six shadowless lights around at 30 degrees
    # and one overhead stand in for it (about 1 W/m^2 on a level surface, like the sky map).
    sky_rgb = np.array([0.85, 0.95, 1.3]) * env.sky_strength * gain / np.pi
    for k in range(6):
        d = direction_of(frame, 60.0 * k + 15.0, 30.0)
        out.append(f"light_source {{ {_v(d * 1e4)} color {_rgb(0.32 * sky_rgb)} parallel "
                   "point_at <0, 0, 0> shadowless }\n")
    out.append(f"light_source {{ {_v(up * 1e4)} color {_rgb(0.05 * sky_rgb)} parallel "
               "point_at <0, 0, 0> shadowless }\n")
    if ground is not None:  # light bounced off the ground onto faces that look down
        level = env.sun_strength * max(np.sin(np.radians(env.sun_elevation)), 0.0) + env.sky_strength
        bounce = np.full(3, 0.36 * level * gain / np.pi)
        out.append(f"light_source {{ {_v(-up * 1e4)} color {_rgb(bounce)} parallel "
                   "point_at <0, 0, 0> shadowless }\n")
    out.append("\n")

    out.append(f"#include \"{object_inc}\"\n")
    out.append(f"object {{ Object_Mesh\n  {_finish_object(material)}\n}}\n\n")
    if ice_inc is not None:
        out.append(f"#include \"{ice_inc}\"\n")
        out.append(f"object {{ Ice_Mesh\n  {_ice_material(config)}\n}}\n\n")

    if ground is not None:
        h = ground.half_size
        corners = [ground.centre + h * (a * front + b * right) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        g = np.eye(4)
        g[:3, 0], g[:3, 1], g[:3, 2] = front * FLIP, up * FLIP, right * FLIP
        g[:3, 3] = ground.centre * FLIP
        gm = ", ".join(f"{x:.9g}" for x in np.concatenate([g[:3, :3].T.ravel(), g[:3, 3]]))
        if env.ground == "checker":
            pigment = (f"checker color rgb <0.3, 0.3, 0.31> color rgb <0.42, 0.42, 0.43> "
                       f"translate <0, 0.5, 0> scale {ground.cell:.9g} matrix <{gm}>")
        else:
            pigment = "color rgb <0.36, 0.36, 0.37>"
        out.append(f"polygon {{ 5, {', '.join(_v(c) for c in corners)}, {_v(corners[0])}\n"
                   f"  texture {{ pigment {{ {pigment} }} finish {{ ambient 0.02 diffuse 1.0 }} }}\n}}\n")
    return "".join(out)


def povray_command(config: RenderConfig, view: int, output: str) -> list[str]:
    """The command line that renders view ``view`` of ``scene.pov`` into ``output``."""
    return ["povray", "+Iscene.pov", f"+O{output}", f"+W{config.width}", f"+H{config.height}",
            "+A0.3", "+R3", "+FN", "-D", "-V", "-GA", f"Declare=View={view}"]


def require_povray() -> str:
    """Path of the ``povray`` command, or `InputError` saying how to get it."""
    exe = shutil.which("povray")
    if exe is None:
        raise InputError("the render config asks for POV-Ray (renderer: povray or both) but the "
                         "`povray` command is not installed: install it (apt-get install povray) "
                         "or set renderer: mitsuba")
    return exe


def render_povray(job_dir: Path, config: RenderConfig, view: int = 0,
                  output: str = "render_povray.png") -> float:
    """Render view ``view`` of ``job_dir/scene.pov`` with the povray command; seconds taken.

    Raises
    ------
    InputError
        POV-Ray is not installed.
    RuntimeError
        POV-Ray failed; the message holds the end of its output.
    """
    require_povray()
    start = time.perf_counter()
    proc = subprocess.run(povray_command(config, view, output), cwd=job_dir,
                          capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if proc.returncode != 0 or not (Path(job_dir) / output).is_file():
        tail = (proc.stderr or proc.stdout)[-2000:]
        raise RuntimeError(f"povray failed on {Path(job_dir) / 'scene.pov'} (exit {proc.returncode}):\n{tail}")
    return seconds
