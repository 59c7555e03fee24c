"""The names of the fidelity options and what each means, without the wire's models: the aids
(`--aids`) and the motion noise settings (`--noise`), so that a command line is checked and its
--help written before anything heavy is imported. mhrc.core.fidelity (the noise's rates, the
trace's records) builds on these; docs/fidelity.md says what they are for.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Literal, cast

AIDS: dict[str, str] = {
    "live_state": "scene graphs show the live truth (where every known object is now, which containers are open), "
    "not what the robot last saw or was told",
    "solved_move": "a pick that fails for distance also says which move(dx, dy) would fix it",
    "feedback_advice": "failed actions' feedback also says what to do next and lists the names the robot could have used",
    "goal_map": "Bob's observation and task text say which goal each target goes to (the panel of each solid)",
    "status_hints": "Bob's task status adds what is missing, what comes next and what is wrong",
    "reach_labels": "object lines in LLM prompts say whether the object is within the robot's arm reach",
    "prompt_hints": "LLM prompts add advice beyond the paper's appendix: distances, reach, arm base and pick window, "
    "proactive strategy, message templates, furniture kinds",
    "exact_motion": "no motion noise (as --noise off: bases stop exactly on their stand pose) and released objects are "
    "set down without physics, so navigation never ends off target and a placed object never slides off",
}
PAPER = "paper"


class AidsError(ValueError):
    """An aid name mhrc does not know."""


def parse_aids(value: str | Iterable[str] | None) -> tuple[str, ...]:
    """`"all"`, `"none"`, a comma-separated list or an iterable of names -> sorted aid names."""
    if value is None:
        return ()
    names = [n.strip() for n in (value.split(",") if isinstance(value, str) else value) if n.strip()]
    if names in (["none"], []):
        return ()
    if names == ["all"]:
        return tuple(sorted(AIDS))
    unknown = [n for n in names if n not in AIDS]
    if unknown:
        raise AidsError(
            f"--aids: unknown aid {', '.join(map(repr, unknown))}; known aids: {', '.join(AIDS)}, or all, or none"
        )
    return tuple(sorted(set(names)))


def label(aids: Iterable[str]) -> str:
    """`paper`, or `aids:` and the aid names: how traces and result rows name the fidelity."""
    names = sorted(aids)
    return PAPER if not names else "aids:" + ",".join(names)


def describe() -> str:
    """One line per aid, for --help."""
    return "; ".join(f"{k}: {v}" for k, v in AIDS.items())


NoiseSetting = Literal["on", "off"]
NOISE: dict[str, str] = {
    "on": "the calibrated motion noise (the default): a base stops a little off its goal and now and then slips off "
    "target, a released object now and then slips on the suction cup",
    "off": "no motion noise: bases stop exactly on their goal and released objects do not slip (they still fall and "
    "settle under physics); not the calibration the default grid is scored with",
}


class NoiseError(ValueError):
    """A --noise value mhrc does not know."""


def parse_noise(value: str | None) -> NoiseSetting:
    """`on` (also None: the default) or `off`."""
    if value is None:
        return "on"
    if value not in NOISE:
        raise NoiseError(
            f"--noise: unknown setting {value!r}; use on (the calibrated motion noise, the default) or off (none)"
        )
    return cast(NoiseSetting, value)
