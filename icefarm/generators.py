"""Meshes icefarm builds itself, so its scenes, demos and tests need nothing from outside.

Four objects, all Y-up (gravity is (0, -1, 0)) with their lowest point on y = 0, in arbitrary
units (`icefarm.mesh.prepare` scales each to the size its manifest states). Manifests name
them as ``mesh: generator:<name>``.

========  ==================================================================================
teapot    the Utah teapot tessellated from Newell's 32 bicubic Bezier patches; like most
          downloaded models it is not watertight: the project's own problem mesh
fountain  a lower basin, a column, an upper bowl whose rim overhangs, a finial: a surface of
          revolution, one closed manifold (after Kim et al.'s fountain, the paper's Fig. 16 b)
roof      a house with a gable roof whose slabs overhang the walls (eaves) and the gable
          ends: one closed manifold
branch    a bent, tapered branch with three side twigs: one closed manifold
========  ==================================================================================

``detail`` sets the resolution: face counts grow about as ``detail ** 2``; the default
(`DEFAULT_DETAIL`) gives a few thousand faces. Everything is deterministic.
"""

from __future__ import annotations

import difflib
import math
import operator

import numpy as np
import trimesh

from .errors import InputError
from .geometry import unit

DEFAULT_DETAIL = 8
MAX_DETAIL = 64


def generator_names() -> tuple[str, ...]:
    """Names `generate` accepts, in a stable order."""
    return tuple(_GENERATORS)


def generate(name: str, detail: int | None = None) -> trimesh.Trimesh:
    """Build the named mesh.

    Parameters
    ----------
    name : str
        One of `generator_names()`.
    detail : int, optional
        Resolution level in ``[1, MAX_DETAIL]``; face counts grow about as ``detail ** 2``.
        None means `DEFAULT_DETAIL` (a few thousand faces).

    Returns
    -------
    trimesh.Trimesh
        Y-up, lowest point on y = 0, arbitrary units, outward-facing triangles.

    Raises
    ------
    InputError
        Unknown name (the message lists the valid ones and the nearest match) or a bad detail.
    """
    build = _GENERATORS.get(name) if isinstance(name, str) else None
    if build is None:
        names = generator_names()
        hint = difflib.get_close_matches(str(name), names, n=1, cutoff=0.4)
        tip = f"; did you mean {hint[0]!r}?" if hint else ""
        raise InputError(f"unknown mesh generator {name!r}: choose one of {', '.join(names)}{tip}")
    return build(_check_detail(detail))


def _check_detail(detail) -> int:
    if detail is None:
        return DEFAULT_DETAIL
    try:
        if isinstance(detail, bool):
            raise TypeError
        level = operator.index(detail)
    except TypeError:
        raise InputError(f"mesh detail must be a whole number from 1 to {MAX_DETAIL}, "
                         f"got {detail!r}") from None
    if not 1 <= level <= MAX_DETAIL:
        raise InputError(f"mesh detail must be from 1 to {MAX_DETAIL}, got {level}")
    return level


# --------------------------------------------------------------------------------- teapot

def teapot(detail: int = DEFAULT_DETAIL) -> trimesh.Trimesh:
    """The Utah teapot, each of its 32 Bezier patches evaluated on a ``detail`` x ``detail`` grid.

    Newell's data is rotated from Z-up to Y-up (spout towards +x, handle towards -x); the
    bottom rests on y = 0 and the lid tops out at y = 3.15. Vertices on shared patch seams
    are welded and the triangles the patch poles (lid knob, bottom centre) collapse to are
    dropped, so it has ``64 * detail ** 2 - 8 * detail`` faces for detail >= 2 (4,032 at
    the default). All normals face outwards and the winding agrees across every seam.

    It is *not* watertight, as in the classic data: 4 components (body with rim and bottom,
    lid with knob, handle, spout) and 6 open boundary loops (the body's top opening, the
    lid's lower rim, both ends of the handle and both ends of the spout); handle and spout
    pierce the body without being joined to it, and the lid sits in the body's opening
    without touching it.
    That makes it the project's own problem mesh for the proxy-surface path.
    """
    vertices, faces = bezier_patches(_TEAPOT_POINTS[_TEAPOT_PATCHES], detail)
    # Newell's patches all run so that dS/du x dS/dv points into the pot: reverse them.
    mesh = trimesh.Trimesh(vertices @ _Z_UP_TO_Y_UP.T, faces[:, ::-1], process=False)
    mesh.merge_vertices()  # patch seams share their control points, so they coincide
    mesh.update_faces(mesh.nondegenerate_faces(height=1e-12))
    mesh.remove_unreferenced_vertices()
    return _rest_on_ground(mesh)


