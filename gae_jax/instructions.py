"""Instructions: what an edit prompt asks for, its ideal 3D counterpart, and CLIP captions.

Two vocabularies, one per built-in editor:
  * semantic -- one region and one colour, optionally as stripes: "turn the lips navy blue",
    "make the hair blonde", "make her lipstick red", "make the skin pale", "add green stripes to
    the skin". `parse` returns an `Instruction`, whose ideal edit (`ideal_albedo`) recolours the
    mesh's vertex albedo exactly;
  * style -- "make it an oil painting", "a pencil sketch", ...; `parse_style` names the style.
    Styles have no ideal 3D counterpart.

Reading a semantic prompt: every word must be understood. Region words and their synonyms
(`REGION_WORDS`, `REGION_PHRASES`: "lipstick" and "mouth" are the lips, "face" the skin, "eyes" the
irises, "the whites of the eyes" the sclera); colour names from `colours` (the project's eleven,
hair colours, XKCD's 949 and CSS4's 148 names, longest name first: "navy blue"); modifiers
("light", "pale", "dark", "bright", ...) of the colour that follows, or of the region's own colour
when no colour is named ("make the skin pale"); the pattern "stripes"; and words that ask for
nothing (`FILLER`: "turn", "make", "the", "her", "please", ...). Anything else is refused with the
reason -- a shape or size ("thick"), something the head lacks ("a beard"), a part of a region
("the nose"), a pattern other than stripes, an unknown word -- never dropped. Both raise
ValueError listing the vocabulary when a prompt is not understood.
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np

from gae_jax import colours
from gae_jax.model import head

REGION_WORDS = {
    "lips": ("lips", "lip", "lipstick", "mouth"),
    "hair": ("hair", "hairs"),
    "skin": ("skin", "face", "complexion"),
    "iris": ("eyes", "eye", "iris", "irises"),
    "brows": ("eyebrows", "eyebrow", "brows", "brow"),
    "sclera": ("sclera", "scleras", "sclerae"),
    "pupil": ("pupils", "pupil"),
    "teeth": ("teeth", "tooth"),
    "tongue": ("tongue",),
}
# Phrases read as one region word before the words are split (regex -> region).
REGION_PHRASES = {
    r"\b(whites?|white parts?) of (the |her |his |their )?eyes?\b": "sclera",
    r"\beye ?whites?\b": "sclera",
    r"\b(inside|interior) (of )?(the |her |his |their )?mouth\b": "mouth",
    r"\bmouth cavity\b": "mouth",
    r"\beye colou?r\b": "iris",
    r"\bhair colou?r\b": "hair",
    r"\bskin colou?r\b": "skin",
}
COLOURS = colours.BASE  # the project's own names (kept for code that names a base colour)
PATTERN_WORDS = ("stripes", "striped", "stripe", "stripy", "stripey")
STRIPE_PERIOD = 0.02  # head-space metres along y (about ten stripes over the head)
NEGATIONS = ("not", "don't", "dont", "never", "without", "no", "nothing", "except")
FILLER = frozenset("""
    turn turned make made paint painted colour color coloured colored dye dyed change changed
    give recolour recolor recoloured recolored tint tinted set put apply add adding let render
    the a an his her their its my your our him them it to into in on of with over across
    please be is are all both so that this those these they look looks like and some very
    really nice lovely beautiful pretty fully entirely completely whole shade hue tone person
    man woman girl boy lady guy avatar head she he one ones up now just bit little slightly
