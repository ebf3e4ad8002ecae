"""``sb3-marl push-to-hub`` and ``load-from-hub``: models on the Hugging Face Hub (rl-zoo's flags)."""

from __future__ import annotations

import argparse
import os
import shutil
from pathlib import Path
from typing import Any

from sb3_marl.cli.common import (
    MAX_EPISODES,
    CommandFailed,
    UsageError,
    add_run_selection,
    find_run_of,
    load_model_of,
    outputs_of,
    positive,
)


def add_parsers(commands: Any) -> None:
    """Add the Hub's subcommands to the ``sb3-marl`` parser's ``commands``."""
    push = commands.add_parser("push-to-hub", help="build a model folder with a model card and upload it (rl-zoo's flags)")
    add_run_selection(push)
    push.add_argument("--repo-name", default=None, help="default: <algo>-<env name>")
    push.add_argument(
        "-orga", "--organization", default=None, help="Hub user or organisation (needed to upload; not with --dry-run)"
    )
    push.add_argument("-m", "--commit-message", default="Upload sb3-marl model", help="the Hub commit's message")
    push.add_argument(
        "--eval-episodes", type=positive(maximum=MAX_EPISODES), default=10, help="episodes of the card's evaluation"
    )
    push.add_argument("--no-video", action="store_true", help="leave replay.mp4 out")
    push.add_argument("--private", action="store_true", help="create the Hub repo private")
    push.add_argument("--dry-run", metavar="PATH", default=None, help="only build the folder at PATH")

    load = commands.add_parser("load-from-hub", help="download a model into the log layout (then evaluate/enjoy it)")
    load.add_argument("--repo-id", required=True, help="ORG/NAME")
    load.add_argument("-f", "--folder", "--log-folder", dest="folder", default="logs", help="log folder to place the run in")

    push.set_defaults(handler=push_to_hub)
    load.set_defaults(handler=load_from_hub_command)


def push_to_hub(args: argparse.Namespace) -> int:
    from rl_zoo3.utils import EnvironmentName

    from sb3_marl.hub import HubError, build_model_folder, push_folder
    from sb3_marl.runs.experiment import EVAL_SEED_OFFSET

    if args.organization is None and args.dry_run is None:
        raise UsageError("-orga/--organization: required to upload (the Hub user or organisation); --dry-run PATH only builds")
    organization = args.organization or "your-organization"  # a dry run's card names a placeholder
    repo_id = f"{organization}/{args.repo_name or f'{args.algo}-{EnvironmentName(args.env)}'}"
    _check_repo_id("-orga/--organization and --repo-name", repo_id)
    dry_run = args.dry_run
    occupied = os.path.exists(dry_run or "") and (not os.path.isdir(dry_run) or bool(os.listdir(dry_run)))
    if dry_run and (os.path.islink(dry_run) or occupied):
        raise UsageError(f"--dry-run: {args.dry_run!r} exists and is not an empty folder: give a new or empty folder.")
    if not args.no_video:
        from sb3_marl.evaluation.video import VideoExtraMissing, imageio_module

        try:
            imageio_module()
        except VideoExtraMissing as error:
            raise CommandFailed(f"{error}; or leave the video out with --no-video") from None
    run = find_run_of(args)
    model = load_model_of(run, args)  # a clear error for an unreadable model, before building anything
    folder = Path(args.dry_run) if args.dry_run else fresh_folder(outputs_of(args, run) / "hub")
    build_model_folder(run, folder, repo_id, args.eval_episodes, args.seed + EVAL_SEED_OFFSET, not args.no_video, model)
    print(f"built the model folder {folder} for {repo_id}")
    if args.dry_run:
        return 0
    try:
        url = push_folder(folder, repo_id, args.commit_message, private=args.private)
    except HubError as error:
        raise CommandFailed(str(error)) from None
    print(f"uploaded to {url}")
    return 0


def fresh_folder(folder: Path) -> Path:
    """``folder`` emptied and created anew: whatever was there (an earlier build, files or links
    put there, a link to another folder) is removed without following links, so the upload holds
    only the files built for it."""
    if folder.is_symlink() or folder.is_file():
        folder.unlink()
    elif folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    return folder


def _check_repo_id(flag: str, repo_id: str) -> None:
    from huggingface_hub.utils import HFValidationError, validate_repo_id

    try:
        validate_repo_id(repo_id)
    except HFValidationError as error:
        raise UsageError(f"{flag}: invalid Hub repo id {repo_id!r}: {error}") from None
    if repo_id.count("/") != 1:
        raise UsageError(f"{flag}: invalid Hub repo id {repo_id!r}: expected ORG/NAME.")


def load_from_hub_command(args: argparse.Namespace) -> int:
    from sb3_marl.hub import HubError, load_from_hub

    _check_repo_id("--repo-id", args.repo_id)

    try:
        run = load_from_hub(args.repo_id, args.folder)
    except HubError as error:
        raise CommandFailed(str(error)) from None
    print(f"downloaded {args.repo_id} into {run}")
    return 0
