"""The built-in procedural head (the embedded default): FLAME's fields, joints and parameters,
its own topology (5,183 vertices, 9,592 faces; FLAME has 5,023 / 9,976).

`make_head()` returns a `FlameModel` (template, identity and expression blendshapes, pose
correctives, joint regressor, skinning weights, faces, FLAME's 5-joint tree) plus `HeadAssets`
(per-face region labels, per-vertex albedo), so every code path used for a real FLAME file is the
one used here. Axes as FLAME: y up, the face looks down +z, metres.

What makes the paper's problem real is all there: skin with a nose, brows and hair; lips that part
when the jaw opens, in front of a dark mouth cavity; upper teeth (on the neck joint) and lower teeth
(on the jaw) hidden behind closed lips; eyeballs (sclera, iris, pupil) that turn with the eye
joints, under eyelids that close with the blink expressions. Identity directions: head width,
nose length, jaw width. Expression directions: blink left, blink right, smile, brow raise, lips
part, pout. Deterministic, a few thousand vertices, built in milliseconds with numpy.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from gae_jax.model import makehuman
from gae_jax.model.flame import FLAME_PARENTS, FlameModel, FlameParams
# The heads' region vocabulary, read as head.REGION_ID by the stages above.
from gae_jax.model.regions import REGION_ID, REGIONS, HeadAssets  # noqa: F401
SHAPE_NAMES = ("head_width", "nose_length", "jaw_width")
EXPR_NAMES = ("blink_left", "blink_right", "smile", "brow_raise", "lips_part", "pout")
ALBEDO = dict(skin=(0.87, 0.68, 0.56), hair=(0.25, 0.16, 0.10), brows=(0.22, 0.14, 0.09),
              lips=(0.75, 0.32, 0.34), mouth=(0.25, 0.05, 0.07), teeth=(0.95, 0.94, 0.88),
              sclera=(0.96, 0.96, 0.96), iris=(0.25, 0.45, 0.65), pupil=(0.03, 0.03, 0.03),
              tongue=(0.70, 0.33, 0.36))

HEAD_RADII = (0.078, 0.102, 0.092)
MOUTH_CENTRE = np.array([0.0, -0.045])  # (x, y) on the face
MOUTH_HALF = np.array([0.026, 0.008])  # half-width / half-height of the skin opening
EYE_CENTRES = (np.array([0.032, 0.018, 0.064]), np.array([-0.032, 0.018, 0.064]))
EYE_RADIUS = 0.0125
LID_GAP = 1.12  # eyelid radius / eyeball radius
LID_OPEN_ANGLE = np.deg2rad(55.0)  # polar angle from +y that the open upper lid reaches
LID_CLOSED_ANGLE = np.deg2rad(150.0)
IRIS_ANGLE = np.deg2rad(22.0)  # angular radius of the iris around the gaze axis (+z)
PUPIL_ANGLE = np.deg2rad(9.0)
EYE_CAP_DEGREES = 110.0  # the eyeball is modelled up to this angle from the gaze
JAW_PIVOT = np.array([0.0, -0.015, 0.0])
NECK_PIVOT = np.array([0.0, -0.075, -0.01])
ROOT = np.array([0.0, -0.11, -0.02])


class _Builder:
    """Accumulates mesh parts with their skinning weights and blendshape displacements."""

    def __init__(self):
        self.verts, self.faces, self.regions, self.colors, self.weights = [], [], [], [], []
        self.shape = {n: [] for n in SHAPE_NAMES}
        self.expr = {n: [] for n in EXPR_NAMES}
        self.count = 0

    def add(self, verts, faces, face_regions, colors, weights, shape=None, expr=None):
        n = len(verts)
        self.verts.append(verts)
        self.faces.append(np.asarray(faces) + self.count)
        self.regions.append(np.asarray(face_regions))
        self.colors.append(colors)
        self.weights.append(weights)
        for name in SHAPE_NAMES:
            self.shape[name].append((shape or {}).get(name, np.zeros((n, 3))))
        for name in EXPR_NAMES:
            self.expr[name].append((expr or {}).get(name, np.zeros((n, 3))))
        start = self.count
        self.count += n
        return start


def _grid_faces(rows: int, cols: int, wrap: bool) -> np.ndarray:
    """Two triangles per cell of a rows x cols vertex grid (columns wrap around when asked)."""
    faces = []
    for r in range(rows - 1):
        for c in range(cols if wrap else cols - 1):
            a, b = r * cols + c, r * cols + (c + 1) % cols
            d, e = a + cols, b + cols
            faces += [(a, d, b), (b, d, e)]
    return np.asarray(faces, np.int64)


def _sphere(centre, radius, rows, cols, theta_max=np.pi, axis_up=True, theta=None):
    """UV sphere (or cap up to polar angle theta_max from +y): vertices (rows*cols, 3), faces.

    `theta` (rows,) gives the rings' polar angles explicitly."""
    theta = np.linspace(1e-3, theta_max, rows) if theta is None else np.asarray(theta)
    rows = len(theta)
    phi = np.linspace(0, 2 * np.pi, cols, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    unit = np.stack([np.sin(t) * np.sin(p), np.cos(t), np.sin(t) * np.cos(p)], -1).reshape(-1, 3)
    return np.asarray(centre) + radius * unit, _grid_faces(rows, cols, wrap=True), unit


def _one_hot(n, joint):
    w = np.zeros((n, 5))
    w[:, joint] = 1.0
    return w


def _skin(b: _Builder):
    rows, cols = 44, 64
    verts, faces, unit = _sphere((0.0, 0.0, 0.0), 1.0, rows, cols)
    verts = verts * np.asarray(HEAD_RADII)
    x, y, z = verts.T
    front = np.clip(unit[:, 2], 0, 1)
    # Nose: a ridge in front, between the eyes and above the mouth.
    nose = np.exp(-((x / 0.012) ** 2) - (((y + 0.005) / 0.022) ** 2)) * front ** 4
    verts[:, 2] += 0.028 * nose
    # Brow ridge and chin.
    brow = np.exp(-(((y - 0.036) / 0.008) ** 2)) * np.exp(-(((np.abs(x) - 0.03) / 0.02) ** 2))
    verts[:, 2] += 0.006 * brow * front
    # Eye sockets: press the skin back so the eyeballs sit in front of it.
    for centre in EYE_CENTRES:
        d2 = ((x - centre[0]) / 0.02) ** 2 + ((y - centre[1]) / 0.014) ** 2
        verts[:, 2] -= 0.014 * np.exp(-d2) * front
    face_centres = verts[faces].mean(1)
    fx, fy, fz = face_centres.T
    in_mouth = ((fx - MOUTH_CENTRE[0]) / MOUTH_HALF[0]) ** 2 + (
        (fy - MOUTH_CENTRE[1]) / MOUTH_HALF[1]) ** 2 < 1.0
    faces = faces[~(in_mouth & (fz > 0))]
    face_centres = verts[faces].mean(1)
    fx, fy, fz = face_centres.T
    regions = np.full(len(faces), REGION_ID["skin"])
    hair = (fy > 0.055 - 0.09 * np.clip(-fz / HEAD_RADII[2], 0, 1)) & ~(
        (fz > 0.05) & (fy < 0.075))
    regions[hair] = REGION_ID["hair"]
    brows = (np.abs(fy - 0.04) < 0.0055) & (np.abs(np.abs(fx) - 0.032) < 0.017) & (fz > 0.04)
    regions[brows] = REGION_ID["brows"]
    colors = np.tile(ALBEDO["skin"], (len(verts), 1))
    vy, vz = verts[:, 1], verts[:, 2]
    hair_v = (vy > 0.055 - 0.09 * np.clip(-vz / HEAD_RADII[2], 0, 1)) & ~(
        (vz > 0.05) & (vy < 0.075))
    colors[hair_v] = ALBEDO["hair"]
    brow_v = (np.abs(vy - 0.04) < 0.0055) & (np.abs(np.abs(x) - 0.032) < 0.017) & (vz > 0.04)
    colors[brow_v] = ALBEDO["brows"]
    # Skinning: lower face on the jaw (smoothly), the rest on the neck.
    below = np.clip((MOUTH_CENTRE[1] + 0.004 - y) / 0.02, 0, 1)
    jaw_w = below * np.clip(z / 0.03, 0, 1) * np.clip((0.1 + y) / 0.03, 0, 1)
    weights = np.zeros((len(verts), 5))
    weights[:, 2] = jaw_w
    weights[:, 1] = 1 - jaw_w
    near_mouth = np.exp(-(((x - MOUTH_CENTRE[0]) / 0.035) ** 2)
                        - (((y - MOUTH_CENTRE[1]) / 0.025) ** 2)) * front
    shape = dict(
        head_width=np.stack([x * 0.12, 0 * x, 0 * x], -1),
        nose_length=np.stack([0 * x, -0.002 * nose, 0.012 * nose], -1),
        jaw_width=np.stack([x * 0.15 * below, 0 * x, 0 * x], -1),
    )
    expr = dict(
        brow_raise=np.stack([0 * x, 0.006 * brow * front, 0 * x], -1),
        smile=np.stack([0.004 * np.sign(x) * near_mouth, 0.003 * near_mouth, 0 * x], -1),
    )
    b.add(verts, faces, regions, colors, weights, shape, expr)


def _lip(b: _Builder, upper: bool):
    """Half a torus along the mouth opening's rim, protruding in front of the skin."""
    rows, cols = 10, 33
    s = np.linspace(0, np.pi, cols)  # around the mouth, corner to corner
    a = np.linspace(-np.pi / 2 - 0.6, np.pi / 2 + 1.2, rows) if upper else np.linspace(
        -np.pi / 2 - 1.2, np.pi / 2 + 0.6, rows)
    sg = 1.0 if upper else -1.0
    rim_x = MOUTH_HALF[0] * np.cos(s)
    rim_y = MOUTH_CENTRE[1] + sg * (0.0012 + 0.0028 * np.sin(s))
    depth = HEAD_RADII[2] * np.sqrt(np.clip(1 - (rim_x / HEAD_RADII[0]) ** 2
                                            - (rim_y / HEAD_RADII[1]) ** 2, 0, 1)) - 0.001
    tube = 0.0062 * (0.55 + 0.45 * np.sin(s))  # thinner at the corners
    aa, ss = np.meshgrid(a, s, indexing="ij")
    tt = np.broadcast_to(tube, aa.shape)
    verts = np.stack([np.broadcast_to(rim_x, aa.shape),
                      np.broadcast_to(rim_y, aa.shape) + sg * tt * np.sin(aa),
                      np.broadcast_to(depth, aa.shape) + tt * np.cos(aa)], -1).reshape(-1, 3)
    faces = _grid_faces(rows, cols, wrap=False)
    if not upper:
        faces = faces[:, ::-1]
    n = len(verts)
    regions = np.full(len(faces), REGION_ID["lips"])
    weights = _one_hot(n, 2 if not upper else 1)
    corner = np.exp(-((np.abs(verts[:, 0]) - MOUTH_HALF[0]) / 0.008) ** 2)
    expr = dict(
        lips_part=np.tile([0.0, 0.004 * sg, 0.0], (n, 1)),
        pout=np.tile([0.0, 0.0, 0.006], (n, 1)) * (1 - corner)[:, None],
        smile=np.stack([0.004 * np.sign(verts[:, 0]) * corner, 0.005 * corner, 0 * corner], -1),
    )
    shape = dict(jaw_width=np.stack([verts[:, 0] * 0.15 * (0 if upper else 1), 0 * corner,
                                     0 * corner], -1))
    b.add(verts, faces, regions, np.tile(ALBEDO["lips"], (n, 1)), weights, shape, expr)


def _mouth_cavity(b: _Builder):
    """A dark cup behind the mouth opening (open at the front, on the neck joint)."""
    centre = np.array([0.0, MOUTH_CENTRE[1] - 0.004, 0.065])
    _, faces, unit = _sphere((0.0, 0.0, 0.0), 1.0, 16, 24)
    verts = centre + unit * np.array([0.030, 0.020, 0.030])
    faces = faces[unit[faces].mean(1)[:, 2] < 0.5]
    n = len(verts)
    b.add(verts, faces[:, ::-1], np.full(len(faces), REGION_ID["mouth"]),
          np.tile(ALBEDO["mouth"], (n, 1)), _one_hot(n, 1))


def _teeth(b: _Builder, upper: bool):
    """A row of teeth: a thin curved slab along an arc behind the lips."""
    cols = 17
    ang = np.linspace(-1.0, 1.0, cols)
    radius = 0.020
    cz = 0.075 - radius - (0.0 if upper else 0.002)
    height = 0.0085
    top = MOUTH_CENTRE[1] + (0.0005 if upper else -0.0005)
    y0, y1 = (top, top + height) if upper else (top - height, top)
    verts = []
    for thickness in (0.0, -0.004):
        for y in (y0, y1):
            verts.append(np.stack([(radius + thickness) * np.sin(ang), np.full(cols, y),
                                   cz + (radius + thickness) * np.cos(ang)], -1))
    verts = np.concatenate(verts)  # 4 rows: front-bottom, front-top, back-bottom, back-top
    front = _grid_faces(2, cols, wrap=False)
    back = _grid_faces(2, cols, wrap=False)[:, ::-1] + 2 * cols
    lower = np.array([[0 * cols + c, 2 * cols + c, 0 * cols + c + 1] for c in range(cols - 1)]
                     + [[0 * cols + c + 1, 2 * cols + c, 2 * cols + c + 1]
                        for c in range(cols - 1)])
    upper_edge = np.array([[1 * cols + c, 1 * cols + c + 1, 3 * cols + c]
                           for c in range(cols - 1)]
                          + [[1 * cols + c + 1, 3 * cols + c + 1, 3 * cols + c]
                             for c in range(cols - 1)])
    faces = np.concatenate([front[:, ::-1], back, lower, upper_edge])
    n = len(verts)
    b.add(verts, faces, np.full(len(faces), REGION_ID["teeth"]),
          np.tile(ALBEDO["teeth"], (n, 1)), _one_hot(n, 1 if upper else 2))


def _eye(b: _Builder, side: int):
    """The visible cap of an eyeball around its gaze (+z), rings on the pupil and iris edges;
    the back, always inside the socket, is left out."""
    centre = EYE_CENTRES[side]
    rings = np.deg2rad([0.06, 9.0, 22.0, 34.0, 48.0, 63.0, 78.0, 94.0, EYE_CAP_DEGREES])
    _, faces, up = _sphere((0.0, 0.0, 0.0), 1.0, 0, 16, theta=rings)
    unit = np.stack([up[:, 0], -up[:, 2], up[:, 1]], -1)  # rotate the cap's axis from +y to +z
    verts = np.asarray(centre) + EYE_RADIUS * unit
    gaze = np.arccos(np.clip(unit[faces].mean(1)[:, 2] / np.linalg.norm(
        unit[faces].mean(1), axis=1), -1, 1))
    regions = np.full(len(faces), REGION_ID["sclera"])
    regions[gaze < IRIS_ANGLE] = REGION_ID["iris"]
    regions[gaze < PUPIL_ANGLE] = REGION_ID["pupil"]
    vgaze = np.arccos(np.clip(unit[:, 2], -1, 1))
    colors = np.tile(ALBEDO["sclera"], (len(verts), 1))
    colors[vgaze < IRIS_ANGLE + 0.03] = ALBEDO["iris"]
    colors[vgaze < PUPIL_ANGLE + 1e-6] = ALBEDO["pupil"]
    b.add(verts, faces, regions, colors, _one_hot(len(verts), 3 + side))


def _eyelid(b: _Builder, side: int):
    """Upper-lid cap over the eyeball; blinking stretches it down over the front."""
    centre = EYE_CENTRES[side]
    rows, cols = 14, 32
    theta = np.linspace(1e-3, LID_OPEN_ANGLE, rows)
    closed = theta * (LID_CLOSED_ANGLE / LID_OPEN_ANGLE)
    phi = np.linspace(-np.pi / 2, np.pi / 2, cols)  # front half: the back is inside the head

    def cap(th):
        t, p = np.meshgrid(th, phi, indexing="ij")
        u = np.stack([np.sin(t) * np.sin(p), np.cos(t), np.sin(t) * np.cos(p)], -1)
        return centre + EYE_RADIUS * LID_GAP * u.reshape(-1, 3)

    verts = cap(theta)
    faces = _grid_faces(rows, cols, wrap=False)
    n = len(verts)
    name = ("blink_left", "blink_right")[side]
    colors = np.tile(ALBEDO["skin"], (n, 1))
    b.add(verts, faces, np.full(len(faces), REGION_ID["skin"]), colors, _one_hot(n, 1),
          expr={name: cap(closed) - verts})


HEAD_KINDS = ("procedural", "makehuman")
# What the entry points use when no --head is given (the library's own calls default to the
# procedural head, the fast one for tests).
DEFAULT_KIND = "makehuman"


def make_head(kind: str = "procedural") -> tuple[FlameModel, HeadAssets]:
    """A built-in head as (FlameModel, HeadAssets); identity A is all-zero coefficients.

    kind: `procedural` (this module's) or `makehuman` (the MakeHuman base head with the 52 ARKit
    face units, `model/makehuman.py`)."""
    if kind == "makehuman":
        return makehuman.load()
    if kind != "procedural":
        raise ValueError(f"unknown head {kind!r}; built-in heads: {', '.join(HEAD_KINDS)}")
    b = _Builder()
    _skin(b)
    _mouth_cavity(b)
    _lip(b, upper=True)
    _lip(b, upper=False)
    _teeth(b, upper=True)
    _teeth(b, upper=False)
    eye_ranges = []
    for side in (0, 1):
        start = b.count
        _eye(b, side)
        eye_ranges.append((start, b.count))
        _eyelid(b, side)
    # Joint helpers: unreferenced vertices that pin the root, neck and jaw joints.
    helpers = b.add(np.stack([ROOT, NECK_PIVOT, JAW_PIVOT]), np.zeros((0, 3), np.int64), [],
                    np.zeros((3, 3)), np.stack([_one_hot(1, j)[0] for j in (0, 1, 2)]))
    verts = np.concatenate(b.verts)
    v = len(verts)
    j_reg = np.zeros((5, v))
    for j in range(3):
        j_reg[j, helpers + j] = 1.0
    for side, (s, e) in enumerate(eye_ranges):
        j_reg[3 + side, s:e] = 1.0 / (e - s)
    shapedirs = np.stack([np.concatenate(b.shape[n]) for n in SHAPE_NAMES], -1)
    exprdirs = np.stack([np.concatenate(b.expr[n]) for n in EXPR_NAMES], -1)
    model = FlameModel(
        v_template=jnp.asarray(verts, jnp.float32),
        shapedirs=jnp.asarray(shapedirs, jnp.float32),
        exprdirs=jnp.asarray(exprdirs, jnp.float32),
        posedirs=jnp.zeros((v, 3, 36), jnp.float32),
        j_regressor=jnp.asarray(j_reg, jnp.float32),
        lbs_weights=jnp.asarray(np.concatenate(b.weights), jnp.float32),
        faces=jnp.asarray(np.concatenate(b.faces), jnp.int32),
        parents=FLAME_PARENTS)
    assets = HeadAssets(face_regions=np.concatenate(b.regions).astype(np.int32),
                        vertex_colors=np.concatenate(b.colors).astype(np.float32),
                        expr_names=EXPR_NAMES, shape_names=SHAPE_NAMES)
    return model, assets


def expression(model: FlameModel, names: tuple = EXPR_NAMES, **coefficients) -> jnp.ndarray:
    """(E,) expression vector from named coefficients, e.g. expression(m, blink_left=1.0);
    `names`: the model's expression names (`HeadAssets.expr_names`)."""
    unknown = set(coefficients) - set(names)
    if unknown:
        raise ValueError(f"unknown expressions {sorted(unknown)}; known: {', '.join(names)}")
    return jnp.asarray([float(coefficients.get(n, 0.0)) for n in names], jnp.float32)


def identity(names: tuple = SHAPE_NAMES, **coefficients) -> jnp.ndarray:
    """(S,) shape vector from named coefficients, e.g. identity(head_width=0.5); `names`: the
    model's identity names (`HeadAssets.shape_names`)."""
    unknown = set(coefficients) - set(names)
    if unknown:
        raise ValueError(f"unknown shape directions {sorted(unknown)}; known: {', '.join(names)}")
    return jnp.asarray([float(coefficients.get(n, 0.0)) for n in names], jnp.float32)


def params(model: FlameModel, *, shape=None, expr=None, jaw_open: float = 0.0,
           rotation=(0.0, 0.0, 0.0), neck=(0.0, 0.0, 0.0), eyes=(0.0,) * 6,
           translation=(0.0, 0.0, 0.0)) -> FlameParams:
    """Convenience FlameParams for the head; `jaw_open` is the jaw's rotation in radians."""
    f = jnp.float32
    return FlameParams(
        shape=jnp.zeros(model.num_shape, f) if shape is None else jnp.asarray(shape, f),
        expr=jnp.zeros(model.num_expr, f) if expr is None else jnp.asarray(expr, f),
        rotation=jnp.asarray(rotation, f), neck=jnp.asarray(neck, f),
        jaw=jnp.asarray([jaw_open, 0.0, 0.0], f), eyes=jnp.asarray(eyes, f),
        translation=jnp.asarray(translation, f))