def bezier_patches(control: np.ndarray, resolution: int) -> tuple[np.ndarray, np.ndarray]:
    """Tessellate bicubic Bezier patches on a regular parameter grid.

    Parameters
    ----------
    control : (p, 4, 4, 3) float
        Control points of ``p`` patches, indexed ``[patch, u, v]``.
    resolution : int
        Grid cells along each parameter direction (>= 1).

    Returns
    -------
    vertices : (p * (resolution + 1) ** 2, 3) float
        Unwelded: patch seams repeat their vertices.
    faces : (p * 2 * resolution ** 2, 3) int
        Counter-clockwise around the normal ``dS/du x dS/dv``.
    """
    control = np.asarray(control, dtype=np.float64)
    if control.ndim != 4 or control.shape[1:] != (4, 4, 3):
        raise ValueError(f"control must have shape (p, 4, 4, 3), got {control.shape}")
    if resolution < 1:
        raise ValueError(f"resolution must be >= 1, got {resolution}")
    t = np.linspace(0.0, 1.0, resolution + 1)
    basis = np.stack([(1 - t) ** 3, 3 * t * (1 - t) ** 2, 3 * t ** 2 * (1 - t), t ** 3], axis=1)
    points = np.einsum("ui,pijc,vj->puvc", basis, control, basis)
    side = resolution + 1
    grid = grid_faces(side, side)
    faces = grid[None] + (np.arange(len(control)) * side * side)[:, None, None]
    return points.reshape(-1, 3), faces.reshape(-1, 3)


def grid_faces(rows: int, cols: int, wrap: bool = False) -> np.ndarray:
    """Triangles of a ``rows`` x ``cols`` vertex grid stored row-major (vertex ``r * cols + c``).

    Each cell ``(r, c)`` becomes ``[a, b, d]`` and ``[a, d, e]`` with ``a = (r, c)``,
    ``b = (r + 1, c)``, ``d = (r + 1, c + 1)``, ``e = (r, c + 1)``: counter-clockwise
    around ``d/dr x d/dc``. With ``wrap`` the last column joins the first (a tube).

    Returns
    -------
    (2 * (rows - 1) * (cols - 1 + wrap), 3) int
    """
    r, c = np.meshgrid(np.arange(rows - 1), np.arange(cols if wrap else cols - 1), indexing="ij")
    a = r * cols + c
    e = r * cols + (c + 1) % cols
    b, d = a + cols, e + cols
    quads = np.stack([a, b, d, e], axis=-1).reshape(-1, 4)
    return np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])