""".split())
UNSUPPORTED = {
    "a change of shape or size": """thick thicker thin thinner long longer short shorter big
        bigger small smaller large larger wide wider narrow narrower full fuller plump plumper
        curly wavy straight spiky messy bald shaved puffy swollen shape size volume""".split(),
    "something this head does not have": """beard moustache mustache stubble goatee glasses
        sunglasses hat cap earring earrings piercing piercings tattoo tattoos scar scars
        freckles wrinkles mole makeup horns crown mask veil""".split(),
    "a change of expression, age or identity": """smile smiling frown frowning angry happy sad
        surprised older younger old young age aged elderly child baby""".split(),
    "removing something": "remove delete erase hide cut shave".split(),
    "a pattern other than stripes": """spots spotted dots dotted polka checks checked
        checkered plaid pattern patterned zigzag stars flowers gradient""".split(),
}
BODY_PARTS = """nose nostrils ears ear cheeks cheek forehead chin neck jaw eyelids eyelid
    eyelashes eyelash lashes gums nails scalp temples""".split()


@dataclasses.dataclass(frozen=True)
class Instruction:
    region: str  # a key of REGION_WORDS (a `head.REGIONS` name)
    colour: tuple
    stripes: bool = False
    colour_name: str = dataclasses.field(default="", compare=False)  # as the prompt said it


def vocabulary() -> str:
    regions = ", ".join(f"{r} ({'/'.join(w)})" for r, w in REGION_WORDS.items())
    return (f"regions: {regions}, the whites of the eyes (sclera), the inside of the mouth; "
            f"colours: {len(colours.table())} names (e.g. navy blue, teal, crimson, blonde, "
            f"lipstick red: XKCD and CSS4 names); modifiers: {', '.join(sorted(set(colours.MODIFIERS)))}; "
            "pattern: stripes. Examples: 'turn the lips blue', 'make the hair blonde', "
            "'give her dark green eyes', 'make the skin pale', 'add green stripes to the skin'")


def _words(prompt: str) -> list:
    """Lower-case words ("-" and "/" read as spaces); region phrases become one token
    `<region>`."""
    text = prompt.lower().replace("\u2019", "'")
    for pattern, region in REGION_PHRASES.items():
        text = re.sub(pattern, f" <{region}> ", text)
    words = re.findall(r"<[a-z]+>|[a-z0-9][a-z0-9'%.]*[a-z0-9%]|[a-z0-9]",
                       text.replace("-", " ").replace("/", " "))
    return words


def _region_of(word: str) -> str | None:
    if word.startswith("<"):
        return word[1:-1]
    return next((r for r, names in REGION_WORDS.items() if word in names), None)


def _read(words: list) -> dict:
    """What the words ask: regions, colours (name, rgb), modifiers left over, stripes, and
    what cannot be done (unsupported, body parts, unknown, negations)."""
    found = dict(regions=[], colours=[], modifier=None, stripes=False, unsupported=[],
                 parts=[], unknown=[], negated=[])
    i = 0
    while i < len(words):
        named = colours.lookup(words[i:])
        w = words[i][:-2] if words[i].endswith("'s") else words[i]  # "her face's colour"
        region = _region_of(w)
        # A region word that starts a colour name is that colour once a region is named:
        # "turn the lips lipstick red", "make the skin iris".
        if region is not None and not (found["regions"] and named is not None):
            if region not in found["regions"]:
                found["regions"].append(region)
            i += 1
            continue
        if w in NEGATIONS:
            found["negated"].append(w)
            i += 1
            continue
        if w in colours.MODIFIERS and (named is None or len(named[0].split()) == 1):
            following = colours.lookup(words[i + 1:])
            if following is not None:  # "light crimson": the modifier applied to the colour
                n = len(following[0].split())
                found["colours"].append((f"{w} {following[0]}",
                                         colours.modify(following[1], w)))
                i += 1 + n
            else:  # "make the skin pale": the region's own colour, modified
                found["modifier"] = w
                i += 1
            continue
        if named is not None:
            found["colours"].append(named)
            i += len(named[0].split())
            continue
        if w in PATTERN_WORDS:
            found["stripes"] = True
        elif any(w in words_ for words_ in UNSUPPORTED.values()):
            found["unsupported"].append(w)
        elif w in BODY_PARTS:
            found["parts"].append(w)
        elif w not in FILLER and _style_of([w]) is None:
            found["unknown"].append(w)
        i += 1
    return found


def parse(prompt: str) -> Instruction:
    """The one edit `prompt` asks for: a region, a colour, optionally stripes.

    Refuses (ValueError, with the reason and the vocabulary) rather than guess or drop a word: a
    prompt with no known region or colour, with two regions or two colours ("turn the lips blue
    and the hair white", "turn the blue lips red": run one edit per region), with a negation
    ("don't make the lips red"), or asking what the editor cannot do ("make the eyebrows white
    and thick", "add a beard", "paint the nose red", "add spots"). A style prompt points to
    `--editor style`.
    """
    words = _words(prompt)
    f = _read(words)
    regions, named = f["regions"], f["colours"]
    problem = None
    if f["negated"]:
        problem = (f"it is negated ({f['negated'][0]!r}); say what to change, not what to leave "
                   "alone")
    elif f["unsupported"]:
        w = f["unsupported"][0]
        what = next(k for k, v in UNSUPPORTED.items() if w in v)
        problem = (f"it asks for {w!r}, {what}, which the semantic editor cannot do: it "
                   "recolours one region or paints stripes on it")
    elif f["parts"]:
        problem = (f"{f['parts'][0]!r} is not a region of its own on this head (it is part of "
                   "the skin); the editor recolours whole regions")
    elif f["unknown"]:
        problem = (f"it does not know the word{'s' if len(f['unknown']) > 1 else ''} "
                   f"{', '.join(repr(w) for w in f['unknown'])}")
    elif len(regions) > 1:
        problem = (f"it names {len(regions)} regions ({', '.join(regions)}); one edit changes "
                   "one region: run one edit per region")
    elif len(named) > 1:
        problem = (f"it names {len(named)} colours ({', '.join(n for n, _ in named)}); say "
                   "only the new colour")
    elif not regions or not (named or f["modifier"]):
        missing = [m for m, ok in (("a region", regions), ("a colour", named or f["modifier"]))
                   if not ok]
        problem = f"it names no {' and no '.join(m[2:] for m in missing)} it knows"
        if _style_of(words) is not None:
            problem += " (it reads like a style: use --editor style)"
    if problem:
        raise ValueError(f"the semantic editor does not understand {prompt!r}: {problem}. It "
                         f"understands {vocabulary()}")
    region = regions[0]
    if named:
        name, rgb = named[0]
        if f["modifier"]:  # "make the lips dark, blue": the modifier before another word
            name, rgb = f"{f['modifier']} {name}", colours.modify(rgb, f["modifier"])
    else:
        name, rgb = f["modifier"], colours.modify(head.ALBEDO[region], f["modifier"])
    return Instruction(region, tuple(float(v) for v in rgb), f["stripes"], name)


def stripe_on(y: np.ndarray, phase: float = 0.0) -> np.ndarray:
    """Where the stripes' colour goes, by head-space height y; `phase` shifts the stripes by
    that fraction of a period (1/2: the other half of the region)."""
    return np.sin(2 * np.pi * np.asarray(y) / STRIPE_PERIOD + 2 * np.pi * phase) > 0


def stripe_distance(y: np.ndarray, pixel: np.ndarray, phase: float = 0.0) -> np.ndarray:
    """Signed distance in pixels from each pixel's centre to the nearest stripe edge (positive on
    a stripe, as `stripe_on` decides): (H, W) head-space heights `y`, (H, W) `pixel`, the height
    one pixel spans there (|grad y|). Its clip(d + 1/2, 0, 1) is the share of the pixel a
    straight stripe edge leaves on the stripe, as a supersampled render of the stripes has
    (exact for a pixel narrower than a stripe, STRIPE_PERIOD / 2, across which y is linear)."""
    u = np.mod(np.asarray(y, np.float64) / STRIPE_PERIOD + phase, 1.0)
    on = u < 0.5
    half = np.mod(u, 0.5)
    edge = STRIPE_PERIOD * np.minimum(half, 0.5 - half)
    return (np.where(on, edge, -edge) / np.maximum(pixel, 1e-9)).astype(np.float32)


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


def stripe_shader(instruction: Instruction, face_regions, phase: float = 0.0):
    """The ideal stripes decided per ray, not per vertex: a `raycast_views` shader of (V, 7)
    values [shaded colour (3), shaded stripe colour (3), rest-pose height y (1)] that takes the
    stripe colour where the hit face is the instruction's region and the height interpolated
    at the hit is on a stripe (`stripe_on`); the mesh's vertices are about as far apart as a
    stripe is wide, so stripes painted on vertices would be a blur of the mesh."""
    inside = np.asarray(face_regions) == head.REGION_ID[instruction.region]

    def shade(values, faces):
        on = inside[faces] & stripe_on(values[:, 6], phase)
        return np.where(on[:, None], values[:, 3:6], values[:, :3])

    return shade


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
        region = {"iris": "eyes", "sclera": "whites of the eyes", "mouth": "inside of the mouth",
                  "pupil": "pupils", "brows": "eyebrows"}.get(ins.region, ins.region)
        what = (f"{ins.colour_name} stripes on the {region}" if ins.stripes
                else f"{ins.colour_name} {region}")
        return SOURCE_CAPTION, f"a photo of a person's face with {what}"
    except ValueError:
        pass
    try:
        return SOURCE_CAPTION, STYLE_CAPTIONS[parse_style(prompt)]
    except ValueError:
        return SOURCE_CAPTION, f"{SOURCE_CAPTION}, {prompt}"
