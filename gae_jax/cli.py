"""Command-line flags generated from the config dataclasses, for every entry point.

Each config field becomes `--field-name` with the field's type and a help text from the entry
point's HELP table (a test checks that every field has one), so a flag and a field never
disagree. Errors a user can cause (a bad value, a missing or malformed file) end as one line on
stderr and exit code 2 (`main_guard`).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from typing import Callable

from gae_jax import loop
from gae_jax.model.flame_io import FlameFileError
from gae_jax.util.compile import use_persistent_cache
from gae_jax.util.fileio import PlyError, cache_root
from gae_jax.util.memory import keep_freed_memory

USER_ERRORS = (ValueError, FileNotFoundError, NotADirectoryError, FileExistsError,
               FlameFileError, PlyError)
TYPES = {"int": int, "float": float, "str": str, "Optional[int]": int}


def parse_bool(text: str) -> bool:
    if text.lower() in ("true", "1", "yes", "on"):
        return True
    if text.lower() in ("false", "0", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")


def add_config_flags(parser: argparse.ArgumentParser, cls, help: dict, title: str,
                     choices: dict | None = None) -> None:
    """Adds `--field-name` for every field of dataclass `cls` (default None: not given; the help
    shows the field's default), restricted to `choices[field]` where given."""
    choices = choices or {}
    missing = {f.name for f in dataclasses.fields(cls)} - set(help)
    if missing:
        raise KeyError(f"no help text for {cls.__name__} fields {sorted(missing)}")
    group = parser.add_argument_group(title)
    for field in dataclasses.fields(cls):
        flag = "--" + field.name.replace("_", "-")
        default = field.default if field.default is not dataclasses.MISSING else None
        text = f"{help[field.name]} (default: {default!r})"
        if str(field.type) in ("bool", "<class 'bool'>"):
            group.add_argument(flag, type=parse_bool, default=None, metavar="{true,false}",
                               help=text)
        else:
            group.add_argument(flag, type=TYPES[str(field.type)], default=None, help=text,
                               choices=choices.get(field.name))


COMPILE_CACHE_OFF = "off"


def add_compile_cache_flag(parser: argparse.ArgumentParser) -> None:
    """`--compile-cache DIR|off` (default `$GAE_JAX_COMPILE_CACHE`, else the cache root's
    `xla/`)."""
    parser.add_argument("--compile-cache", default=None, metavar="DIR|off",
                        help="keep compiled programs on disk here, so a second run skips most "
                             "compilation ('off': compile every run; default: "
                             "$GAE_JAX_COMPILE_CACHE, else ~/.cache/gae_jax/xla)")


def compile_cache_folder(choice) -> str | None:
    """The folder `--compile-cache` names (None: off)."""
    choice = choice or os.environ.get("GAE_JAX_COMPILE_CACHE") or os.path.join(
        cache_root(), "xla")
    return None if choice == COMPILE_CACHE_OFF else choice


def prepare_process(compile_cache) -> None:
    """The process-wide settings an entry point makes before it compiles anything: the
    persistent compilation cache where `--compile-cache` says, and a host allocator that keeps
    large freed blocks (`memory.keep_freed_memory`: a jitted step's temporaries are not faulted
    in afresh on every call)."""
    use_persistent_cache(compile_cache_folder(compile_cache))
    keep_freed_memory()


def given(args: argparse.Namespace, cls) -> dict:
    """The fields of `cls` that were given on the command line."""
    return {f.name: getattr(args, f.name) for f in dataclasses.fields(cls)
            if getattr(args, f.name) is not None}


def check_run_folder(out: str, resume: bool, overwrite: bool, checkpoint: str,
                     marker: str) -> None:
    """Makes sure `out` can hold this run: a folder (made if missing) that holds no other run
    (its `marker` or `checkpoint`) unless `overwrite` -- whose stale checkpoints are then
    removed -- or, with `resume`, one that holds `checkpoint`. ValueError otherwise."""
    if os.path.exists(out) and not os.path.isdir(out):
        raise ValueError(f"--out {out}: is a file, not a folder")
    try:
        os.makedirs(out, exist_ok=True)
    except OSError as e:
        raise ValueError(f"--out {out}: cannot make the folder ({e.strerror})") from None
    has_run = any(os.path.exists(os.path.join(out, n)) for n in (marker, checkpoint))
    if resume:
        if not os.path.isfile(os.path.join(out, checkpoint)):
            finished = os.path.isfile(os.path.join(out, marker))
            raise ValueError(f"--resume: {out} holds no {checkpoint}" + (
                " (the run finished and removed it; --keep-checkpoint keeps it so that a run "
                "can be extended)" if finished else " (nothing to resume)"))
    elif has_run and not overwrite:
        raise ValueError(f"--out {out} already holds a run; pass --overwrite to replace it, "
                         "--resume to continue it, or choose another folder")
    elif has_run:
        loop.remove_checkpoint(os.path.join(out, checkpoint))


def main_guard(run: Callable[[], int]) -> int:
    """Runs an entry point's body; a user error becomes `error: ...` on stderr and exit 2."""
    try:
        return run()
    except USER_ERRORS as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
