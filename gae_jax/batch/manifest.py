"""A batch manifest (TOML) read into jobs.

    [defaults]                      # optional: what every job takes unless it says otherwise
    iterations = 100

    [[jobs]]                        # one entry; a list value expands it (a grid)
    name = "colours"                # optional: the jobs' folder prefix
    prompt = ["turn the lips blue", "make the hair ginger"]
    seed = [0, 1]                   # -> 4 jobs
    preset = "fast"                 # any `edit.config.PRESETS` name
    head = "makehuman"              # any SceneConfig field: data, flame_model, size, ...
    avatar = ""                     # a GaussianAvatars avatar folder (empty: reconstruct)
    video = true

Every other key is an `EditConfig` field. Errors are one line naming the job and the field.
"""

from __future__ import annotations

import dataclasses
import itertools
import os
import re
import tomllib

from gae_jax.edit import config as edit_config
from gae_jax.edit.config import EditConfig
from gae_jax.scene.load import SceneConfig

JOB_KEYS = ("name", "preset", "avatar", "video")  # keys that are neither config's fields
FOLDER_FIELDS = ("data", "avatar")  # must be folders when given
FILE_FIELDS = ("flame_model", "flame_masks")  # must be files when given


class ManifestError(ValueError):
    """A manifest that cannot be run; the message names the job and the field."""


@dataclasses.dataclass(frozen=True)
class Job:
    """One edit of a batch: its folder name, scene, edit settings, input avatar (a folder or
    "" to reconstruct) and whether to write the video."""

    name: str
    scene: SceneConfig
    config: EditConfig
    avatar: str = ""
    video: bool = True

    def describe(self) -> dict:
        """The job as JSON-able settings (what `summary.json` and the job's folder record)."""
        return dict(name=self.name, scene=dataclasses.asdict(self.scene),
                    config=dataclasses.asdict(self.config), avatar=self.avatar,
                    video=self.video)

    @classmethod
    def from_description(cls, d: dict) -> "Job":
        return cls(d["name"], SceneConfig(**d["scene"]), EditConfig(**d["config"]),
                   d["avatar"], d["video"])


def read(path: str) -> list:
    """The jobs of the manifest at `path`, in order; ManifestError on anything unusable."""
    try:
        with open(path, "rb") as f:
            blob = tomllib.load(f)
    except FileNotFoundError:
        raise ManifestError(f"{path}: no such file") from None
    except tomllib.TOMLDecodeError as e:
        raise ManifestError(f"{path}: not TOML ({e})") from None
    unknown = set(blob) - {"defaults", "jobs"}
    if unknown:
        raise ManifestError(f"{path}: unknown table {sorted(unknown)[0]!r} (a manifest has "
                            "[defaults] and [[jobs]])")
    entries = blob.get("jobs")
    if not isinstance(entries, list) or not entries:
        raise ManifestError(f"{path}: no [[jobs]] entry")
    defaults = blob.get("defaults", {})
    jobs, base = [], os.path.dirname(os.path.abspath(path))
    for index, entry in enumerate(entries):
        label = entry.get("name", f"job {index + 1}")
        jobs += expand({**defaults, **entry}, label, index, base)
    names = [j.name for j in jobs]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ManifestError(f"{path}: two jobs are named {twice[0]!r}; give the entries "
                            "distinct names")
    return jobs


def expand(entry: dict, label: str, index: int, base: str) -> list:
    """The jobs of one [[jobs]] entry: the cartesian product of its list values."""
    grid = {k: v for k, v in entry.items() if isinstance(v, list)}
    for key, values in grid.items():
        if not values:
            raise ManifestError(f"job {label!r}: {key}: an empty list")
    jobs = []
    for combo in itertools.product(*grid.values()):
        values = dict(entry, **dict(zip(grid, combo)))
        suffix = "_".join(_slug(f"{k}{v}" if not isinstance(v, str) else v)
                          for k, v in zip(grid, combo))
        prefix = entry.get("name") or f"job{index + 1}"
        jobs.append(_job(values, label, "_".join(filter(None, [_slug(prefix), suffix])), base))
    return jobs


def _job(values: dict, label: str, name: str, base: str) -> Job:
    scene_fields = {f.name: f for f in dataclasses.fields(SceneConfig)}
    edit_fields = {f.name: f for f in dataclasses.fields(EditConfig)}
    for key in values:
        if key not in scene_fields and key not in edit_fields and key not in JOB_KEYS:
            raise ManifestError(f"job {label!r}: unknown field {key!r}")
    where = f"job {label!r}"
    for key, value in values.items():
        field = scene_fields.get(key) or edit_fields.get(key)
        expected = str if key in ("name", "preset", "avatar") else bool if key == "video" else (
            TYPES[field.type])
        if not _type_ok(value, expected):
            raise ManifestError(f"{where}: {key}: {value!r} is not {TYPE_NAMES[expected]}")
    for key in FOLDER_FIELDS + FILE_FIELDS:
        if values.get(key):
            values[key] = os.path.join(base, values[key])
            exists = os.path.isdir if key in FOLDER_FIELDS else os.path.isfile
            if not exists(values[key]):
                raise ManifestError(f"{where}: {key}: {values[key]}: no such "
                                    f"{'folder' if key in FOLDER_FIELDS else 'file'}")
    try:
        scene = SceneConfig(**{k: v for k, v in values.items() if k in scene_fields})
        config = edit_config.preset(values.get("preset", "fast"),
                                    **{k: v for k, v in values.items() if k in edit_fields})
    except ValueError as e:
        raise ManifestError(f"{where}: {e}") from None
    if values.get("avatar") and not os.path.isfile(os.path.join(values["avatar"],
                                                                "point_cloud.ply")):
        raise ManifestError(f"{where}: avatar: {values['avatar']}: no point_cloud.ply")
    return Job(name, scene, config, values.get("avatar", ""), values.get("video", True))


TYPES = {"int": int, "float": float, "str": str, "bool": bool}  # the config fields' types
TYPE_NAMES = {int: "an integer", float: "a number", str: "a string", bool: "true or false"}


def _type_ok(value, expected) -> bool:
    if expected is bool:
        return isinstance(value, bool)
    if expected is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if expected is int:
        return isinstance(value, int) and not isinstance(value, bool)
    return isinstance(value, expected)


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9.]+", "-", text).strip("-").lower()