# Newell's teapot, Z-up, in its original units (public domain): 306 control points, and
# 32 patches of 16 one-based point indices, row by row; rim 1-4, body 5-12, handle 13-16,
# spout 17-20, lid 21-28, bottom 29-32. Points 205, 206, 216 and 223 are unused, as in the
# original file.
_TEAPOT_POINTS = np.array("""
    1.4 0 2.4  1.4 -0.784 2.4  0.784 -1.4 2.4  0 -1.4 2.4
    1.3375 0 2.53125  1.3375 -0.749 2.53125  0.749 -1.3375 2.53125  0 -1.3375 2.53125
    1.4375 0 2.53125  1.4375 -0.805 2.53125  0.805 -1.4375 2.53125  0 -1.4375 2.53125
    1.5 0 2.4  1.5 -0.84 2.4  0.84 -1.5 2.4  0 -1.5 2.4
    -0.784 -1.4 2.4  -1.4 -0.784 2.4  -1.4 0 2.4  -0.749 -1.3375 2.53125
    -1.3375 -0.749 2.53125  -1.3375 0 2.53125  -0.805 -1.4375 2.53125  -1.4375 -0.805 2.53125
    -1.4375 0 2.53125  -0.84 -1.5 2.4  -1.5 -0.84 2.4  -1.5 0 2.4
    -1.4 0.784 2.4  -0.784 1.4 2.4  0 1.4 2.4  -1.3375 0.749 2.53125
    -0.749 1.3375 2.53125  0 1.3375 2.53125  -1.4375 0.805 2.53125  -0.805 1.4375 2.53125
    0 1.4375 2.53125  -1.5 0.84 2.4  -0.84 1.5 2.4  0 1.5 2.4
    0.784 1.4 2.4  1.4 0.784 2.4  0.749 1.3375 2.53125  1.3375 0.749 2.53125
    0.805 1.4375 2.53125  1.4375 0.805 2.53125  0.84 1.5 2.4  1.5 0.84 2.4
    1.75 0 1.875  1.75 -0.98 1.875  0.98 -1.75 1.875  0 -1.75 1.875
    2 0 1.35  2 -1.12 1.35  1.12 -2 1.35  0 -2 1.35
    2 0 0.9  2 -1.12 0.9  1.12 -2 0.9  0 -2 0.9
    -0.98 -1.75 1.875  -1.75 -0.98 1.875  -1.75 0 1.875  -1.12 -2 1.35
    -2 -1.12 1.35  -2 0 1.35  -1.12 -2 0.9  -2 -1.12 0.9
    -2 0 0.9  -1.75 0.98 1.875  -0.98 1.75 1.875  0 1.75 1.875
    -2 1.12 1.35  -1.12 2 1.35  0 2 1.35  -2 1.12 0.9
    -1.12 2 0.9  0 2 0.9  0.98 1.75 1.875  1.75 0.98 1.875
    1.12 2 1.35  2 1.12 1.35  1.12 2 0.9  2 1.12 0.9
    2 0 0.45  2 -1.12 0.45  1.12 -2 0.45  0 -2 0.45
    1.5 0 0.225  1.5 -0.84 0.225  0.84 -1.5 0.225  0 -1.5 0.225
    1.5 0 0.15  1.5 -0.84 0.15  0.84 -1.5 0.15  0 -1.5 0.15
    -1.12 -2 0.45  -2 -1.12 0.45  -2 0 0.45  -0.84 -1.5 0.225
    -1.5 -0.84 0.225  -1.5 0 0.225  -0.84 -1.5 0.15  -1.5 -0.84 0.15
    -1.5 0 0.15  -2 1.12 0.45  -1.12 2 0.45  0 2 0.45
    -1.5 0.84 0.225  -0.84 1.5 0.225  0 1.5 0.225  -1.5 0.84 0.15
    -0.84 1.5 0.15  0 1.5 0.15  1.12 2 0.45  2 1.12 0.45
    0.84 1.5 0.225  1.5 0.84 0.225  0.84 1.5 0.15  1.5 0.84 0.15
    -1.6 0 2.025  -1.6 -0.3 2.025  -1.5 -0.3 2.25  -1.5 0 2.25
    -2.3 0 2.025  -2.3 -0.3 2.025  -2.5 -0.3 2.25  -2.5 0 2.25
    -2.7 0 2.025  -2.7 -0.3 2.025  -3 -0.3 2.25  -3 0 2.25
    -2.7 0 1.8  -2.7 -0.3 1.8  -3 -0.3 1.8  -3 0 1.8
    -1.5 0.3 2.25  -1.6 0.3 2.025  -2.5 0.3 2.25  -2.3 0.3 2.025
    -3 0.3 2.25  -2.7 0.3 2.025  -3 0.3 1.8  -2.7 0.3 1.8
    -2.7 0 1.575  -2.7 -0.3 1.575  -3 -0.3 1.35  -3 0 1.35
    -2.5 0 1.125  -2.5 -0.3 1.125  -2.65 -0.3 0.9375  -2.65 0 0.9375
    -2 -0.3 0.9  -1.9 -0.3 0.6  -1.9 0 0.6  -3 0.3 1.35
    -2.7 0.3 1.575  -2.65 0.3 0.9375  -2.5 0.3 1.125  -1.9 0.3 0.6
    -2 0.3 0.9  1.7 0 1.425  1.7 -0.66 1.425  1.7 -0.66 0.6
    1.7 0 0.6  2.6 0 1.425  2.6 -0.66 1.425  3.1 -0.66 0.825
    3.1 0 0.825  2.3 0 2.1  2.3 -0.25 2.1  2.4 -0.25 2.025
    2.4 0 2.025  2.7 0 2.4  2.7 -0.25 2.4  3.3 -0.25 2.4
    3.3 0 2.4  1.7 0.66 0.6  1.7 0.66 1.425  3.1 0.66 0.825
    2.6 0.66 1.425  2.4 0.25 2.025  2.3 0.25 2.1  3.3 0.25 2.4
    2.7 0.25 2.4  2.8 0 2.475  2.8 -0.25 2.475  3.525 -0.25 2.49375
    3.525 0 2.49375  2.9 0 2.475  2.9 -0.15 2.475  3.45 -0.15 2.5125
    3.45 0 2.5125  2.8 0 2.4  2.8 -0.15 2.4  3.2 -0.15 2.4
    3.2 0 2.4  3.525 0.25 2.49375  2.8 0.25 2.475  3.45 0.15 2.5125
    2.9 0.15 2.475  3.2 0.15 2.4  2.8 0.15 2.4  0 0 3.15
    0 -0.002 3.15  0.002 0 3.15  0.8 0 3.15  0.8 -0.45 3.15
    0.45 -0.8 3.15  0 -0.8 3.15  0 0 2.85  0.2 0 2.7
    0.2 -0.112 2.7  0.112 -0.2 2.7  0 -0.2 2.7  -0.002 0 3.15
    -0.45 -0.8 3.15  -0.8 -0.45 3.15  -0.8 0 3.15  -0.112 -0.2 2.7
    -0.2 -0.112 2.7  -0.2 0 2.7  0 0.002 3.15  -0.8 0.45 3.15
    -0.45 0.8 3.15  0 0.8 3.15  -0.2 0.112 2.7  -0.112 0.2 2.7
    0 0.2 2.7  0.45 0.8 3.15  0.8 0.45 3.15  0.112 0.2 2.7
    0.2 0.112 2.7  0.4 0 2.55  0.4 -0.224 2.55  0.224 -0.4 2.55
    0 -0.4 2.55  1.3 0 2.55  1.3 -0.728 2.55  0.728 -1.3 2.55
    0 -1.3 2.55  1.3 0 2.4  1.3 -0.728 2.4  0.728 -1.3 2.4
    0 -1.3 2.4  -0.224 -0.4 2.55  -0.4 -0.224 2.55  -0.4 0 2.55
    -0.728 -1.3 2.55  -1.3 -0.728 2.55  -1.3 0 2.55  -0.728 -1.3 2.4
    -1.3 -0.728 2.4  -1.3 0 2.4  -0.4 0.224 2.55  -0.224 0.4 2.55
    0 0.4 2.55  -1.3 0.728 2.55  -0.728 1.3 2.55  0 1.3 2.55
    -1.3 0.728 2.4  -0.728 1.3 2.4  0 1.3 2.4  0.224 0.4 2.55
    0.4 0.224 2.55  0.728 1.3 2.55  1.3 0.728 2.55  0.728 1.3 2.4
    1.3 0.728 2.4  0 0 0  1.5 0 0.15  1.5 0.84 0.15
    0.84 1.5 0.15  0 1.5 0.15  1.5 0 0.075  1.5 0.84 0.075
    0.84 1.5 0.075  0 1.5 0.075  1.425 0 0  1.425 0.798 0
    0.798 1.425 0  0 1.425 0  -0.84 1.5 0.15  -1.5 0.84 0.15
    -1.5 0 0.15  -0.84 1.5 0.075  -1.5 0.84 0.075  -1.5 0 0.075
    -0.798 1.425 0  -1.425 0.798 0  -1.425 0 0  -1.5 -0.84 0.15
    -0.84 -1.5 0.15  0 -1.5 0.15  -1.5 -0.84 0.075  -0.84 -1.5 0.075
    0 -1.5 0.075  -1.425 -0.798 0  -0.798 -1.425 0  0 -1.425 0
    0.84 -1.5 0.15  1.5 -0.84 0.15  0.84 -1.5 0.075  1.5 -0.84 0.075
    0.798 -1.425 0  1.425 -0.798 0
""".split(), dtype=np.float64).reshape(306, 3)

