"""Instructions: what an edit prompt asks for, its ideal 3D counterpart, and CLIP captions.

Two vocabularies, one per built-in editor:
  * semantic -- a region word, a colour word and optionally "stripes" ("turn the lips blue",
    "make the hair white", "add green stripes to the skin"); `parse` returns an `Instruction`,
    whose ideal edit (`ideal_albedo`) recolours the mesh's vertex albedo exactly;
  * style -- "make it an oil painting", "a pencil sketch", ...; `parse_style` names the style.
    Styles have no ideal 3D counterpart.
Both raise ValueError listing the vocabulary when a prompt is not understood.
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np

from gae_jax.model import head

REGION_WORDS = {
    "lips": ("lips", "lip"),
    "hair": ("hair",),
    "skin": ("skin", "face"),
    "iris": ("eyes", "eye", "iris", "irises"),
    "brows": ("eyebrows", "eyebrow", "brows"),
    "teeth": ("teeth",),
}
COLOURS = {
    "blue": (0.12, 0.28, 0.85), "red": (0.85, 0.10, 0.10), "green": (0.15, 0.70, 0.20),
    "white": (0.95, 0.95, 0.95), "black": (0.05, 0.05, 0.05), "yellow": (0.95, 0.85, 0.15),
    "purple": (0.55, 0.20, 0.70), "pink": (0.95, 0.50, 0.70), "orange": (0.95, 0.50, 0.10),
    "gold": (0.85, 0.68, 0.20), "silver": (0.75, 0.75, 0.78),
}
PATTERN_WORDS = ("stripes", "striped", "stripe")
STRIPE_PERIOD = 0.02  # head-space metres along y (about ten stripes over the head)


@dataclasses.dataclass(frozen=True)
class Instruction:
    region: str  # a key of REGION_WORDS (a `head.REGIONS` name)
    colour: tuple
    stripes: bool = False


def vocabulary() -> str:
    regions = ", ".join(w for words in REGION_WORDS.values() for w in words)
    return (f"regions: {regions}; colours: {', '.join(COLOURS)}; pattern: stripes. Examples: "
            "'turn the lips blue', 'make the hair white', 'give her red eyes', "
            "'add green stripes to the skin'")


def parse(prompt: str) -> Instruction:
    """The instruction in `prompt`; ValueError (with the vocabulary) when it is not understood."""
    words = re.findall(r"[a-z]+", prompt.lower())
    region = next((r for w in words for r, names in REGION_WORDS.items() if w in names), None)
    colour = next((COLOURS[w] for w in words if w in COLOURS), None)
    if region is None or colour is None:
        missing = "a region" if region is None else "a colour"
        raise ValueError(f"the semantic editor does not understand {prompt!r} (no {missing} it "
                         f"knows). It understands {vocabulary()}")
    return Instruction(region, colour, any(w in PATTERN_WORDS for w in words))


def stripe_on(y: np.ndarray) -> np.ndarray:
    """Where the stripes' colour goes, by head-space height y."""
    return np.sin(2 * np.pi * np.asarray(y) / STRIPE_PERIOD) > 0


def region_vertices(faces: np.ndarray, face_regions: np.ndarray, region: str,
                    num_vertices: int) -> np.ndarray:
    """(V,) bool: vertices at least half of whose faces belong to `region` (none if unused)."""
    faces = np.asarray(faces)
    num = num_vertices
    inside = np.repeat(np.asarray(face_regions) == head.REGION_ID[region], 3)
    hits = np.bincount(faces.ravel(), weights=inside, minlength=num)
    total = np.bincount(faces.ravel(), minlength=num)
    return (total > 0) & (hits >= 0.5 * total)


def ideal_albedo(instruction: Instruction, albedo: np.ndarray, faces, face_regions,
                 rest_vertices) -> np.ndarray:
    """(V, 3) vertex albedo with the instruction applied exactly (the ground-truth edit)."""
    albedo = np.asarray(albedo, np.float64).copy()
    mask = region_vertices(faces, face_regions, instruction.region, len(albedo))
    if instruction.stripes:
        mask &= stripe_on(np.asarray(rest_vertices)[:, 1])
    albedo[mask] = instruction.colour
    return albedo


STYLE_WORDS = {
    "oil": ("oil",),
    "sketch": ("pencil", "sketch", "drawing"),
    "cartoon": ("cartoon", "comic", "toon"),
    "stylise": ("stylise", "stylize", "stylised", "stylized", "watercolour", "watercolor",
                "painting", "painted"),
}


def parse_style(prompt: str) -> str:
    """The style named in the prompt; ValueError listing the known ones otherwise."""
    text = prompt.lower()
    for style, words in STYLE_WORDS.items():
        if any(w in text for w in words):
            return style
    known = "; ".join(f"{s}: {', '.join(w)}" for s, w in STYLE_WORDS.items())
    raise ValueError(f"the style editor does not understand {prompt!r}. It knows: {known}")


SOURCE_CAPTION = "a photo of a person's face"
STYLE_CAPTIONS = {
    "oil": "an oil painting of a person's face",
    "sketch": "a pencil sketch of a person's face",
    "cartoon": "a cartoon of a person's face",
    "stylise": "a watercolour painting of a person's face",
}


def captions(prompt: str) -> tuple:
    """(source, target) captions for CLIP-S, derived from an instruction."""
    try:
        ins = parse(prompt)
        colour = next(n for n, rgb in COLOURS.items() if tuple(rgb) == tuple(ins.colour))
        what = (f"{colour} stripes on the {ins.region}" if ins.stripes
                else f"{colour} {ins.region}")
        return SOURCE_CAPTION, f"a photo of a person's face with {what}"
    except ValueError:
        pass
    try:
        return SOURCE_CAPTION, STYLE_CAPTIONS[parse_style(prompt)]
    except ValueError:
        return SOURCE_CAPTION, f"{SOURCE_CAPTION}, {prompt}"
