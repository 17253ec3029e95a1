"""Colour names as people use them, and the modifiers that shift them.

`lookup(words)` reads the longest colour name at the start of a word list. Names come from three
tables, the first that has a name wins:
  * `BASE`: the project's own eleven mid-tones ("blue", "red", ...), kept so that the showcase
    prompts mean what they always meant;
  * `HAIR`: hair colours no general table has ("blonde", "platinum", "ginger", "brunette", ...);
  * matplotlib's 949 XKCD colour-survey names ("navy blue", "teal", "crimson", "lipstick red":
    what people called a colour; "/" and "-" read as spaces) and then its 148 CSS4 names
    ("cornflowerblue", written as one word as CSS does).
`modify(rgb, modifier)` applies "light", "pale", "dark", "bright", ... when the modified name is
not in a table itself ("light blue" is XKCD's; "light crimson" is crimson lightened).
RGB values are floats in [0, 1], sRGB as the tables give them.
"""

from __future__ import annotations

import functools

import numpy as np

BASE = {
    "blue": (0.12, 0.28, 0.85), "red": (0.85, 0.10, 0.10), "green": (0.15, 0.70, 0.20),
    "white": (0.95, 0.95, 0.95), "black": (0.05, 0.05, 0.05), "yellow": (0.95, 0.85, 0.15),
    "purple": (0.55, 0.20, 0.70), "pink": (0.95, 0.50, 0.70), "orange": (0.95, 0.50, 0.10),
    "gold": (0.85, 0.68, 0.20), "silver": (0.75, 0.75, 0.78),
}
HAIR = {
    "blonde": (0.90, 0.78, 0.50), "blond": (0.90, 0.78, 0.50),
    "platinum": (0.90, 0.89, 0.83), "platinum blonde": (0.90, 0.89, 0.83),
    "ash blonde": (0.78, 0.74, 0.62), "strawberry blonde": (0.88, 0.62, 0.42),
    "ginger": (0.78, 0.36, 0.13), "brunette": (0.36, 0.23, 0.14), "chestnut": (0.45, 0.24, 0.12),
    "jet black": (0.03, 0.03, 0.04), "raven": (0.06, 0.06, 0.09),
}
SPELLINGS = {"gray": "grey", "colour": "color"}  # read as the tables spell them
MODIFIERS = {
    "light": "light", "lighter": "light", "pale": "pale", "pastel": "pale", "dark": "dark",
    "darker": "dark", "deep": "dark", "bright": "bright", "brighter": "bright", "vivid": "bright",
    "vibrant": "bright", "neon": "bright", "dull": "dull", "muted": "dull",
}
LUMA = np.array([0.299, 0.587, 0.114])


@functools.lru_cache(maxsize=1)
def table() -> dict:
    """name -> (r, g, b) for every known colour name (lower case, words separated by spaces)."""
    import matplotlib.colors as mcolors

    names: dict = {}
    for name, value in list(mcolors.CSS4_COLORS.items()) + list(mcolors.XKCD_COLORS.items()):
        key = name.removeprefix("xkcd:").replace("/", " ").replace("-", " ")
        names[key] = tuple(float(v) for v in mcolors.to_rgb(value))
    names.update({k: tuple(v) for k, v in HAIR.items()})
    names.update({k: tuple(v) for k, v in BASE.items()})
    return names


def normalise(word: str) -> str:
    return SPELLINGS.get(word, word)


@functools.lru_cache(maxsize=1)
def longest_name() -> int:
    return max(len(k.split()) for k in table())


def lookup(words: list) -> tuple[str, tuple] | None:
    """(name, rgb) of the longest colour name that `words` (lower case) start with, or None."""
    words = [normalise(w) for w in words]
    names = table()
    for n in range(min(len(words), longest_name()), 0, -1):
        name = " ".join(words[:n])
        if name in names:
            return name, names[name]
    return None


def modify(rgb, modifier: str) -> tuple:
    """`rgb` under a modifier word (a key of `MODIFIERS`):
    light: halfway to white; pale: 70 % to a light grey of its own luminance, then a quarter to
    white (less saturated than light); dark: 55 % of itself; bright: stretched away from its
    grey so the largest channel reaches 1; dull: 60 % of the way to its own grey."""
    c = np.asarray(rgb, np.float64)
    kind = MODIFIERS[modifier]
    grey = float(c @ LUMA)
    if kind == "light":
        out = c + 0.5 * (1.0 - c)
    elif kind == "pale":
        out = 0.3 * c + 0.7 * max(grey, 0.8)
        out = out + 0.25 * (1.0 - out)
    elif kind == "dark":
        out = 0.55 * c
    elif kind == "bright":
        spread = c - grey
        top = float(np.max(c))
        out = grey + 1.6 * spread
        out = out / max(float(np.max(out)), 1e-6) * max(top, 0.9) if top > 0 else out
    else:
        out = c + 0.6 * (grey - c)
    return tuple(float(v) for v in np.clip(out, 0.0, 1.0))