_TEAPOT_PATCHES = np.array("""
      1   2   3   4   5   6   7   8   9  10  11  12  13  14  15  16
      4  17  18  19   8  20  21  22  12  23  24  25  16  26  27  28
     19  29  30  31  22  32  33  34  25  35  36  37  28  38  39  40
     31  41  42   1  34  43  44   5  37  45  46   9  40  47  48  13
     13  14  15  16  49  50  51  52  53  54  55  56  57  58  59  60
     16  26  27  28  52  61  62  63  56  64  65  66  60  67  68  69
     28  38  39  40  63  70  71  72  66  73  74  75  69  76  77  78
     40  47  48  13  72  79  80  49  75  81  82  53  78  83  84  57
     57  58  59  60  85  86  87  88  89  90  91  92  93  94  95  96
     60  67  68  69  88  97  98  99  92 100 101 102  96 103 104 105
     69  76  77  78  99 106 107 108 102 109 110 111 105 112 113 114
     78  83  84  57 108 115 116  85 111 117 118  89 114 119 120  93
    121 122 123 124 125 126 127 128 129 130 131 132 133 134 135 136
    124 137 138 121 128 139 140 125 132 141 142 129 136 143 144 133
    133 134 135 136 145 146 147 148 149 150 151 152  69 153 154 155
    136 143 144 133 148 156 157 145 152 158 159 149 155 160 161  69
    162 163 164 165 166 167 168 169 170 171 172 173 174 175 176 177
    165 178 179 162 169 180 181 166 173 182 183 170 177 184 185 174
    174 175 176 177 186 187 188 189 190 191 192 193 194 195 196 197
    177 184 185 174 189 198 199 186 193 200 201 190 197 202 203 194
    204 204 204 204 207 208 209 210 211 211 211 211 212 213 214 215
    204 204 204 204 210 217 218 219 211 211 211 211 215 220 221 222
    204 204 204 204 219 224 225 226 211 211 211 211 222 227 228 229
    204 204 204 204 226 230 231 207 211 211 211 211 229 232 233 212
    212 213 214 215 234 235 236 237 238 239 240 241 242 243 244 245
    215 220 221 222 237 246 247 248 241 249 250 251 245 252 253 254
    222 227 228 229 248 255 256 257 251 258 259 260 254 261 262 263
    229 232 233 212 257 264 265 234 260 266 267 238 263 268 269 242
    270 270 270 270 279 280 281 282 275 276 277 278 271 272 273 274
    270 270 270 270 282 289 290 291 278 286 287 288 274 283 284 285
    270 270 270 270 291 298 299 300 288 295 296 297 285 292 293 294
    270 270 270 270 300 305 306 279 297 303 304 275 294 301 302 271
""".split(), dtype=np.int64).reshape(32, 4, 4) - 1

_Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


# ------------------------------------------------------------------------------- fountain

def fountain(detail: int = DEFAULT_DETAIL) -> trimesh.Trimesh:
    """A two-basin garden fountain, one closed manifold: a surface of revolution about +y.

    A wide lower basin (radius 1, wall top at y = 0.3, a bead overhanging its outer wall),
    a column, an upper bowl (radius 0.58) whose rim carries an outward drip lip, so water
    on it leaves from overhanging edges above the lower basin, and a small finial at
    y = 1.17. Its outline is `_FOUNTAIN_PROFILE`, evenly subdivided. At the default
    detail the profile has 41 pieces and the lathe 28 sectors, giving 2,240 faces, the
    polygon count of the paper's Figure 16 b input.
    """
    around = max(8, round(3.5 * detail))
    pieces = max(len(_FOUNTAIN_PROFILE) - 1, round(41 * detail / 8))
    profile = resample_polyline(_FOUNTAIN_PROFILE, pieces, weights=_FOUNTAIN_WEIGHTS)
    vertices, faces = lathe(profile, around)
    return _rest_on_ground(trimesh.Trimesh(vertices, faces, process=False))


def lathe(profile: np.ndarray, segments: int) -> tuple[np.ndarray, np.ndarray]:
    """Revolve a profile about the y axis into a closed surface.

    Parameters
    ----------
    profile : (k, 2) float
        ``(radius, y)`` points, k >= 3. The first and last lie on the axis (radius 0),
        the others off it; together with the axis they bound a simple polygon that runs
        counter-clockwise (outwards along the bottom first), so normals face outwards.
    segments : int
        Divisions around the axis (>= 3).

    Returns
    -------
    vertices : ((k - 2) * segments + 2, 3) float
    faces : (segments * (2 * k - 4), 3) int
        A closed 2-manifold when the profile polygon is simple.
    """
    profile = np.asarray(profile, dtype=np.float64)
    if profile.ndim != 2 or profile.shape[1] != 2 or len(profile) < 3:
        raise ValueError(f"profile must have shape (k >= 3, 2), got {profile.shape}")
    if profile[0, 0] != 0 or profile[-1, 0] != 0 or (profile[1:-1, 0] <= 0).any():
        raise ValueError("profile must start and end on the axis (radius 0) and stay off it between")
    if segments < 3:
        raise ValueError(f"segments must be >= 3, got {segments}")
    inner = profile[1:-1]
    theta = np.arange(segments) * (2 * np.pi / segments)
    rings = np.stack([inner[:, :1] * np.cos(theta), np.broadcast_to(inner[:, 1:], (len(inner), segments)),
                      inner[:, :1] * np.sin(theta)], axis=-1).reshape(-1, 3)
    top = len(rings) + 1
    vertices = np.concatenate([[[0.0, profile[0, 1], 0.0]], rings, [[0.0, profile[-1, 1], 0.0]]])
    j = np.arange(segments)
    nxt = (j + 1) % segments
    last = 1 + (len(inner) - 1) * segments
    faces = np.concatenate([
        np.stack([np.zeros_like(j), 1 + j, 1 + nxt], axis=1),                 # bottom fan
        grid_faces(len(inner), segments, wrap=True) + 1,                      # bands
        np.stack([last + j, np.full_like(j, top), last + nxt], axis=1),      # top fan
    ])
    return vertices, faces


