"""The report's parts for a dynamic episode's scenario events (mhrc.viewer.events), in HTML.

Each kind has one mark, the same everywhere (timeline, legend, lanes, map): a colour and a
shape (`GLYPHS`). The timeline is a track under the slider with one marker per event at its
frame, its sentence as the tooltip; a skipped event's marker is dimmer and its tooltip says
why. Lane entries: a breakdown in its robot's lane, every other event in a `world` lane. A
static episode (no events) gets none of this: its page is the same as before.
"""

from __future__ import annotations

from mhrc.viewer.events import GLYPHS, KINDS, ScenarioMark, scenario_label
from mhrc.viewer.model import EpisodeView
from mhrc.viewer.wording import html_text as _e

THUMB = 16  # px: the slider's thumb; a frame's place on the track is where the thumb's centre goes
ROW = 15  # px between stacked markers (events of one frame)


def scenario_fact(view: EpisodeView) -> str | None:
    """`busy_house (d45b5975)` for the header, or None for a static episode."""
    named = view.header.scenario
    if not named:
        return None
    name, sha = named
    return scenario_label(name, sha)


def _tooltip(m: ScenarioMark) -> str:
    said = not m.skipped or m.skipped in m.text  # the world's sentence usually says why already
    return m.caption + ("" if m.applied or said else f" (skipped: {m.skipped})")


def _classes(m: ScenarioMark, base: str) -> str:
    return f"{base} ev-{_e(m.event)}" + ("" if m.applied else " skipped")


def _attrs(m: ScenarioMark) -> str:
    frame = "" if m.frame is None else f' data-frame="{m.frame}"'
    return f' data-index="{m.index}" data-event="{_e(m.event)}" data-tick="{m.tick}"{frame}'


def timeline(view: EpisodeView) -> str:
    """The markers under the slider, one per event at its frame (stacked when they share one)."""
    last = max(len(view.frames) - 1, 1)
    rows: dict[int | None, int] = {}
    marks = []
    for m in view.events:
        row = rows.get(m.frame, 0)
        rows[m.frame] = row + 1
        where = m.frame if m.frame is not None else last
        left = f"calc({THUMB / 2:g}px + (100% - {THUMB}px) * {where / last:.4f})"
        marks.append(
            f'<span class="{_classes(m, "ev-marker")}"{_attrs(m)} role="button" tabindex="0" '
            f'title="{_e(_tooltip(m))}" style="left:{left};top:{row * ROW}px">{GLYPHS.get(m.event, "?")}</span>'
        )
    height = max(rows.values(), default=1) * ROW + 2
    return f'<div id="event-track" aria-label="scenario events" style="height:{height}px">{"".join(marks)}</div>'


def legend(view: EpisodeView) -> str:
    """The event kinds this episode has, for the map's legend."""
    kinds = [k for k in KINDS if any(m.event == k for m in view.events)]
    names = {
        "relocate": "object moved",
        "new_target": "target added",
        "close": "container closed",
        "breakdown": "robot broken down",
    }
    items = " ".join(
        f'<span class="li"><span class="ev-glyph ev-{k}">{GLYPHS[k]}</span>{names[k]}</span>' for k in kinds
    )
    if any(not m.applied for m in view.events):
        items += f' <span class="li"><span class="ev-glyph skipped">{GLYPHS["relocate"]}</span>skipped event</span>'
    return f"<br>{items}"


def entry(m: ScenarioMark) -> str:
    """One event in a lane: its tick, mark, kind, sentence, and why it was skipped."""
    badge = "applied" if m.applied else "skipped"
    parts = [
        f'<li class="{_classes(m, "lane-event")}"{_attrs(m)}>',
        f'<div class="shead"><span class="tick">t{m.tick}</span> <span class="ev-glyph ev-{_e(m.event)}">{GLYPHS.get(m.event, "?")}</span>'
        f' <b>{_e(m.event)}</b> <span class="badge {badge}">{badge}</span></div>',
        f'<div class="feedback">{_e(m.text)}</div>',
    ]
    if not m.applied:
        parts.append(f'<div class="skip-why">skipped: {_e(m.skipped or "no reason given")}</div>')
    parts.append(f'<div class="dim">scenario {_e(m.scenario)}, event {m.index}</div></li>')
    return "".join(parts)


def robot_of(m: ScenarioMark) -> str | None:
    """The lane an event goes in: its robot's for an applied breakdown, else the world's (None)."""
    return m.robot if m.event == "breakdown" and m.applied else None
