"""The run folder: its one writer and one reader, the only code that knows its file names.

A run folder of `python -m gae_jax.train` holds:
  metrics.json            the config, scene settings, timings, scores, tile capacity
  evaluation_set.npz      per protocol: posed meshes, cameras, truth and region labels
  original_avatar/, edited_avatar/   GaussianAvatars folders (point_cloud.ply, flame_param.npz)
  edited_posed.ply        the edited avatar posed at one frame, in world space (3DGS viewers)
  motion.npz              the scene's sequences and identities (the viewer's player)
  grid.png, reenactment.mp4          for people
  evaluation.json, evaluation.md     written by `python -m gae_jax.evaluate`
  edit_checkpoint.npz     while a run is unfinished (or kept)
  screenshots/            the viewer's
  job.json                a batch job's settings (`python -m gae_jax.batch`)
"""

from __future__ import annotations

import dataclasses
import json
import os

from gae_jax.edit.config import EditConfig, StepConfig
from gae_jax.edit.edit import CHECKPOINT
from gae_jax.evaluation import truth
from gae_jax.model import avatar_io
from gae_jax.model.avatar import Avatar
from gae_jax.render import wabe
from gae_jax.scene import motion_io
from gae_jax.scene.load import SceneConfig
from gae_jax.util.fileio import atomic_write_bytes

METRICS = "metrics.json"
EVALUATION = ("evaluation.json", "evaluation.md")
AVATARS = {"original": "original_avatar", "edited": "edited_avatar"}
POSED = "edited_posed.ply"
GRID = "grid.png"
VIDEO = "reenactment.mp4"
SCREENSHOTS = "screenshots"
JOB = "job.json"
AVATAR_FILE = "point_cloud.ply"


def path(run_dir: str, name: str) -> str:
    """The path of the run's `name`: "metrics", "grid", "video", "posed", "evaluation_set",
    "motion", "checkpoint", "screenshots", or an avatar folder ("original", "edited")."""
    names = dict(metrics=METRICS, grid=GRID, video=VIDEO, posed=POSED, screenshots=SCREENSHOTS,
                 job=JOB,
                 evaluation_set=truth.FILE_NAME, motion=motion_io.FILE_NAME,
                 checkpoint=CHECKPOINT, **AVATARS)
    if name not in names:
        raise KeyError(f"a run folder has no {name!r}; it has {sorted(names)}")
    return os.path.join(run_dir, names[name])


def write_metrics(run_dir: str, metrics: dict) -> None:
    atomic_write_bytes(path(run_dir, "metrics"), json.dumps(metrics, indent=1).encode())


def write_job(run_dir: str, description: dict) -> None:
    """The settings of the batch job this folder is the run of."""
    atomic_write_bytes(path(run_dir, "job"), json.dumps(description, indent=1).encode())


def read_job(run_dir: str) -> dict | None:
    """What `write_job` wrote into `run_dir`, or None; ValueError naming an unreadable file."""
    job_path = path(run_dir, "job")
    if not os.path.isfile(job_path):
        return None
    try:
        with open(job_path) as f:
            return json.load(f)
    except json.JSONDecodeError as e:
        raise ValueError(f"{job_path}: unreadable ({e})") from None


def write_evaluation(run_dir: str, results: dict, table: str) -> None:
    """`evaluate`'s scores (JSON) and their summary table (Markdown)."""
    atomic_write_bytes(os.path.join(run_dir, EVALUATION[0]),
                       json.dumps(results, indent=1).encode())
    atomic_write_bytes(os.path.join(run_dir, EVALUATION[1]), (table + "\n").encode())


@dataclasses.dataclass(frozen=True)
class Run:
    """What a finished run folder says about its run: where it is, the edit's config and scene
    settings, the tile capacity and blend it trained with, and the metrics as written."""

    folder: str
    config: EditConfig
    scene: SceneConfig
    tile_capacity: int
    blend: wabe.Blend
    metrics: dict

    def avatar_folder(self, which: str) -> str:
        """The GaussianAvatars folder of the "original" or "edited" avatar; FileNotFoundError
        naming it when it holds no point_cloud.ply."""
        folder = path(self.folder, which)
        if not os.path.isfile(os.path.join(folder, AVATAR_FILE)):
            raise FileNotFoundError(f"{folder}: no {AVATAR_FILE} (the run did not finish?)")
        return folder

    def avatars(self, face_regions) -> dict:
        """{"original", "edited": Avatar} bound with `face_regions`; ValueError when their
        Gaussian counts differ."""
        out = {w: avatar_io.load_bound_avatar(
            os.path.join(self.avatar_folder(w), AVATAR_FILE), face_regions) for w in AVATARS}
        if out["edited"].num != out["original"].num:
            raise ValueError(f"{self.folder}: the edited avatar has {out['edited'].num} "
                             f"Gaussians, the original {out['original'].num}")
        return out

    def evaluation_set(self) -> truth.EvalSet:
        return truth.load(path(self.folder, "evaluation_set"))

    def motion_file(self) -> str | None:
        """The run's motion.npz, or None when the run predates it."""
        motion = path(self.folder, "motion")
        return motion if os.path.isfile(motion) else None


def read(run_dir: str) -> Run:
    """The run written into `run_dir`; NotADirectoryError / FileNotFoundError / ValueError in
    one line naming what is missing or unreadable."""
    if not os.path.isdir(run_dir):
        raise NotADirectoryError(f"{run_dir}: no such folder")
    metrics_path = path(run_dir, "metrics")
    if not os.path.isfile(metrics_path):
        raise FileNotFoundError(f"{metrics_path} not found; is {run_dir!r} a run folder of "
                                "python -m gae_jax.train that finished?")
    try:
        with open(metrics_path) as f:
            saved = json.load(f)
        config = EditConfig(**saved["config"])
        scene = SceneConfig(**saved["scene"])
        capacity = int(saved["tile_capacity"])
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
        raise ValueError(f"{metrics_path}: not a metrics file of this version ({e})") from None
    return Run(run_dir, config, scene, capacity, StepConfig.of(config).blend, saved)


def avatar_file(folder: str) -> str:
    """The point_cloud.ply of a GaussianAvatars avatar folder; FileNotFoundError naming it."""
    ply = os.path.join(folder, AVATAR_FILE)
    if not os.path.isfile(ply):
        raise FileNotFoundError(f"{folder}: no {AVATAR_FILE} (not a GaussianAvatars avatar "
                                "folder)")
    return ply


def write_avatar(run_dir: str, which: str, avatar: Avatar, shape, motion, static_offset,
                 num_vertices: int, extra: dict | None = None) -> None:
    """The "original" or "edited" avatar as a GaussianAvatars folder of the run."""
    avatar_io.save_avatar_folder(path(run_dir, which), avatar, shape, motion, static_offset,
                                 num_vertices, extra)