def resample_polyline(points: np.ndarray, segments: int, weights: np.ndarray | None = None) -> np.ndarray:
    """Split each piece of a polyline evenly so the whole has exactly ``segments`` pieces.

    Every input point is kept; pieces get subdivisions in proportion to ``length * weight``
    (largest remainder), at least one each.

    Parameters
    ----------
    points : (k, d) float
    segments : int
        At least ``k - 1``.
    weights : (k - 1,) float, optional
        Non-negative importance of each piece (default 1).

    Returns
    -------
    (segments + 1, d) float
    """
    points = np.asarray(points, dtype=np.float64)
    pieces = len(points) - 1
    if segments < pieces:
        raise ValueError(f"segments ({segments}) must be >= the polyline's {pieces} pieces")
    share = np.linalg.norm(np.diff(points, axis=0), axis=1)
    if weights is not None:
        share = share * np.asarray(weights, dtype=np.float64)
    ideal = segments * share / share.sum() if share.sum() > 0 else np.full(pieces, segments / pieces)
    counts = np.maximum(1, np.floor(ideal)).astype(np.int64)
    while counts.sum() > segments:  # only when many pieces were forced up to one
        counts[np.argmax(np.where(counts > 1, counts - ideal, -np.inf))] -= 1
    short = segments - counts.sum()
    counts[np.argsort(counts - ideal, kind="stable")[:short]] += 1
    piece = np.repeat(np.arange(pieces), counts)
    step = np.arange(len(piece)) - np.repeat(np.cumsum(counts) - counts, counts)
    t = (step / counts[piece])[:, None]
    inner = points[piece] * (1 - t) + points[piece + 1] * t
    return np.concatenate([inner, points[-1:]])


# (radius, y) from the bottom centre out, over both basins, to the finial's tip. The lower
# basin is 1 wide (radius) and 0.3 high; its wall top carries a bead that overhangs the
# outer wall; the upper bowl's underside flares from the column to a drip lip at r = 0.58.
_FOUNTAIN_PROFILE = np.array([
    [0.00, 0.00], [1.00, 0.00],                                    # base
    [1.00, 0.22], [1.03, 0.25], [1.03, 0.29], [0.99, 0.30],        # outer wall, bead
    [0.93, 0.30], [0.92, 0.10], [0.20, 0.08],                      # inner wall, floor
    [0.20, 0.16], [0.12, 0.20], [0.10, 0.24],                      # plinth
    [0.09, 0.62], [0.12, 0.66],                                    # column, collar
    [0.14, 0.70], [0.25, 0.78], [0.40, 0.88], [0.52, 0.95],        # bowl underside
    [0.56, 0.97], [0.58, 1.00], [0.57, 1.03], [0.53, 1.04],        # drip lip, rim
    [0.50, 1.02], [0.42, 0.96], [0.28, 0.88], [0.12, 0.84],        # bowl inside
    [0.05, 0.84], [0.04, 1.00], [0.07, 1.06], [0.08, 1.10],        # finial
    [0.06, 1.15], [0.00, 1.17],
])
# The flat underside gets no extra rings: nothing happens there.
_FOUNTAIN_WEIGHTS = np.r_[0.0, np.ones(len(_FOUNTAIN_PROFILE) - 2)]


# ----------------------------------------------------------------------------------- roof

def roof(detail: int = DEFAULT_DETAIL) -> trimesh.Trimesh:
    """A house with a chimney and a gable roof that overhangs its walls, one closed manifold.

    The house is 2 wide (x), 3 deep (z) with walls 1 high; the roof rises 0.75 to its
    ridge (about 37 degrees), is 0.12 thick (vertically), and overhangs 0.35 past the long
    walls (the eaves, where icicles hang) and 0.3 past the gable ends. The pieces are
    fused by a boolean union (manifold3d) and remeshed isotropically (pymeshlab), keeping
    the creases, to about ``60 * detail ** 2`` faces.
    """
    half_w, wall, half_d = 1.0, 1.0, 1.5
    rise, thick, eave, gable = 0.75, 0.12, 0.35, 0.3
    slope = rise / half_w
    ridge = wall + rise  # underside of the roof at the ridge
    out = half_w + eave
    low = wall - eave * slope  # underside of the roof at the eaves
    # The gable walls reach into the middle of the roof slab so no faces of the union coincide.
    house = prism([(-half_w, 0.0), (half_w, 0.0), (half_w, wall + thick / 2),
                   (0.0, ridge + thick / 2), (-half_w, wall + thick / 2)],
                  [[0, 1, 2], [0, 2, 3], [0, 3, 4]], -half_d, half_d)
    slab = prism([(-out, low), (0.0, ridge), (out, low), (out, low + thick),
                  (0.0, ridge + thick), (-out, low + thick)],
                 [[0, 1, 4], [0, 4, 5], [1, 2, 3], [1, 3, 4]], -half_d - gable, half_d + gable)
    chimney = prism([(0.35, 1.2), (0.6, 1.2), (0.6, 2.05), (0.35, 2.05)],
                    [[0, 1, 2], [0, 2, 3]], 0.55, 0.85)
    mesh = trimesh.boolean.union([house, slab, chimney], engine="manifold")
    return _rest_on_ground(_remesh(mesh, 60 * detail ** 2))


