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
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..jobdir import POVRAY_STEM, SCENE_POV
from .camera import direction as direction_of
from .config import GROUND_PLAIN, IceLook, IceMedium, RenderConfig, ice_medium
from .material import Material
from .spec import SceneSpec

FLIP = np.array([1.0, 1.0, -1.0])  # right-handed world -> POV's left-handed one
METAL_COLOURS = {"Al": (0.91, 0.92, 0.92), "Ag": (0.97, 0.96, 0.91), "Au": (1.0, 0.78, 0.34),
                 "Cu": (0.95, 0.64, 0.54), "Cr": (0.55, 0.56, 0.55)}


def _v(v) -> str:
    x, y, z = np.asarray(v, dtype=np.float64) * FLIP
    return f"<{x:.9g}, {y:.9g}, {z:.9g}>"


def _rgb(v) -> str:
    return "rgb <" + ", ".join(f"{float(x):.6g}" for x in v) + ">"


# mesh2 text is assembled from 4-byte words (uint32 views of ASCII) looked up in tables: one
# head word per number (separator, sign, leading digits) and 4-digit body words. Table
# lookups and whole-word stores run about 3x faster than digit-by-digit byte arithmetic.
_BODY_WORDS = np.frombuffer(b"".join(b"%04d" % i for i in range(10_000)), dtype=np.uint32)
_INT_HEADS = np.frombuffer(b"".join(sep + sign + b"%02d" % d for sep in (b"<", b",")
                                    for sign in (b" ", b"-") for d in range(100)), dtype=np.uint32)
_UNIT_HEADS = np.frombuffer(b"".join(sep + sign + b"%d." % d for sep in (b"<", b",")
                                     for sign in (b" ", b"-") for d in range(10)), dtype=np.uint32)
_LINE_END = np.frombuffer(b" >,\n", dtype=np.uint32)[0]
MICROMETRES = 1e6  # mesh2 vertices are written as integer micrometres and scaled back in POV


