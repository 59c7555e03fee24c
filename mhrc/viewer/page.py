"""The episode report: one self-contained HTML file (CSS, JS and data inline, nothing fetched).

The static parts (header, the task's targets and which of them ended unplaced, house map's
furniture, robot lanes, messages, failure panel) are HTML written here (the lanes and the
messages in mhrc.viewer.page_lanes), readable without JavaScript; the map's moving parts
(robots, paths, objects, open containers, messages in flight) are drawn by a small script from
the frames embedded as JSON in `<script type="application/json" id="mhrc-data">`, one frame
per world snapshot, scrubbed with a range slider or the arrow keys (Home and End jump). The page opens on the last frame, the state
the episode was judged on. A robot's path follows each navigate's planned route where its result
carries one (older traces: straight lines between stops). Labels never cover one another: the
fixed ones are placed here (mhrc.viewer.placement), the moving ones by the script, which
measures them. A dynamic episode's scenario events (mhrc.viewer.events) get a track of markers
under the slider, entries in the lanes and marks on the map (mhrc.viewer.page_events); a static
episode's page has none of them. The script and the style are `page.js` and `page.css` beside
this module (package data), inlined into every page.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from importlib.resources import files
from typing import Any, TypeVar

from mhrc.analysis.diagnostics import Diagnostics
from mhrc.core.protocol.events import DEFAULT_PROTOCOL
from mhrc.viewer import page_coordination, page_events
from mhrc.viewer.model import EpisodeView
from mhrc.viewer.page_lanes import lanes_section, messages_section
from mhrc.viewer.placement import Box, Request, place
from mhrc.viewer.scene_map import Piece
from mhrc.viewer.targets import ObjectFate, TaskView
from mhrc.viewer.wording import diagnostic_label, partial_success
from mhrc.viewer.wording import html_text as _e

T = TypeVar("T")
SCALE = 80.0  # SVG pixels per metre
ROBOT_COLORS = {"alice": "#d62728", "bob": "#1f77b4", "david": "#2ca02c"}
# the other robots of a team, in order: eight distinct colours, so a team of eight never repeats one
PALETTE = ["#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf", "#bcbd22", "#7f7f7f", "#393b79"]
# the page's style and script, inlined into every report: package data beside this module
CSS = files("mhrc.viewer").joinpath("page.css").read_text(encoding="utf-8")
JS = files("mhrc.viewer").joinpath("page.js").read_text(encoding="utf-8")


def robot_colors(robots: list[str]) -> dict[str, str]:
    """A colour per robot: the paper's three their own, the others the palette's in order (none
    used twice while the palette lasts)."""
    return distinct(robots, ROBOT_COLORS, PALETTE)


def distinct(robots: list[str], named: dict[str, T], palette: list[T]) -> dict[str, T]:
    """`named` colours for the robots that have one, the palette's unused ones, in order, for the rest."""
    used = {named[r] for r in robots if r in named}
    extra = iter([c for c in palette if c not in used] * (1 + len(robots) // max(1, len(palette))))
    return {r: named[r] if r in named else next(extra) for r in robots}


def _bounds(view: EpisodeView) -> tuple[float, float, float, float]:
    if view.scene:
        b = view.scene.bounds
        return float(b[0]) - 0.3, float(b[1]) + 0.3, float(b[2]) - 0.3, float(b[3]) + 0.3
    xs = [p.x for f in view.frames for p in f.robots.values()] + [p.x for f in view.frames for p in f.objects.values()]
    ys = [p.y for f in view.frames for p in f.robots.values()] + [p.y for f in view.frames for p in f.objects.values()]
    if not xs:
        return -5.0, 5.0, -4.0, 4.0
    return min(xs) - 1, max(xs) + 1, min(ys) - 1, max(ys) + 1


# --------------------------------------------------------------------------- generic tables


def value_html(value: Any, depth: int = 0) -> str:
    """Any JSON-like value as HTML: dicts as key/value tables, lists of dicts as tables."""
    if isinstance(value, dict):
        if not value:
            return '<span class="dim">none</span>'
        rows = "".join(f"<tr><th>{_e(k)}</th><td>{value_html(v, depth + 1)}</td></tr>" for k, v in value.items())
        return f'<table class="kv">{rows}</table>'
    if isinstance(value, (list, tuple)):
        if not value:
            return '<span class="dim">none</span>'
        if all(isinstance(v, dict) for v in value):
            cols: list[str] = []
            for v in value:
                cols += [k for k in v if k not in cols]
            head = "".join(f"<th>{_e(c)}</th>" for c in cols)
            body = "".join(
                "<tr>" + "".join(f"<td>{value_html(v.get(c), depth + 1)}</td>" for c in cols) + "</tr>" for v in value
            )
            return f'<table class="grid"><tr>{head}</tr>{body}</table>'
        return "<ul>" + "".join(f"<li>{value_html(v, depth + 1)}</li>" for v in value) + "</ul>"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.3g}" if abs(value) < 1000 else f"{value:.1f}"
    return _e(value)


# --------------------------------------------------------------------------- sections


def _header(view: EpisodeView) -> str:
    h = view.header
    models = ", ".join(f"{r}: {m}" for r, m in h.models.items()) or "unknown"
    facts: dict[str, object] = {
        "task": h.task,
        "scene": h.scene,
        "seed": h.seed,
        "objects": h.n_objects,
        "robots": ", ".join(h.robots),
        **({"protocol": h.protocol} if h.protocol != DEFAULT_PROTOCOL else {}),  # the paper's page is as it was
        "model(s)": models,
        "fidelity": h.fidelity,
        "aids": ", ".join(h.aids or []) or "none",
        "scheduler": h.scheduler,
        "horizon": h.horizon,
        "TS lower bound": h.lower_bound,
        "end": h.reason or "not recorded",
    }
    scenario = page_events.scenario_fact(view)
    if scenario is not None:  # a dynamic episode: the scenario of events it ran with
        facts = {**dict(list(facts.items())[:4]), "scenario": scenario, **dict(list(facts.items())[4:])}
    if h.scheduler == "async":
        facts["time scale"] = h.time_scale
        facts["step seconds"] = h.step_seconds
    facts["protocol version(s)"] = ", ".join(str(v) for v in h.versions) or "unknown"
    facts["trace"] = h.trace
    fact_rows = "".join(
        f"<tr><th>{_e(k)}</th><td>{_e(v if v is not None else 'unknown')}</td></tr>" for k, v in facts.items()
    )
    if h.metrics is not None:
        m = h.metrics.model_dump(mode="json")  # every metric, shown as the generic table shows JSON
        key = {"success": "Succ", "partial_success": "PS", "temporal_steps": "TS", "action_steps": "AS"}
        ps = partial_success(h.metrics.partial_success, h.metrics.placed, h.metrics.total)
        shown = {k: value_html(m.get(k)) for k in key}
        score, _, count = ps.partition(" ")
        count_html = f' <span class="mvs">{_e(count)}</span>' if count else ""
        shown["partial_success"] = _e(score) + count_html
        first = "".join(
            f'<div class="metric" data-metric="{k}"><div class="mv">{shown[k]}</div><div class="mk">{label}</div></div>'
            for k, label in key.items()
        )
        lb = h.lower_bound
        first += f'<div class="metric"><div class="mv">{_e(lb if lb is not None else "?")}</div><div class="mk">TS lower bound</div></div>'
        first += f'<div class="metric"><div class="mv">{value_html(m.get("makespan"))} s</div><div class="mk">makespan</div></div>'
        everything = {k: (ps if k == "partial_success" else v) for k, v in m.items()}
        metrics = f'<div class="metrics">{first}</div><details><summary>all metrics</summary>{value_html(everything)}</details>'
    else:
        metrics = '<p class="dim">no metrics: the trace has no episode_done event</p>'
    warn = "".join(f'<div class="warning">&#9888; {_e(w)}</div>' for w in view.warnings)
    title = f"{h.task or 'episode'} in {h.scene or 'an unknown scene'}, seed {h.seed if h.seed is not None else '?'}"
    if h.scenario:
        title += f", scenario {h.scenario[0]}"
    return (
        f'<header id="header"><h1>mhrc: {_e(title)}</h1>{warn}'
        f'<div class="cols"><table class="kv facts">{fact_rows}</table><div>{metrics}</div></div></header>'
    )


def _names_where(objs: list[ObjectFate]) -> str:
    return ", ".join(f"<b>{_e(o.name)}</b> ({_e(o.where)})" for o in objs)


def _targets(task: TaskView | None) -> str:
    """The task's objects: targets, which of them are not placed at the end and where they are, distractors."""
    if task is None:
        return ""
    notes = "".join(f'<div class="note">{_e(n)}</div>' for n in task.notes)
    if task.targets is None:
        return (
            f'<section id="targets"><h2>Targets</h2>{notes}<p class="tsum">The trace does not say which objects are '
            "targets (no observation of Bob's names them).</p></section>"
        )
    targets = [o for o in task.objects if o.role == "target"]
    placed = [o for o in targets if o.placed]
    unplaced = task.unplaced
    unknown = [o for o in targets if o.placed is None]
    if unplaced:
        summary = (
            f'<span class="unplaced-count">{len(unplaced)} of {len(targets)} targets not placed</span> at the end: '
            f"{_names_where(unplaced)}."
        )
    elif unknown:
        summary = f"{len(targets)} targets; whether they ended on their goals is not known."
    else:
        summary = f'<span class="placed-count">All {len(targets)} targets placed.</span>'
    if placed and unplaced:
        summary += f" Placed: {', '.join(f'<b>{_e(o.name)}</b>' for o in placed)}."
    ds = task.distractors
    summary += f" Distractors (not on the list): {_names_where(ds)}." if ds else " No distractors."
    rows = []
    dash = '<span class="dim">&#8212;</span>'
    for o in task.objects:
        if o.role == "target":
            state, cls = {
                True: ("&#10003; placed", "placed"),
                False: ("&#10007; not placed", "unplaced"),
                None: ("unknown", ""),
            }[o.placed]
        else:
            state, cls = dash, ""
        flag = {True: "yes", False: "no", None: ""}[o.placed]
        rows.append(
            f'<tr class="obj-row {o.role} {cls}" data-name="{_e(o.name)}" data-role="{o.role}" data-placed="{flag}">'
            f'<td><span class="odot {o.role} {cls}"></span>{_e(o.name)}</td><td>{o.role}</td>'
            f'<td>{_e(o.goal) if o.goal else dash}</td><td>{_e(o.where)}</td><td class="state">{state}</td></tr>'
        )
    sources = [f"targets from {task.targets_from}"]
    if task.goals_from:
        sources.append(f"goals from {task.goals_from}")
    if task.end_from:
        sources.append(f"ends from {task.end_from}")
    order = " The task is ordered: the targets must reach their goals in the listed order." if task.ordered else ""
    return (
        f'<section id="targets"><h2>Targets</h2>{notes}<p class="tsum">{summary}{order}</p>'
        '<table class="grid objs"><tr><th>object</th><th>role</th><th>goal</th><th>at the end</th><th>placed</th></tr>'
        f'{"".join(rows)}</table><p class="dim">{_e("; ".join(sources))}.</p></section>'
    )


def _static_labels(
    view: EpisodeView, px: Callable[[float], float], py: Callable[[float], float], frame: Box
) -> list[str]:
    """The furniture's and the goal area's labels, placed so that none covers another
    (mhrc.viewer.placement), with a leader line where a label sits away from its thing."""
    sc = view.scene
    assert sc is not None

    def box(cx: float, cy: float, sx: float, sy: float) -> Box:
        return Box(px(cx - sx / 2), py(cy + sy / 2), px(cx + sx / 2), py(cy - sy / 2))

    furniture = [(f, box(f.x, f.y, f.sx, f.sy)) for f in sc.furniture]
    goal = box(*sc.goal_area)
    soft: list[tuple[Box, float]] = [(b, 1.0) for _, b in furniture] + [(goal, 1.0)]
    soft += [(box(*wall), 3.0) for wall in sc.walls]
    soft += [(box(fx.x, fx.y, 0.16, 0.12), 1.0) for fx in sc.fixtures]
    spots = {(round(o.x, 1), round(o.y, 1)) for f in view.frames for o in f.objects.values()}
    soft += [(Box.centred(px(x), py(y), 14, 14), 3.0) for x, y in spots]  # where objects lie: keep them visible
    stands = {(round(r.x, 1), round(r.y, 1)) for f in view.frames for r in f.robots.values()}
    soft += [(Box.centred(px(x), py(y), 22, 22), 1.0) for x, y in stands]
    requests = [
        Request(f.name + (" ▣" if f.openable else ""), "fname", b)
        for f, b in sorted(furniture, key=lambda fb: (fb[1].x1 - fb[1].x0) * (fb[1].y1 - fb[1].y0))
    ]
    requests.append(Request("goal area", "gname", goal, fonts=(10.0, 8.5), prefer_outside=True))
    out = []
    for lab in place(requests, frame, soft):
        if lab.leader is not None:
            x1, y1, x2, y2 = lab.leader
            out.append(f'<line class="leader" x1="{x1}" y1="{y1}" x2="{x2}" y2="{y2}"/>')
        out.append(
            f'<text class="{lab.request.cls}" x="{round(lab.box.cx, 1)}" y="{lab.baseline}" '
            f'font-size="{lab.font:g}">{_e(lab.request.text)}</text>'
        )
    return out


@dataclass(frozen=True)
class MapFrame:
    """Metres on the floor to the map's SVG pixels (SCALE a metre; y points up in the house, down on the page)."""

    xmin: float
    ymax: float

    def px(self, x: float) -> float:
        return round((x - self.xmin) * SCALE, 1)

    def py(self, y: float) -> float:
        return round((self.ymax - y) * SCALE, 1)

    def rect(self, cx: float, cy: float, sx: float, sy: float, cls: str, extra: str = "") -> str:
        """An SVG rect of class `cls` centred at (cx, cy), sx by sy metres; `extra` ends its tag."""
        return (
            f'<rect class="{cls}" x="{self.px(cx - sx / 2)}" y="{self.py(cy + sy / 2)}" width="{round(sx * SCALE, 1)}" '
            f'height="{round(sy * SCALE, 1)}"{extra}/>'
        )

    def piece(self, f: Piece, cls: str, title: str | None = None) -> str:
        """A piece of furniture of the map (mhrc.viewer.scene_map) in its colour, named in `data-name`."""
        r, g, bl = (int(255 * c) for c in f.color[:3])
        inner = f"><title>{_e(title)}</title></rect" if title is not None else ""
        return self.rect(f.x, f.y, f.sx, f.sy, cls, f' data-name="{_e(f.name)}" style="fill:rgb({r},{g},{bl})"{inner}')


def _map(view: EpisodeView, colors: dict[str, str]) -> str:
    xmin, xmax, ymin, ymax = _bounds(view)
    w, hgt = (xmax - xmin) * SCALE, (ymax - ymin) * SCALE
    frame = MapFrame(xmin, ymax)
    px, py, rect = frame.px, frame.py, frame.rect

    parts: list[str] = []
    sc = view.scene
    if sc:
        b = sc.bounds
        parts.append(rect((b[0] + b[1]) / 2, (b[2] + b[3]) / 2, b[1] - b[0], b[3] - b[2], "floor"))
        for f in sc.furniture:
            if f.open_footprint is not None:
                cx, cy, sx, sy = f.open_footprint
                parts.append(rect(cx, cy, sx, sy, "open-footprint", f' data-for="{_e(f.name)}"'))
        for f in sc.furniture:
            cls = "furniture container" if f.openable else "furniture"
            parts.append(frame.piece(f, cls, f"{f.name}: {f.kind}"))
        gx, gy, gsx, gsy = sc.goal_area
        parts.append(rect(gx, gy, gsx, gsy, "goal-area", "><title>goal area</title></rect"))
        for fx in sc.fixtures:
            parts.append(rect(fx.x, fx.y, 0.16, 0.12, "fixture", f"><title>{_e(fx.name)}</title></rect"))
        for wx, wy, wsx, wsy in sc.walls:
            parts.append(rect(wx, wy, wsx, wsy, "wall"))
        parts += _static_labels(view, px, py, Box(0.0, 0.0, w, hgt))
    legend = "".join(
        f'<span class="li"><span class="chip" style="background:{c}"></span>{_e(r)}</span> ' for r, c in colors.items()
    )
    legend += "<br>" + " ".join(
        f'<span class="li"><span class="odot {cls}"></span>{text}</span>'
        for cls, text in (
            ("target unplaced", "target, not on its goal"),
            ("target placed", "target on its goal"),
            ("distractor", "distractor"),
            ("ring", "target not placed at the end"),
        )
    )
    if view.events:
        legend += page_events.legend(view)
    n = len(view.frames)
    if view.frames_from == "snapshots":
        note = ""
    elif view.frames_from == "observations":
        note = '<div class="warning">&#9888; no snapshots in this trace: robot positions come from their own observations; objects are not shown</div>'
    else:
        note = '<div class="warning">&#9888; nothing to animate: the trace has no snapshots and no action results</div>'
    disabled = " disabled" if n == 0 else ""
    slider = (
        f'<input type="range" id="tick-slider" min="0" max="{max(n - 1, 0)}" value="{max(n - 1, 0)}" step="1"{disabled} '
        'aria-label="frame">'
    )
    if view.events:  # the scenario's events on a track under the slider
        slider = f'<div class="timeline">{slider}{page_events.timeline(view)}</div>'
    frame_events = '<div id="frame-events"></div>' if view.events else ""
    tick_label = f"tick {view.frames[-1].tick} (the end)" if n else "no frames"
    return f"""
<section id="map-section"><h2>House map</h2>{note}
<div class="controls">
  <button id="prev" type="button"{disabled}>&#9664;</button>
  {slider}
  <button id="next" type="button"{disabled}>&#9654;</button>
  <span id="tick-label">{tick_label}</span>
  <span class="dim">(frames: {n}; use the slider, the &#8592; &#8594; keys, Home or End)</span>
</div>
<div class="map-wrap">
<svg id="map" viewBox="0 0 {round(w, 1)} {round(hgt, 1)}" data-xmin="{xmin}" data-ymax="{ymax}" data-scale="{SCALE}" role="img" aria-label="top-down map">
<g id="static">{"".join(parts)}</g>
<g id="dyn"></g>
</svg>
<div id="frame-info"><div class="legend">{legend}</div>{frame_events}<div id="frame-steps"></div><div id="frame-objects"></div></div>
</div>
</section>"""


LABELLED_KEYS = (
    "rejected_by_reason",
    "failed_by_code",
)  # breakdowns by kind or outcome code; the others are by name or skill


def _diagnostic_value(key: str, value: Any) -> str:
    """A diagnostics value: a breakdown's kinds and outcome codes labelled, object names and skills as they are."""
    if isinstance(value, dict) and value:

        def name(k: str) -> str:
            return (
                f'<span title="{_e(k)}">{_e(diagnostic_label(k))}</span>'
                if key in LABELLED_KEYS
                else f"<code>{_e(k)}</code>"
            )

        def inner(v: Any) -> str:
            if isinstance(v, dict):  # failed_by_skill: skill -> outcome code -> count
                return ", ".join(f"{_e(diagnostic_label(c))} &#215;{_e(n)}" for c, n in v.items())
            return _e(v)

        return "".join(f"<div>{name(str(k))}: {inner(v)}</div>" for k, v in value.items())
    if key == "steps_above_bound" and value is None:  # not "none": that reads as no step above it
        return '<span class="dim" title="cut off by the horizon before the bound, or no bound known">n/a</span>'
    if value in (0, None, {}) and not isinstance(value, bool):
        return f'<span class="dim">{"none" if value in (None, {}) else 0}</span>'
    return value_html(value)


def _failures(diagnostics: Diagnostics | None, note: str | None) -> str:
    """mhrc.analysis.diagnostics' findings with the labels people read (mhrc.analysis.diagnostics.LABELS); the key in each row's title."""
    if diagnostics is None:
        return f'<section id="failures"><h2>Failures</h2><p class="note">{_e(note)}</p></section>'
    rows = "".join(
        f'<tr data-key="{_e(k)}"><th title="{_e(k)}">{_e(diagnostic_label(str(k)))}</th><td>{_diagnostic_value(str(k), v)}</td></tr>'
        for k, v in diagnostics.as_dict().items()
    )
    return f'<section id="failures"><h2>Failures</h2><table class="kv diag">{rows}</table></section>'


def _data(view: EpisodeView, colors: dict[str, str]) -> str:
    calls = {
        s.goal_id: {"robot": s.robot, "call": s.call, "ok": s.result is not None and s.result.outcome.succeeded}
        for lane in view.steps.values()
        for s in lane
    }
    data: dict[str, object] = {
        "robots": view.robots,
        "fliers": view.header.fliers,
        "colors": colors,
        "frames": [f.as_data() for f in view.frames],
        "framesFrom": view.frames_from,
        "messages": [
            {
                "sender": m.sender,
                "to": m.to,
                "content": m.content,
                "sent": m.sent,
                "delivered": m.delivered,
                "frame": m.frame,
            }
            for m in view.messages
        ],
        "calls": calls,
        "routes": view.routes,
        "roles": view.task.roles() if view.task else {},
        "goals": view.task.goals if view.task else {},
        "bobBase": list(view.scene.bob_base) if view.scene else None,
    }
    if view.events:
        data["events"] = [m.as_data() for m in view.events]
    text = json.dumps(data, separators=(",", ":"), ensure_ascii=False)
    # inside <script>: no "</script>" or "<!--" can end it early
    return text.replace("<", "\\u003c").replace("\u2028", "\\u2028").replace("\u2029", "\\u2029")


def render_page(view: EpisodeView, diagnostics: Diagnostics | None = None, diagnostics_note: str | None = None) -> str:
    colors = robot_colors(view.robots)
    title = f"mhrc {view.header.task or ''} {view.header.scene or ''} seed {view.header.seed}"
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><meta name="viewport" content="width=device-width, initial-scale=1">
<title>{_e(title)}</title><style>{CSS}</style></head>
<body>
{_header(view)}
{_targets(view.task)}
{_map(view, colors)}
{page_coordination.section(view)}{lanes_section(view, colors)}
{messages_section(view, colors)}
{_failures(diagnostics, diagnostics_note)}
<script type="application/json" id="mhrc-data">{_data(view, colors)}</script>
<script>{JS}</script>
</body></html>
"""