def prism(profile, cap_triangles, z0: float, z1: float) -> trimesh.Trimesh:
    """Extrude a counter-clockwise polygon in the xy plane from ``z0`` to ``z1``: a closed solid.

    Parameters
    ----------
    profile : (n, 2) float
        Polygon corners, counter-clockwise seen from +z.
    cap_triangles : (n - 2, 3) int
        A counter-clockwise triangulation of the polygon by its corner indices.
    z0, z1 : float
        ``z0 < z1``.

    Returns
    -------
    trimesh.Trimesh
        ``2 n`` vertices, ``2 n + 2 (n - 2)`` outward-facing faces.
    """
    profile = np.asarray(profile, dtype=np.float64)
    caps = np.asarray(cap_triangles, dtype=np.int64)
    n = len(profile)
    x, y = profile.T
    if 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) <= 0:
        raise ValueError("prism profile must run counter-clockwise")
    if not z0 < z1:
        raise ValueError(f"need z0 < z1, got {z0}, {z1}")
    vertices = np.concatenate([np.c_[profile, np.full(n, z0)], np.c_[profile, np.full(n, z1)]])
    i = np.arange(n)
    j = (i + 1) % n
    faces = np.concatenate([np.stack([i, j, n + j], axis=1), np.stack([i, n + j, n + i], axis=1),
                            caps + n, caps[:, ::-1]])
    return trimesh.Trimesh(vertices, faces, process=False)


# --------------------------------------------------------------------------------- branch

def branch(detail: int = DEFAULT_DETAIL) -> trimesh.Trimesh:
    """A bent, tapered tree branch with three side twigs, one closed manifold.

    The main branch runs about 1.1 along +x, rising then drooping, its radius tapering
    from 0.045 (flat cut end at x = 0) to 0.012 (rounded tip); three twigs (radius 0.6 of
    the branch where they leave it, tapering to 0.005, rounded tips) leave it at 30, 55
    and 78 % of its length. Tubes are swept along Bezier curves and fused by a boolean
    union (manifold3d); the branch and twig tubes get ``2 detail`` and ``1.5 detail``
    sides.
    """
    sides = max(8, 2 * detail)
    t = np.linspace(0.0, 1.0, max(8, 6 * detail) + 1)
    main = bezier_curve([[0.0, 0.30, 0.0], [0.40, 0.44, 0.04], [0.75, 0.40, 0.16],
                         [1.10, 0.28, 0.14]], t)
    main_radius = 0.045 - 0.033 * t ** 0.8
    tubes = [tube(main, main_radius, sides)]
    twig_t = np.linspace(0.0, 1.0, max(4, 2 * detail) + 1)
    for at, bend, tip in _TWIGS:
        k = np.searchsorted(t, at)
        start = main[k]
        path = bezier_curve([start, start + np.asarray(bend), start + np.asarray(tip)], twig_t)
        radius = 0.6 * main_radius[k] * (1 - twig_t) + 0.005 * twig_t
        tubes.append(tube(path, radius, max(6, round(1.5 * detail))))
    mesh = trimesh.boolean.union(tubes, engine="manifold")
    return _rest_on_ground(mesh)


# (where along the branch, second control point, end point; both relative to the start)
_TWIGS = (
    (0.30, (0.10, 0.16, -0.04), (0.22, 0.30, -0.14)),
    (0.55, (0.12, 0.06, 0.12), (0.30, 0.16, 0.26)),
    (0.78, (0.08, 0.10, -0.10), (0.20, 0.12, -0.24)),
)