def vector_lines(rows: np.ndarray, unit: bool = False) -> np.ndarray:
    """ASCII ``<a,b,c >,`` lines for ``rows`` ``(n, 3)``, every number the same width.

    Parameters
    ----------
    rows : (n, 3) array
        Integers (``unit`` False), zero-padded to 2 + 4k digits: ``< 000012,-000340, 000000 >,``; or
        components of unit vectors (``unit`` True, ``|x| < 10``) with four decimals:
        ``< 0.7071,-0.7071, 0.0000 >,``.
    unit : bool

    Returns
    -------
    (k,) uint8
        The text, which file objects write without a copy.
    """
    rows = np.asarray(rows)
    if rows.ndim != 2 or rows.shape[1] != 3:
        raise ValueError(f"rows must be (n, 3), got shape {rows.shape}")
    if unit:
        scaled = np.rint(np.abs(rows.astype(np.float64)) * 1e4).astype(np.int32)
        if scaled.size and scaled.max() >= 100_000:
            raise ValueError("unit vector components must be smaller than 10")
        negative = (rows < 0) & (scaled > 0)  # no "-0.0000"
        heads, span, body_words = _UNIT_HEADS, 10, 1
    else:
        if not np.issubdtype(rows.dtype, np.integer):
            raise ValueError(f"rows must be integers unless unit is set, got {rows.dtype}")
        negative = rows < 0
        scaled = np.abs(rows.astype(np.int64))
        top = int(scaled.max()) if scaled.size else 0
        scaled = scaled.astype(np.int32 if top < 2**31 else np.int64)
        heads, span, body_words = _INT_HEADS, 100, -(-max(len(str(top)) - 2, 0) // 4)
    words = 1 + body_words  # per number
    line = np.empty((len(rows), 3 * words + 1), dtype=np.uint32)
    for i in range(3):
        rest = scaled[:, i]
        for w in range(body_words, 0, -1):
            rest, chunk = np.divmod(rest, 10_000)
            line[:, i * words + w] = _BODY_WORDS.take(chunk)
        head = rest + (2 * span if i else 0)  # rest < span: the head's digits
        head += negative[:, i] * span
        line[:, i * words] = heads.take(head)
    line[:, -1] = _LINE_END
    return line.view(np.uint8).reshape(-1)


def write_mesh2(path: str | Path, name: str, vertices: np.ndarray, normals: np.ndarray,
                faces: np.ndarray, inside: bool = False) -> None:
    """Write ``#declare name = mesh2 {...}`` for ``vertices``/``normals`` ``(n, 3)``, ``faces`` ``(m, 3)``.

    Coordinates are written in POV's left-handed frame (Z negated), in integer
    micrometres that the mesh's ``scale`` turns back into meters; unit normals with four
    decimals. ``inside`` marks a closed mesh, which POV-Ray then treats as a solid with an
    interior.
    """
    blocks = (("vertex_vectors", vector_lines(np.rint(np.asarray(vertices, dtype=np.float64) * FLIP
                                                      * MICROMETRES).astype(np.int64))),
              ("normal_vectors", vector_lines(np.asarray(normals, dtype=np.float64) * FLIP, unit=True)),
              ("face_indices", vector_lines(np.asarray(faces))))
    with open(path, "wb") as f:
        f.write(f"#declare {name} = mesh2 {{\n".encode())
        for (block, text), count in zip(blocks, (len(vertices), len(normals), len(faces))):
            f.write(f"  {block} {{\n    {count},\n".encode())
            text = memoryview(text)
            f.write(text[:-2] if len(text) else text)  # no comma after the last vector
            f.write(b"\n  }\n")
        if inside:
            f.write(b"  inside_vector <0.267, 0.534, 0.801>\n")
        f.write(f"  scale {1 / MICROMETRES:g}\n}}\n".encode())


def _finish_object(material: Material) -> str:
    kind, rough = material.type, material.roughness
    if kind == "diffuse":
        return (f"texture {{ pigment {{ color {_rgb(material.color)} }} "
                "finish { ambient 0.02 diffuse 1.0 } }")
    if kind == "plastic":
        return (f"texture {{ pigment {{ color {_rgb(material.color)} }} "
                f"finish {{ ambient 0.02 diffuse 0.75 specular 0.6 roughness {max(rough, 0.001) ** 2:.6g} "
                "reflection { 0.02, 0.2 fresnel on } conserve_energy } }")
    colour = METAL_COLOURS[material.metal]
    return (f"texture {{ pigment {{ color {_rgb(colour)} }} "
            f"finish {{ ambient 0.05 diffuse 0.15 metallic specular 0.8 roughness {max(rough, 0.001) ** 2:.6g} "
            "reflection { 0.75 metallic } } }")


def _fade(medium: IceMedium | None) -> str:
    """POV-Ray's exponential fade for absorption ``a`` per meter (R, G, B).

    With ``fade_power`` 1000 or more POV-Ray 3.7 multiplies light that crossed ``d``
    meters of the interior by ``exp(-(1 - fade_color) d / fade_distance)``: the strongest
    channel gets ``fade_color`` 0 and ``fade_distance`` 1 / max(a), the others
    ``1 - a / max(a)``. Empty when nothing absorbs.
    """
    if medium is None or max(medium.absorption) <= 0:
        return ""
    a = np.asarray(medium.absorption, dtype=np.float64)
    top = float(a.max())
    return f" fade_distance {1.0 / top:.6g} fade_power 1001 fade_color {_rgb(1.0 - a / top)}"


def _scattering_media(medium: IceMedium | None) -> str:
    """Isotropic scattering media (per meter) for cloudy ice; empty for clear ice."""
    if medium is None or medium.scattering <= 0:
        return ""
    return (f"\n    media {{ method 3 intervals 1 samples 2, 2 "
            f"scattering {{ 1, rgb {medium.scattering:.6g} }} }}")


def _ice_material(ice: IceLook) -> str:
    medium = ice_medium(ice)
    bumps = (f"\n    normal {{ bumps {min(ice.roughness * 2, 1):.4g} scale 0.0015 }}"
             if ice.roughness > 0 else "")
    filt = ", ".join(f"{float(t):.6g}" for t in ice.tint)
    return f"""material {{
  texture {{
    pigment {{ color rgbf <{filt}, 1> }}
    finish {{ ambient 0 diffuse 0 specular 0.8 roughness 0.0008
             reflection {{ 0.0, 1.0 fresnel on }} conserve_energy }}{bumps}
  }}
  interior {{ ior {ice.ior:.6g}{_fade(medium)}{_scattering_media(medium)} }}
}}"""


def scene_pov(spec: SceneSpec, *, object_inc: str, ice_inc: str | None) -> str:
    """The text of ``scene.pov`` (POV-Ray 3.7): ``spec`` (`icefarm.scene.spec.SceneSpec`), its
    meshes included from ``object_inc`` and ``ice_inc`` (None: no ice).

    The ice's absorption becomes its interior's exponential fade, its scattering an
    isotropic scattering medium. Without radiosity the sky lights nothing: fill lights
    around and below stand in for it, from the spec's light terms.
    """
    width, height = spec.resolution
    sky, sun, ground = spec.sky, spec.sun, spec.ground
    gain = 2.0 ** spec.exposure
    aspect = width / height
    right, up, front = spec.frame
    out = ["// icefarm scene for POV-Ray 3.7; render from this folder with\n",
           f"// povray +I{SCENE_POV} +O{POVRAY_STEM}.png +W{width} +H{height} +A0.3 -D -V\n",
           "#version 3.7;\n",
           f"global_settings {{ assumed_gamma 1.0 max_trace_level {max(spec.sampling.max_depth, 5)} "
           "ambient_light rgb 1 }\n",
           "#ifndef (View) #declare View = 0; #end\n",
           "#switch (View)\n"]
    for i, cam in enumerate(spec.cameras):
        out.append(f"#case ({i})\n  camera {{ perspective location {_v(cam.origin)} "
                   f"right x*{aspect:.9g} up y sky {_v(cam.up)} angle {cam.fov_x:.9g} "
                   f"look_at {_v(cam.target)} }}\n  #break\n")
    out.append("#end\n\n")

    # POV's spherical map puts the image's top at +Y and its u = 0 column at +X, turning
    # towards +Z; Mitsuba's envmap (the same image) has u = 0 at -front turning towards
    # right. The pattern is evaluated at (-front, up, right) components of the direction.
    m = np.column_stack([-front * FLIP, up * FLIP, right * FLIP])
    mat = ", ".join(f"{x:.9g}" for x in m.T.ravel()) + ", 0, 0, 0"
    kind = "hdr" if sky.file.lower().endswith(".hdr") else "exr"
    out.append(f"sky_sphere {{\n  pigment {{ image_map {{ {kind} \"{sky.file}\" map_type 1 "
               f"interpolate 2 }} }}\n  matrix <{mat}>\n"
               f"  emission rgb {sky.scale:.6g}\n}}\n\n")

    # POV's diffuse term is pigment * light * cos, Mitsuba's albedo / pi * irradiance:
    # lights are divided by pi so both pictures get the same exposure.
    if sun is not None:
        out.append(f"light_source {{ {_v(np.asarray(sun.direction) * 1e4)} color {_rgb(sun.irradiance / np.pi)} "
                   "parallel point_at <0, 0, 0> }\n")
    # Without radiosity the sky lights nothing: six shadowless lights around at 30 degrees
    # and one overhead stand in for it (about 1 W/m^2 on a level surface, like the sky map).
    sky_rgb = np.array([0.85, 0.95, 1.3]) * sky.strength * gain / np.pi
    for k in range(6):
        d = direction_of(spec.frame, 60.0 * k + 15.0, 30.0)
        out.append(f"light_source {{ {_v(d * 1e4)} color {_rgb(0.32 * sky_rgb)} parallel "
                   "point_at <0, 0, 0> shadowless }\n")
    out.append(f"light_source {{ {_v(up * 1e4)} color {_rgb(0.05 * sky_rgb)} parallel "
               "point_at <0, 0, 0> shadowless }\n")
    if ground is not None:  # light bounced off the ground onto faces that look down
        level = (0.0 if sun is None else sun.strength * max(np.sin(np.radians(sun.elevation)), 0.0)) + sky.strength
        bounce = np.asarray(GROUND_PLAIN) * level * gain / np.pi
        out.append(f"light_source {{ {_v(-up * 1e4)} color {_rgb(bounce)} parallel "
                   "point_at <0, 0, 0> shadowless }\n")
    out.append("\n")

    out.append(f"#include \"{object_inc}\"\n")
    out.append(f"object {{ Object_Mesh\n  {_finish_object(spec.material)}\n}}\n\n")
    if ice_inc is not None:
        out.append(f"#include \"{ice_inc}\"\n")
        # POV-Ray renders media only inside hollow objects.
        medium = ice_medium(spec.ice)
        hollow = " hollow" if medium is not None and medium.scattering > 0 else ""
        out.append(f"object {{ Ice_Mesh{hollow}\n  {_ice_material(spec.ice)}\n}}\n\n")

    if ground is not None:
        h = ground.half_size
        corners = [ground.centre + h * (a * front + b * right) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        g = np.eye(4)
        g[:3, 0], g[:3, 1], g[:3, 2] = front * FLIP, up * FLIP, right * FLIP
        g[:3, 3] = ground.centre * FLIP
        gm = ", ".join(f"{x:.9g}" for x in np.concatenate([g[:3, :3].T.ravel(), g[:3, 3]]))
        if ground.pattern == "checker":
            pigment = (f"checker color {_rgb(ground.colors[0])} color {_rgb(ground.colors[1])} "
                       f"translate <0, 0.5, 0> scale {ground.cell:.9g} matrix <{gm}>")
        else:
            pigment = f"color {_rgb(ground.colors[0])}"
        out.append(f"polygon {{ 5, {', '.join(_v(c) for c in corners)}, {_v(corners[0])}\n"
                   f"  texture {{ pigment {{ {pigment} }} finish {{ ambient 0.02 diffuse 1.0 }} }}\n}}\n")
    return "".join(out)


def povray_command(config: RenderConfig, view: int, output: str) -> list[str]:
    """The command line that renders view ``view`` of ``scene.pov`` into ``output``."""
    return ["povray", f"+I{SCENE_POV}", f"+O{output}", f"+W{config.width}", f"+H{config.height}",
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
                  output: str = f"{POVRAY_STEM}.png") -> float:
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
        raise RuntimeError(f"povray failed on {Path(job_dir) / SCENE_POV} (exit {proc.returncode}):\n{tail}")
    return seconds
