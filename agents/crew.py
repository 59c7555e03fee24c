"""A robot's part in its team and the words its prompts use for its teammates (prompts per kind).

A robot's prompts are its kind's templates, `prompts/<kind>_system.txt`, `<kind>_user.txt` and
`<kind>_hints.txt` (`KIND_PROMPTS` maps each kind id to its templates' stem and says what the
kind is), filled with the robot's name and its team: the paper's Alice, Bob and David are the
`mobile_manipulator`, `tabletop_arm` and `mobile_base` templates filled for the paper's team;
a `drone` has a template in the same shape.

**Parts.** A kind's part follows from what it can do, as the world's (`world/briefs.py`):

- the *finisher* places on the task's goals at its table (a tabletop arm, the paper's Bob);
- a *fetcher* navigates and manipulates: it brings the finisher what it needs (Alice);
- a *scout* only navigates: it searches surfaces and reports (David, a drone).

**Who talks to whom**, by part (`TALKS_TO`):

- the finisher with the fetchers (it asks them for what it lacks; they bring it);
- a fetcher with the finisher, the other fetchers and the scouts;
- a scout with the fetchers and the other scouts.

The finisher and the scouts do not talk, as in the paper, where Bob knows only Alice and David
knows only Alice while Alice knows both. Fetchers talk with each other, and scouts with each
other, so that several of them split the work by claims over messages (each says what it takes
on before it starts), never by anything shared out of band.

A robot's *contacts* are the teammates its part talks to; its system prompt's background names
them and says what each can do, in the appendix's style. Alice's: "Bob is a robot arm on a table
that can manipulate objects; David is a mobile base that can navigate." (`$contacts_are`), from
each contact's kind (`KindPrompt.noun`, `KindPrompt.can`); David's: "Alice can navigate through
the house and manipulate objects." (`$contacts_can`). Where the appendix names a teammate
("tell Bob", "Follow Alice's instructions"), the template names the group of the team that plays
that part: the finisher, the fetchers this scout follows, the scouts a fetcher may send.

**The words.** Four groups, each of them relative to the robot (it is never in its own groups):
`contacts`, `finisher`, `fetchers` (the other fetchers, for a fetcher), `scouts` (the other scouts,
for a scout); each group in role order (finisher, fetchers, scouts), each part in the team's order.
Each group gives seven placeholders:

    $fetchers        the names, joined with "and": Alice / Alice and Carol / Alice, Carol and Frank
    $fetchers_or     joined with "or": Alice or Carol
    $fetchers_s      possessive: Alice's / Alice and Carol's
    $fetchers_they   she / he / it / they (the appendix's pronouns for its Alice, Bob and David;
    $fetchers_them   her / him / it / them  any other robot is "it", several are "they")
    $fetchers_are    "Alice is a mobile manipulator that can ...; Carol is ..." (with the full stop)
    $fetchers_can    "Alice can ...; Carol can ..." (with the full stop)

and `$robot` is the robot's name. A template line that uses a placeholder of a group the team
leaves empty (`$scouts` in a team without scouts, `$fetchers` in the only fetcher's prompt) is
left out, and a numbered list it was in is numbered again: the line about sending David to
explore is not in Alice's prompt of a team without scouts, and the claims lines for peers are
only in the prompts of teams with several fetchers or scouts. These words are filled in once,
when the templates are loaded; what changes step by step (`$skills`, `$teammates`, `$absent`,
`$hints` and the user prompt's sections) is filled in at each step.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from string import Template
from typing import Literal

from mhrc.core.team import PAPER_TEAM, TeamSpec

__all__ = [
    "GROUPS",
    "KIND_PROMPTS",
    "STATIC",
    "TALKS_TO",
    "Crew",
    "KindPrompt",
    "Role",
    "UnknownKind",
    "crew_of",
    "fill",
]

Role = Literal["finisher", "fetcher", "scout"]


@dataclass(frozen=True)
class KindPrompt:
    """How the prompts treat a robot kind: the stem of its template files, its part, and how a
    teammate's background names it: `noun` (what it is) and `can` (what it can do)."""

    template: str
    role: Role
    noun: str
    can: str


# kind id (world.kinds.KINDS) -> its templates and words; data, so a kind's template is picked by its id
KIND_PROMPTS: dict[str, KindPrompt] = {
    "mobile_manipulator": KindPrompt(
        "mobile_manipulator", "fetcher", "a mobile manipulator", "navigate through the house and manipulate objects"
    ),
    "tabletop_arm": KindPrompt("tabletop_arm", "finisher", "a robot arm on a table", "manipulate objects"),
    "mobile_base": KindPrompt("mobile_base", "scout", "a mobile base", "navigate"),
    "drone": KindPrompt("drone", "scout", "a drone", "fly over the furniture and see the surfaces from above"),
}
TALKS_TO: dict[Role, tuple[Role, ...]] = {
    "finisher": ("fetcher",),
    "fetcher": ("finisher", "fetcher", "scout"),
    "scout": ("fetcher", "scout"),
}
# The appendix's pronouns for its three robots; any other robot is "it"
PRONOUNS = {"alice": ("she", "her"), "bob": ("he", "him"), "david": ("he", "him")}
GROUPS = ("contacts", "finisher", "fetchers", "scouts")
FORMS = ("", "_or", "_s", "_they", "_them", "_are", "_can")
STATIC = frozenset({"robot"} | {g + f for g in GROUPS for f in FORMS})  # the placeholders filled once
_GROUP_OF = {g + f: g for g in GROUPS for f in FORMS}
_ROLE_GROUP: dict[Role, str] = {"finisher": "finisher", "fetcher": "fetchers", "scout": "scouts"}
_NUMBERED = re.compile(r"^(\d+)\. ")


