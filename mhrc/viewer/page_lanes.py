"""The report's robot lanes and messages table, in HTML: one lane per robot with an entry per
step (the call, its ack and result, and the thought behind it: the model's analysis, reasoning,
prompt and raw reply, folded), the scenario's events merged in where they happened
(mhrc.viewer.page_events), and the messages the robots sent one another, each row tied to its
frame for the page's script. mhrc.viewer.page puts them into the page.
"""

from __future__ import annotations

from mhrc.core.protocol import ActionAck, Thought
from mhrc.core.protocol.thoughts import HUMAN_POLICY
from mhrc.viewer import page_coordination, page_events
from mhrc.viewer.model import EpisodeView, Step
from mhrc.viewer.wording import diagnostic_label
from mhrc.viewer.wording import html_text as _e


def _reply_analysis(reply: str | None) -> str:
    if not reply:
        return ""
    lines = [ln for ln in reply.splitlines() if not ln.strip().lower().startswith("command")]
    return "\n".join(lines).strip()


def _ack_html(ack: ActionAck) -> str:
    """The ack's line; a rejection's code (mhrc.core.upgrade reads it from an older trace's sentence) in `data-code`."""
    if ack.accepted:
        return f'<div class="ack">ack: accepted{": " + _e(ack.reason) if ack.reason else ""}</div>'
    code = f' data-code="{_e(ack.code.value)}" title="{_e(diagnostic_label(ack.code.value))}"' if ack.code else ""
    return f'<div class="ack"{code}>ack: rejected{": " + _e(ack.reason) if ack.reason else ""}</div>'


def _parse_error_html(t: Thought, prefix: str) -> str:
    """A thought's parse error, with its failure's code (mhrc.core.upgrade reads it from an older trace's texts) in
    `data-failure` and as a label people read."""
    if t.failure is None:
        return f'<div class="perr">{prefix}{_e(t.parse_error)}</div>'
    return (
        f'<div class="perr" data-failure="{_e(t.failure.value)}">{prefix}{_e(t.parse_error)} '
        f'<span class="dim">({_e(diagnostic_label(t.failure.value))})</span></div>'
    )


def _thought_html(t: Thought) -> list[str]:
    """The thought behind a step: the model's analysis, reasoning, command, parse error, usage, prompt and reply."""
    if t.policy == HUMAN_POLICY:  # a person's decision (mhrc play): how long it took
        return [f'<div class="human-decision">decided by a person in {t.latency:.1f} s</div>']
    if t.prompt is None and t.reply is None:
        return [_parse_error_html(t, "")] if t.parse_error else []
    parts = []
    analysis = _reply_analysis(t.reply)
    if t.reasoning:
        parts.append(
            f'<details class="reasoning"><summary>reasoning ({_e(t.reasoning_tokens)} '
            f"tokens)</summary><pre>{_e(t.reasoning)}</pre></details>"
        )
    if analysis:
        parts.append(f'<div class="analysis">{_e(analysis)}</div>')
    parts.append(f'<div class="command">command: <code>{_e(t.action)}</code></div>')
    if t.parse_error:
        parts.append(_parse_error_html(t, "parse error: "))
    parts.append(
        f'<div class="dim">{_e(t.policy)} · {_e(t.prompt_tokens)} prompt + {_e(t.completion_tokens)} completion tokens'
        f" · {t.latency:.2f} s{' · finish ' + _e(t.finish_reason) if t.finish_reason else ''}</div>"
    )
    parts.append(f'<details class="prompt"><summary>prompt</summary><pre>{_e(t.prompt)}</pre></details>')
    parts.append(f'<details class="reply"><summary>raw reply</summary><pre>{_e(t.reply)}</pre></details>')
    return parts


def _step_html(s: Step) -> str:
    res, ack = s.result, s.ack
    if ack is not None and not ack.accepted:
        status, cls = f"rejected: {ack.reason or 'no reason given'}", "rejected"
    elif res is not None:
        out = res.outcome
        status, cls = ("ok", "ok") if out.succeeded else (f"failed: {out.code.value}", "failed")
    elif ack is not None:
        status, cls = "accepted, no result recorded", "pending"
    else:
        status, cls = "no ack or result recorded", "pending"
    has_result = " has-result" if res is not None else ""
    frame = "" if s.frame is None else f' data-frame="{s.frame}"'
    parts = [
        f'<li class="step {cls}{has_result}" data-goal="{_e(s.goal_id)}" data-tick="{_e(s.tick)}"{frame}>',
        f'<div class="shead"><span class="tick">t{_e(s.tick)}</span> <code class="call">{_e(s.call or "?")}</code>'
        f' <span class="badge {cls}">{_e(status)}</span></div>',
    ]
    if ack is not None:
        parts.append(_ack_html(ack))
    if res is not None:
        parts.append(f'<div class="feedback">{_e(res.outcome.feedback)}</div>')
        if res.started is not None:
            parts.append(f'<div class="dim">sim {res.started:.1f}–{(res.ended or res.started):.1f} s</div>')
    if s.thought is not None:
        parts.append(page_coordination.step_line(s.thought.coordination))
        parts += _thought_html(s.thought)
    parts.append("</li>")
    return "".join(parts)


