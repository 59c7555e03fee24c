"""The shipped scenes' names, read from their files' names without loading a layout: the command
line checks `--scene` and lists the default grid's scenes before the layouts' models are imported
(mhrc.world.layouts reads and validates a file when its layout is first asked for)."""

from __future__ import annotations

from pathlib import Path

SCENES_DIR = Path(__file__).with_name("scenes")


def scene_files(directory: Path = SCENES_DIR) -> dict[str, Path]:
    """Each layout file's name (its stem) and path, in the files' order."""
    return {path.stem: path for path in sorted(directory.glob("*.json"))}
