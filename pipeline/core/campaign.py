"""What a raw campaign folder holds: an encoder module's runs or a robot's poses."""

from __future__ import annotations

from pathlib import Path

from .errors import InputError


def campaign_kind(folder) -> str:
    """``"robot"`` when the folder has robot.toml/poses.csv/tracker.csv, else ``"encoder"``."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(folder, "campaign folder not found")
    if (folder / "robot.toml").exists() or (folder / "poses.csv").exists():
        return "robot"
    return "encoder"
