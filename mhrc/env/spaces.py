"""The environment's spaces: what an observation and an action are, as gymnasium spaces that
really contain what the environment returns and takes.

An observation is a dict of two texts: `text`, the user prompt the robot's LLM would be given
(agents/llm_policy.py renders it from the observation and the robot's memory), and
`structured`, the protocol's `Observation` as JSON (`Observation.model_validate_json` reads it
back) for code that does not read text. An action is a command in the paper's syntax
(`navigate(fridge, 0)`), as text.

Characters: every character of the Basic Multilingual Plane but the surrogates and the control
characters other than tab, newline and carriage return. Lengths: MAX_TEXT characters for an
observation's parts (whole histories over a long horizon stay far below it; a model's context
is smaller still), MAX_COMMAND for a command (a message may carry 4,000 characters).
"""

from __future__ import annotations

import copy
import functools
import re

from gymnasium import spaces

MAX_TEXT = 2**21
MAX_COMMAND = 4_200
CHARSET = frozenset(
    "\t\n\r"
    + "".join(chr(c) for c in range(0x20, 0x7F))
    + "".join(chr(c) for c in range(0xA0, 0xD800))
    + "".join(chr(c) for c in range(0xE000, 0xFFFE))  # to U+FFFD
)
_OUTSIDE = re.compile("[^\t\n\r\x20-\x7e\xa0-\ud7ff\ue000-\ufffd]")  # a character not in CHARSET
EMPTY = {"text": "", "structured": ""}  # a robot's observation before the world gave it one


CHARSET_NAME = "BMP printable"  # how a space names CHARSET when printed


class BMPText(spaces.Text):
    """A gymnasium Text space over CHARSET that prints in one short line.

    gymnasium's own repr lists the whole charset (63,000 characters for an action space, twice
    that for an observation's Dict); this one names it. Everything else (contains, sample,
    equality, seeding) is gymnasium's."""

    def __repr__(self) -> str:
        return f"Text({self.min_length}, {self.max_length}, charset={CHARSET_NAME} ({len(self.character_set):,} characters))"


@functools.cache
def _text(max_length: int) -> spaces.Text:
    return BMPText(max_length, min_length=0, charset=CHARSET)


def text_space(max_length: int) -> spaces.Text:
    """A Text space over CHARSET: a copy of one built once (building one sorts and indexes the
    63,000 characters), with a random generator of its own once seeded."""
    return copy.copy(_text(max_length))


def observation_space() -> spaces.Dict:
    return spaces.Dict({"text": text_space(MAX_TEXT), "structured": text_space(MAX_TEXT)})


def action_space() -> spaces.Text:
    return text_space(MAX_COMMAND)


def is_command(x: object) -> bool:
    """Whether `x` is in the action space (as `action_space().contains`, without building one)."""
    return isinstance(x, str) and len(x) <= MAX_COMMAND and _OUTSIDE.search(x) is None


def printable(text: str) -> str:
    """`text` with every character outside CHARSET replaced by U+FFFD (what a robot may be told
    stays inside the space; only messages carry text from outside the world)."""
    return _OUTSIDE.sub("\ufffd", text)
