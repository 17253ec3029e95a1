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
    "tongue": ("tongue",),
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


NEGATIONS = ("not", "don't", "dont", "never", "without", "no", "nothing", "except")


def _words(prompt: str) -> list:
    return re.findall(r"[a-z']+", prompt.lower())


def parse(prompt: str) -> Instruction:
    """The one edit `prompt` asks for: a region, a colour, optionally stripes.

    Refuses (ValueError, with the vocabulary) rather than guess: a prompt with no known region or
    colour, with two regions or two colours ("turn the lips blue and the hair white", "turn the
    blue lips red": run one edit per region), or with a negation ("don't make the lips red").
    A style prompt points to `--editor style`.
    """
    words = _words(prompt)
    regions = list(dict.fromkeys(r for w in words for r, names in REGION_WORDS.items()
                                 if w in names))
    colours = list(dict.fromkeys(w for w in words if w in COLOURS))
    negated = [w for w in words if w in NEGATIONS]
    problem = None
    if negated:
        problem = (f"it is negated ({negated[0]!r}); say what to change, not what to leave "
                   "alone")
    elif len(regions) > 1:
        problem = (f"it names {len(regions)} regions ({', '.join(regions)}); one edit changes "
                   "one region: run one edit per region")
    elif len(colours) > 1:
        problem = (f"it names {len(colours)} colours ({', '.join(colours)}); say only the new "
                   "colour")
    elif not regions or not colours:
        missing = [m for m, found in (("a region", regions), ("a colour", colours)) if not found]
        problem = f"it names no {' and no '.join(m[2:] for m in missing)} it knows"
        if _style_of(words) is not None:
            problem += " (it reads like a style: use --editor style)"
    if problem:
        raise ValueError(f"the semantic editor does not understand {prompt!r}: {problem}. It "
                         f"understands {vocabulary()}")
    return Instruction(regions[0], COLOURS[colours[0]], any(w in PATTERN_WORDS for w in words))


def stripe_on(y: np.ndarray, phase: float = 0.0) -> np.ndarray:
    """Where the stripes' colour goes, by head-space height y; `phase` shifts the stripes by
    that fraction of a period (1/2: the other half of the region)."""
    return np.sin(2 * np.pi * np.asarray(y) / STRIPE_PERIOD + 2 * np.pi * phase) > 0


def mode_of(instruction: Instruction, mode: int, modes: int) -> tuple[Instruction, float]:
    """Answer `mode` (0 .. modes - 1) of a `modes`-modal editor to `instruction`, and its
    stripes' phase. Stripes keep their colour and shift by mode / modes of a period (the other
    half of the region at 2 modes); a recolour keeps its region and takes one of `modes` shades
    of its colour, evenly from dark (mode 0) to light (`colour_shade`)."""
    if not 0 <= mode < modes:
        raise ValueError(f"mode must be in [0, {modes}), got {mode}")
    if instruction.stripes or modes == 1:
        return instruction, mode / modes
    shade = colour_shade(instruction.colour, mode / (modes - 1))
    return dataclasses.replace(instruction, colour=shade), 0.0


def colour_shade(colour, lightness: float) -> tuple:
    """`colour` at `lightness` in [0, 1]: 0 halves it (a dark shade), 1 takes it halfway to
    white (a light one), linear in between (0.5: the mean of the two, near the colour)."""
    c = np.asarray(colour, np.float64)
    dark, light = 0.5 * c, c + 0.5 * (1.0 - c)
    return tuple(float(v) for v in (1.0 - lightness) * dark + lightness * light)


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
                 rest_vertices, phase: float = 0.0) -> np.ndarray:
    """(V, 3) vertex albedo with the instruction applied exactly (the ground-truth edit);
    `phase`: the stripes' (see `stripe_on`)."""
    albedo = np.asarray(albedo, np.float64).copy()
    mask = region_vertices(faces, face_regions, instruction.region, len(albedo))
    if instruction.stripes:
        mask &= stripe_on(np.asarray(rest_vertices)[:, 1], phase)
    albedo[mask] = instruction.colour
    return albedo


STYLE_WORDS = {
    "oil": ("oil",),
    "sketch": ("pencil", "sketch", "drawing"),
    "cartoon": ("cartoon", "comic", "toon"),
    "stylise": ("stylise", "stylize", "stylised", "stylized", "watercolour", "watercolor",
                "painting", "painted"),
}


def _style_of(words) -> str | None:
    for style, names in STYLE_WORDS.items():
        if any(w in names for w in words):
            return style
    return None


def parse_style(prompt: str) -> str:
    """The style named in the prompt (whole words: "spoil" is not "oil"); ValueError listing the
    known ones otherwise."""
    style = _style_of(_words(prompt))
    if style is None:
        known = "; ".join(f"{s}: {', '.join(w)}" for s, w in STYLE_WORDS.items())
        raise ValueError(f"the style editor does not understand {prompt!r}. It knows: {known}")
    return style


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