def bezier_curve(control, t: np.ndarray) -> np.ndarray:
    """Points of a Bezier curve of any degree.

    Parameters
    ----------
    control : (m, d) float
        m >= 2 control points.
    t : (k,) float
        Parameters in [0, 1].

    Returns
    -------
    (k, d) float
    """
    control = np.asarray(control, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)[:, None]
    degree = len(control) - 1
    if control.ndim != 2 or degree < 1:
        raise ValueError(f"control must have shape (m >= 2, d), got {control.shape}")
    i = np.arange(degree + 1)
    binom = np.array([math.comb(degree, k) for k in i], dtype=np.float64)
    basis = binom * t ** i * (1 - t) ** (degree - i)
    return basis @ control


def tube(centerline: np.ndarray, radii: np.ndarray, sides: int, tip_rings: int = 3) -> trimesh.Trimesh:
    """Sweep a circle along a polyline into a closed tube: flat start, rounded end.

    Parameters
    ----------
    centerline : (k, 3) float
        k >= 2 points; the curve must bend gently (it may not run along the axis least
        aligned with its chord).
    radii : (k,) float
        Positive radius at each point.
    sides : int
        Vertices around each ring (>= 3).
    tip_rings : int
        Rings of the hemispherical cap at the end, before its apex.

    Returns
    -------
    trimesh.Trimesh
        Closed, outward-facing.
    """
    centerline = np.asarray(centerline, dtype=np.float64)
    radii = np.asarray(radii, dtype=np.float64)
    if centerline.ndim != 2 or centerline.shape[1] != 3 or len(centerline) < 2:
        raise ValueError(f"centerline must have shape (k >= 2, 3), got {centerline.shape}")
    if radii.shape != (len(centerline),) or (radii <= 0).any():
        raise ValueError("radii must be positive, one per centerline point")
    if sides < 3:
        raise ValueError(f"sides must be >= 3, got {sides}")
    tangent = unit(np.gradient(centerline, axis=0))
    # Round the end: extra rings on a quarter circle, the last one collapsing to the apex.
    angle = np.arange(1, tip_rings + 2) * (0.5 * np.pi / (tip_rings + 1))
    end = centerline[-1] + np.outer(np.sin(angle), tangent[-1]) * radii[-1]
    centerline = np.concatenate([centerline, end])
    radii = np.concatenate([radii, radii[-1] * np.cos(angle[:-1])])
    tangent = np.concatenate([tangent, np.repeat(tangent[-1:], len(angle), axis=0)])
    # Frames from one fixed reference: no twist, fine for curves that bend gently.
    chord = centerline[-1] - centerline[0]
    reference = np.eye(3)[np.argmin(np.abs(chord))]
    if (np.abs(tangent @ reference) > 0.99).any():
        raise ValueError("centerline turns too far from its chord for a twist-free frame")
    normal = unit(reference - (tangent @ reference)[:, None] * tangent)
    binormal = np.cross(tangent, normal)
    phi = np.arange(sides) * (2 * np.pi / sides)
    rings = centerline[:-1, None] + radii[:, None, None] * (
        np.cos(phi)[None, :, None] * normal[:-1, None] + np.sin(phi)[None, :, None] * binormal[:-1, None])
    count = len(rings)
    vertices = np.concatenate([rings.reshape(-1, 3), centerline[:1], centerline[-1:]])
    start, apex = count * sides, count * sides + 1
    j = np.arange(sides)
    nxt = (j + 1) % sides
    last = (count - 1) * sides
    faces = np.concatenate([
        np.stack([np.full_like(j, start), nxt, j], axis=1),
        grid_faces(count, sides, wrap=True)[:, ::-1],
        np.stack([last + j, last + nxt, np.full_like(j, apex)], axis=1),
    ])
    return trimesh.Trimesh(vertices, faces, process=False)


# -------------------------------------------------------------------------------- helpers

def _remesh(mesh: trimesh.Trimesh, faces: int) -> trimesh.Trimesh:
    """Isotropic remeshing to about ``faces`` triangles; creases over 30 degrees are kept."""
    import pymeshlab

    length = np.sqrt(4.0 * mesh.area / (np.sqrt(3.0) * faces))
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.asarray(mesh.vertices, dtype=np.float64),
                               np.asarray(mesh.faces, dtype=np.int32)))
    ms.meshing_isotropic_explicit_remeshing(targetlen=pymeshlab.PureValue(float(length)), iterations=6)
    out = ms.current_mesh()
    return trimesh.Trimesh(out.vertex_matrix(), out.face_matrix(), process=False)


def _rest_on_ground(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Shift the mesh so its lowest point is on y = 0; plain float64 / int64 arrays."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64).copy()
    vertices[:, 1] -= vertices[:, 1].min()
    return trimesh.Trimesh(vertices, np.asarray(mesh.faces, dtype=np.int64), process=False)


_GENERATORS = {"teapot": teapot, "fountain": fountain, "roof": roof, "branch": branch}