class UnknownKind(ValueError):
    """A robot whose kind has no prompts, or a robot not in its team."""


def _join(names: list[str], word: str) -> str:
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} {word} {names[-1]}"


@dataclass(frozen=True)
class Crew:
    """One robot's view of its team for its prompts: its kind, its part and its groups (names,
    in role order, itself never among them)."""

    robot: str
    kind: str
    team: TeamSpec
    groups: Mapping[str, tuple[str, ...]]

    @property
    def prompt(self) -> KindPrompt:
        return KIND_PROMPTS[self.kind]

    @property
    def role(self) -> Role:
        return self.prompt.role

    def words(self) -> dict[str, str]:
        """Every static placeholder's text ("" for a group the team leaves empty)."""
        kinds = self.team.kinds
        out = {"robot": self.robot.capitalize()}
        for group, names in self.groups.items():
            if not names:
                out |= dict.fromkeys((group + f for f in FORMS), "")
                continue
            shown = [n.capitalize() for n in names]
            they, them = ("they", "them") if len(names) != 1 else PRONOUNS.get(names[0], ("it", "it"))
            forms = {
                "": _join(shown, "and"),
                "_or": _join(shown, "or"),
                "_s": _join(shown, "and") + "'s",
                "_they": they,
                "_them": them,
                "_are": "; ".join(
                    f"{s} is {KIND_PROMPTS[kinds[n]].noun} that can {KIND_PROMPTS[kinds[n]].can}"
                    for n, s in zip(names, shown, strict=True)
                )
                + ".",
                "_can": "; ".join(f"{s} can {KIND_PROMPTS[kinds[n]].can}" for n, s in zip(names, shown, strict=True))
                + ".",
            }
            out |= {group + f: text for f, text in forms.items()}
        return out

    @property
    def empty(self) -> frozenset[str]:
        """The groups this robot's team leaves empty."""
        return frozenset(g for g, names in self.groups.items() if not names)

    def fill(self, text: str) -> str:
        """`text` with the static placeholders filled and the lines naming an empty group left out."""
        return fill(text, self.words(), self.empty)


def crew_of(robot: str, team: TeamSpec | None = None) -> Crew:
    """`robot`'s Crew in `team` (the paper's by default); UnknownKind for a robot not in the team
    or of a kind without prompts."""
    team = team or PAPER_TEAM
    kinds = team.kinds
    if robot not in kinds:
        raise UnknownKind(f"robot {robot!r} is not in team {team.name} ({', '.join(kinds)}): give its team")
    unknown = sorted({k for k in kinds.values() if k not in KIND_PROMPTS})
    if unknown:
        raise UnknownKind(
            f"no prompts for robot kind(s) {', '.join(unknown)} (team {team.name}); "
            f"the kinds with prompts are {', '.join(KIND_PROMPTS)}"
        )
    role = KIND_PROMPTS[kinds[robot]].role
    by_role: dict[str, list[str]] = {"finisher": [], "fetchers": [], "scouts": []}
    for name, kind in kinds.items():
        if name != robot:
            by_role[_ROLE_GROUP[KIND_PROMPTS[kind].role]].append(name)
    talks = {_ROLE_GROUP[r] for r in TALKS_TO[role]}
    contacts = [n for g in ("finisher", "fetchers", "scouts") if g in talks for n in by_role[g]]
    groups = {"contacts": tuple(contacts)} | {g: tuple(names) for g, names in by_role.items()}
    return Crew(robot=robot, kind=kinds[robot], team=team, groups=groups)


def _names(line: str) -> set[str]:
    return {m.group("named") or m.group("braced") for m in Template.pattern.finditer(line)} - {None}


def fill(text: str, words: Mapping[str, str], empty: frozenset[str] = frozenset()) -> str:
    """`text` (a string.Template) with the placeholders in `words` filled (their text escaped, so
    that the result is a template again) and every other placeholder, and `$$`, left as they are.
    A line that uses a placeholder of a group in `empty` is left out, and then every numbered
    list is numbered 1, 2, 3 again."""
    lines = text.splitlines(keepends=True)
    kept = [line for line in lines if not any(_GROUP_OF.get(n) in empty for n in _names(line))]
    if len(kept) != len(lines):
        count = 0
        for i, line in enumerate(kept):
            if _NUMBERED.match(line):
                count += 1
                kept[i] = _NUMBERED.sub(f"{count}. ", line, count=1)
            else:
                count = 0
    text = "".join(kept)

    def one(m: re.Match[str]) -> str:
        name = m.group("named") or m.group("braced")
        return words[name].replace("$", "$$") if name in words else m.group(0)

    return Template.pattern.sub(one, text)
