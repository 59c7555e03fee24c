"""Fidelity: an episode is the paper's unless aids are asked for.

By default every robot sees and hears what the paper's robots do (docs/architecture.md, "Fidelity"). The
aids below make the benchmark easier; they are useful for debugging and teaching, so they
stay, each opt-in by name (`--aids solved_move,goal_map` or `--aids all`), and every trace
(`episode_started`) and every `episodes.jsonl` row records which ones an episode ran with.

The motion noise (`--noise on|off`, below) is mhrc's calibration, not the paper's: the paper's
Table III reports navigation that ends off target and placements that fail, which a world
without noise could not produce, but it gives no rates. Every trace and row records the rates
an episode ran with; `--noise off` is recorded like an aid and never averaged with the default.
"""

from __future__ import annotations

from collections.abc import Iterable

from mhrc.core.aids import (
    AIDS,
    NOISE,
    PAPER,
    AidsError,
    NoiseError,
    NoiseSetting,
    describe,
    label,
    parse_aids,
    parse_noise,
)
from mhrc.core.protocol import MotionNoise

__all__ = [
    "AIDS",
    "CALIBRATION",
    "NOISE",
    "NOISELESS",
    "PAPER",
    "AidsError",
    "NoiseError",
    "NoiseSetting",
    "describe",
    "label",
    "motion_noise",
    "parse_aids",
    "parse_noise",
    "recorded_noise",
]

CALIBRATION = MotionNoise()  # the rates `on` draws from (their values and meaning: MotionNoise, docs/fidelity.md)
NOISELESS = MotionNoise(setting="off", navigation_slip=0.0, navigation_sigma=0.0, release_slip=0.0, release_sigma=0.0)


def motion_noise(setting: str, aids: Iterable[str]) -> MotionNoise:
    """The motion noise a world with this --noise setting and these aids draws from: the
    calibration, or none with `--noise off` or the exact_motion aid (which also sets released
    objects down without physics)."""
    return NOISELESS if parse_noise(setting) == "off" or "exact_motion" in aids else CALIBRATION


def recorded_noise(started: dict[str, object]) -> MotionNoise:
    """The motion noise an `episode_started` event (a trace's dict) records; an event written
    before it was recorded ran with the calibration, or with none under the exact_motion aid."""
    if isinstance(started.get("noise"), dict):
        return MotionNoise.model_validate(started["noise"])
    aids = started.get("aids")
    return motion_noise("on", aids if isinstance(aids, list) else ())