def _cells(items: list[tuple[int | None, str]], rows: dict[int, int]) -> str:
    """A lane's items grouped by tick, each tick's group one cell on that tick's row of the lanes'
    grid (`rows`: tick -> grid row), so that a tick sits at the same height in every lane. An item
    without a tick joins the tick before it."""
    groups: list[tuple[int | None, list[str]]] = []
    for tick, html in items:
        if tick is None and groups:
            tick = groups[-1][0]
        if groups and groups[-1][0] == tick:
            groups[-1][1].append(html)
        else:
            groups.append((tick, [html]))
    last = max(rows.values(), default=1) + 1
    return "".join(
        f'<li class="tick-cell" data-tick="{_e(tick)}" style="grid-row:{rows.get(tick, last) if tick is not None else last}">'
        f'<ol class="at-tick">{"".join(html)}</ol></li>'
        for tick, html in groups
    )


def _robot_items(view: EpisodeView, r: str) -> list[tuple[int | None, str]]:
    """A robot's lane items in order, each with its tick: its steps, each event of its robot before
    the first step of its tick or later (page_events.merge's order)."""
    steps = view.steps.get(r, [])
    items: list[tuple[int | None, str]] = [(s.tick, _step_html(s)) for s in steps]
    for m in sorted((m for m in view.events if page_events.robot_of(m) == r), key=lambda m: m.tick, reverse=True):
        at = next((k for k, s in enumerate(steps) if s.tick is not None and s.tick >= m.tick), len(steps))
        items.insert(at, (m.tick, page_events.entry(m)))
    return items


def lanes_section(view: EpisodeView, colors: dict[str, str]) -> str:
    """One lane per robot (and the world's, for a scenario's events) side by side on one grid whose
    rows are the ticks: a tick is at the same height in every lane; the lanes scroll together, in
    one box, across when there are more than the page's width holds."""
    world = [m for m in view.events if page_events.robot_of(m) is None or page_events.robot_of(m) not in view.robots]
    items = {r: _robot_items(view, r) for r in view.robots}
    ticks = sorted({t for lane in items.values() for t, _ in lane if t is not None} | {m.tick for m in world})
    rows = {t: i + 2 for i, t in enumerate(ticks)}  # row 1: the lanes' headings
    span = len(ticks) + 2  # a last row for items with no tick at all
    lanes = []
    for r in view.robots:
        human = view.header.models.get(r) == HUMAN_POLICY  # played by a person (mhrc play)
        mark = ' <span class="human-mark" data-human>&#128100; played by a person</span>' if human else ""
        lanes.append(
            f'<div class="lane{" human" if human else ""}" data-robot="{_e(r)}" style="grid-row:1 / span {span}">'
            f'<h3 style="border-color:{colors[r]}">{_e(r)}{mark} '
            f'<span class="dim">{_e(view.header.models.get(r))} · {len(view.steps.get(r, []))} steps</span></h3>'
            f"<ol>{_cells(items[r], rows)}</ol></div>"
        )
    if world:
        fact = page_events.scenario_fact(view) or ""
        lanes.append(
            f'<div class="lane world-lane" data-lane="world" style="grid-row:1 / span {span}"><h3 style="border-color:#555">world '
            f'<span class="dim">scenario {_e(fact)} · {len(world)} events</span></h3>'
            f"<ol>{_cells([(m.tick, page_events.entry(m)) for m in world], rows)}</ol></div>"
        )
    columns = f"repeat({len(view.robots)}, minmax(11em, 1fr))" + (" minmax(10em, .8fr)" if world else "")
    grid = f"grid-template-columns:{columns};grid-template-rows:auto repeat({span - 1}, auto)"
    return f'<section id="lanes-section"><h2>Robots</h2><div id="lanes" style="{grid}">{"".join(lanes)}</div></section>'


def messages_section(view: EpisodeView, colors: dict[str, str]) -> str:
    if not view.messages:
        return '<section id="messages"><h2>Messages</h2><p class="dim">no messages between robots</p></section>'
    rows = []
    for i, m in enumerate(view.messages):
        frame = "" if m.frame is None else f' data-frame="{m.frame}"'
        c1, c2 = colors.get(m.sender, "#555"), colors.get(m.to, "#555")
        rows.append(
            f'<tr class="msg" data-i="{i}"{frame}><td>{m.sent}</td><td><b style="color:{c1}">{_e(m.sender)}</b> &#8594; '
            f'<b style="color:{c2}">{_e(m.to)}</b></td><td>{_e(m.delivered if m.delivered is not None else "not seen")}</td>'
            f'<td class="content">{_e(m.content)}</td></tr>'
        )
    return (
        '<section id="messages"><h2>Messages</h2><table class="grid"><tr><th>sent at tick</th><th>from &#8594; to</th>'
        f"<th>delivered at tick</th><th>content</th></tr>{''.join(rows)}</table></section>"
    )
