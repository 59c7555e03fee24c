"""The episode report: one self-contained HTML file (CSS, JS and data inline, nothing fetched).

The static parts (header, the task's targets and which of them ended unplaced, house map's
furniture, robot lanes, messages, failure panel) are HTML written here, readable without
JavaScript; the map's moving parts (robots, paths, objects, open containers, messages in flight)
are drawn by a small script from the frames embedded as JSON in
`<script type="application/json" id="mhrc-data">`, one frame per world snapshot, scrubbed with a
range slider or the arrow keys (Home and End jump). The page opens on the last frame, the state
the episode was judged on. A robot's path follows each navigate's planned route where its result
carries one (older traces: straight lines between stops). Labels never cover one another: the
fixed ones are placed here (mhrc.viewer.placement), the moving ones by the script, which
measures them.
"""

from __future__ import annotations

import json
from html import escape
from collections.abc import Callable
from typing import Any

from mhrc.viewer.model import EpisodeView, Step
from mhrc.viewer.placement import Box, Request, place
from mhrc.viewer.targets import ObjectFate, TaskView
from mhrc.viewer.wording import diagnostic_label, partial_success

SCALE = 80.0  # SVG pixels per metre
ROBOT_COLORS = {"alice": "#d62728", "bob": "#1f77b4", "david": "#2ca02c"}
PALETTE = ["#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf"]


def _e(value: Any) -> str:
    return escape("" if value is None else str(value), quote=True)


def robot_colors(robots: list[str]) -> dict[str, str]:
    out: dict[str, str] = {}
    extra = iter(PALETTE * 4)
    for r in robots:
        out[r] = ROBOT_COLORS.get(r) or next(extra)
    return out


def _bounds(view: EpisodeView) -> tuple[float, float, float, float]:
    if view.scene:
        b = view.scene["bounds"]
        return float(b[0]) - 0.3, float(b[1]) + 0.3, float(b[2]) - 0.3, float(b[3]) + 0.3
    xs = [p["x"] for f in view.frames for group in ("robots", "objects") for p in f[group].values()]
    ys = [p["y"] for f in view.frames for group in ("robots", "objects") for p in f[group].values()]
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
            body = "".join("<tr>" + "".join(f"<td>{value_html(v.get(c), depth + 1)}</td>" for c in cols) + "</tr>" for v in value)
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
    models = ", ".join(f"{r}: {m}" for r, m in h["models"].items()) or "unknown"
    facts = {
        "task": h["task"], "scene": h["scene"], "seed": h["seed"], "objects": h["n_objects"],
        "robots": ", ".join(h["robots"]), "model(s)": models, "fidelity": h["fidelity"],
        "aids": ", ".join(h["aids"] or []) or "none", "scheduler": h["scheduler"], "horizon": h["horizon"],
        "TS lower bound": h["lower_bound"], "end": h["reason"] or "not recorded",
    }
    if h["scheduler"] == "async":
        facts["time scale"] = h["time_scale"]
        facts["step seconds"] = h["step_seconds"]
    facts["protocol version(s)"] = ", ".join(str(v) for v in h["versions"]) or "unknown"
    facts["trace"] = h["trace"]
    fact_rows = "".join(f"<tr><th>{_e(k)}</th><td>{_e(v if v is not None else 'unknown')}</td></tr>" for k, v in facts.items())
    m = h["metrics"]
    if m:
        key = {"success": "Succ", "partial_success": "PS", "temporal_steps": "TS", "action_steps": "AS"}
        ps = partial_success(m.get("partial_success"), m.get("placed"), m.get("total"))
        shown = {k: value_html(m.get(k)) for k in key}
        score, _, count = ps.partition(" ")
        count_html = f' <span class="mvs">{_e(count)}</span>' if count else ""
        shown["partial_success"] = _e(score) + count_html
        first = "".join(
            f'<div class="metric" data-metric="{k}"><div class="mv">{shown[k]}</div><div class="mk">{label}</div></div>' for k, label in key.items()
        )
        lb = h["lower_bound"]
        first += f'<div class="metric"><div class="mv">{_e(lb if lb is not None else "?")}</div><div class="mk">TS lower bound</div></div>'
        first += f'<div class="metric"><div class="mv">{value_html(m.get("makespan"))} s</div><div class="mk">makespan</div></div>'
        everything = {k: (ps if k == "partial_success" else v) for k, v in m.items()}
        metrics = f'<div class="metrics">{first}</div><details><summary>all metrics</summary>{value_html(everything)}</details>'
    else:
        metrics = '<p class="dim">no metrics: the trace has no episode_done event</p>'
    warn = "".join(f'<div class="warning">&#9888; {_e(w)}</div>' for w in view.warnings)
    title = f"{h['task'] or 'episode'} in {h['scene'] or 'an unknown scene'}, seed {h['seed'] if h['seed'] is not None else '?'}"
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
        return (f'<section id="targets"><h2>Targets</h2>{notes}<p class="tsum">The trace does not say which objects are '
                'targets (no observation of Bob\'s names them).</p></section>')
    targets = [o for o in task.objects if o.role == "target"]
    placed = [o for o in targets if o.placed]
    unplaced = task.unplaced
    unknown = [o for o in targets if o.placed is None]
    if unplaced:
        summary = (f'<span class="unplaced-count">{len(unplaced)} of {len(targets)} targets not placed</span> at the end: '
                   f'{_names_where(unplaced)}.')
    elif unknown:
        summary = f"{len(targets)} targets; whether they ended on their goals is not known."
    else:
        summary = f'<span class="placed-count">All {len(targets)} targets placed.</span>'
    if placed and unplaced:
        summary += f" Placed: {', '.join(f'<b>{_e(o.name)}</b>' for o in placed)}."
    ds = task.distractors
    summary += (f" Distractors (not on the list): {_names_where(ds)}." if ds else " No distractors.")
    rows = []
    dash = '<span class="dim">&#8212;</span>'
    for o in task.objects:
        if o.role == "target":
            state, cls = {True: ("&#10003; placed", "placed"), False: ("&#10007; not placed", "unplaced"), None: ("unknown", "")}[o.placed]
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


def _static_labels(view: EpisodeView, px: Callable[[float], float], py: Callable[[float], float], frame: Box) -> list[str]:
    """The furniture's and the goal area's labels, placed so that none covers another
    (mhrc.viewer.placement), with a leader line where a label sits away from its thing."""
    sc = view.scene
    assert sc is not None

    def box(cx: float, cy: float, sx: float, sy: float) -> Box:
        return Box(px(cx - sx / 2), py(cy + sy / 2), px(cx + sx / 2), py(cy - sy / 2))

    furniture = [(f, box(f["x"], f["y"], f["sx"], f["sy"])) for f in sc["furniture"]]
    goal = box(*sc["goal_area"])
    soft: list[tuple[Box, float]] = [(b, 1.0) for _, b in furniture] + [(goal, 1.0)]
    soft += [(box(*wall), 3.0) for wall in sc["walls"]]
    soft += [(box(fx["x"], fx["y"], 0.16, 0.12), 1.0) for fx in sc["fixtures"]]
    spots = {(round(o["x"], 1), round(o["y"], 1)) for f in view.frames for o in f["objects"].values()}
    soft += [(Box.centred(px(x), py(y), 14, 14), 3.0) for x, y in spots]  # where objects lie: keep them visible
    stands = {(round(r["x"], 1), round(r["y"], 1)) for f in view.frames for r in f["robots"].values()}
    soft += [(Box.centred(px(x), py(y), 22, 22), 1.0) for x, y in stands]
    requests = [Request(f["name"] + (" ▣" if f["openable"] else ""), "fname", b)
                for f, b in sorted(furniture, key=lambda fb: (fb[1].x1 - fb[1].x0) * (fb[1].y1 - fb[1].y0))]
    requests.append(Request("goal area", "gname", goal, fonts=(10.0, 8.5), prefer_outside=True))
    out = []
    for lab in place(requests, frame, soft):
        if lab.leader is not None:
            x1, y1, x2, y2 = lab.leader
            out.append(f'<line class="leader" x1="{x1}" y1="{y1}" x2="{x2}" y2="{y2}"/>')
        out.append(f'<text class="{lab.request.cls}" x="{round(lab.box.cx, 1)}" y="{lab.baseline}" '
                   f'font-size="{lab.font:g}">{_e(lab.request.text)}</text>')
    return out


def _map(view: EpisodeView, colors: dict[str, str]) -> str:
    xmin, xmax, ymin, ymax = _bounds(view)
    w, hgt = (xmax - xmin) * SCALE, (ymax - ymin) * SCALE

    def px(x: float) -> float:
        return round((x - xmin) * SCALE, 1)

    def py(y: float) -> float:
        return round((ymax - y) * SCALE, 1)

    def rect(cx: float, cy: float, sx: float, sy: float, cls: str, extra: str = "") -> str:
        return (f'<rect class="{cls}" x="{px(cx - sx / 2)}" y="{py(cy + sy / 2)}" width="{round(sx * SCALE, 1)}" '
                f'height="{round(sy * SCALE, 1)}"{extra}/>')

    parts: list[str] = []
    sc = view.scene
    if sc:
        b = sc["bounds"]
        parts.append(rect((b[0] + b[1]) / 2, (b[2] + b[3]) / 2, b[1] - b[0], b[3] - b[2], "floor"))
        for f in sc["furniture"]:
            if "open_footprint" in f:
                cx, cy, sx, sy = f["open_footprint"]
                parts.append(rect(cx, cy, sx, sy, "open-footprint", f' data-for="{_e(f["name"])}"'))
        for f in sc["furniture"]:
            r, g, bl = (int(255 * c) for c in f["color"][:3])
            cls = "furniture container" if f["openable"] else "furniture"
            parts.append(rect(f["x"], f["y"], f["sx"], f["sy"], cls,
                              f' data-name="{_e(f["name"])}" style="fill:rgb({r},{g},{bl})"><title>{_e(f["name"])}: {_e(f["kind"])}</title></rect'))
        gx, gy, gsx, gsy = sc["goal_area"]
        parts.append(rect(gx, gy, gsx, gsy, "goal-area", '><title>goal area</title></rect'))
        for fx in sc["fixtures"]:
            parts.append(rect(fx["x"], fx["y"], 0.16, 0.12, "fixture", f'><title>{_e(fx["name"])}</title></rect'))
        for wx, wy, wsx, wsy in sc["walls"]:
            parts.append(rect(wx, wy, wsx, wsy, "wall"))
        parts += _static_labels(view, px, py, Box(0.0, 0.0, w, hgt))
    legend = "".join(f'<span class="li"><span class="chip" style="background:{c}"></span>{_e(r)}</span> ' for r, c in colors.items())
    legend += "<br>" + " ".join(f'<span class="li"><span class="odot {cls}"></span>{text}</span>' for cls, text in (
        ("target unplaced", "target, not on its goal"), ("target placed", "target on its goal"), ("distractor", "distractor"),
        ("ring", "target not placed at the end")))
    n = len(view.frames)
    if view.frames_from == "snapshots":
        note = ""
    elif view.frames_from == "observations":
        note = '<div class="warning">&#9888; no snapshots in this trace: robot positions come from their own observations; objects are not shown</div>'
    else:
        note = '<div class="warning">&#9888; nothing to animate: the trace has no snapshots and no action results</div>'
    disabled = " disabled" if n == 0 else ""
    return f"""
<section id="map-section"><h2>House map</h2>{note}
<div class="controls">
  <button id="prev" type="button"{disabled}>&#9664;</button>
  <input type="range" id="tick-slider" min="0" max="{max(n - 1, 0)}" value="{max(n - 1, 0)}" step="1"{disabled} aria-label="frame">
  <button id="next" type="button"{disabled}>&#9654;</button>
  <span id="tick-label">{f'tick {view.frames[-1]["tick"]} (the end)' if n else 'no frames'}</span>
  <span class="dim">(frames: {n}; use the slider, the &#8592; &#8594; keys, Home or End)</span>
</div>
<div class="map-wrap">
<svg id="map" viewBox="0 0 {round(w, 1)} {round(hgt, 1)}" data-xmin="{xmin}" data-ymax="{ymax}" data-scale="{SCALE}" role="img" aria-label="top-down map">
<g id="static">{''.join(parts)}</g>
<g id="dyn"></g>
</svg>
<div id="frame-info"><div class="legend">{legend}</div><div id="frame-steps"></div><div id="frame-objects"></div></div>
</div>
</section>"""


def _reply_analysis(reply: str | None) -> str:
    if not reply:
        return ""
    lines = [ln for ln in reply.splitlines() if not ln.strip().lower().startswith("command")]
    return "\n".join(lines).strip()


def _step_html(s: Step) -> str:
    res = s.result or {}
    out = res.get("outcome") or {}
    ack = s.ack
    if ack is not None and not ack.get("accepted", True):
        status, cls = f"rejected: {ack.get('reason') or 'no reason given'}", "rejected"
    elif res:
        status, cls = ("ok", "ok") if out.get("succeeded") else (f"failed: {out.get('code', '?')}", "failed")
    elif ack is not None:
        status, cls = "accepted, no result recorded", "pending"
    else:
        status, cls = "no ack or result recorded", "pending"
    has_result = " has-result" if res else ""
    frame = "" if s.frame is None else f' data-frame="{s.frame}"'
    parts = [
        f'<li class="step {cls}{has_result}" data-goal="{_e(s.goal_id)}" data-tick="{_e(s.tick)}"{frame}>',
        f'<div class="shead"><span class="tick">t{_e(s.tick)}</span> <code class="call">{_e(s.call or "?")}</code>'
        f' <span class="badge {cls}">{_e(status)}</span></div>',
    ]
    if ack is not None:
        parts.append(f'<div class="ack">ack: {"accepted" if ack.get("accepted", True) else "rejected"}'
                     f'{": " + _e(ack.get("reason")) if ack.get("reason") else ""}</div>')
    if out:
        parts.append(f'<div class="feedback">{_e(out.get("feedback"))}</div>')
        if res.get("started") is not None:
            parts.append(f'<div class="dim">sim {res["started"]:.1f}–{(res.get("ended") or res["started"]):.1f} s</div>')
    t = s.thought
    if t:
        if t.get("prompt") is not None or t.get("reply") is not None:
            analysis = _reply_analysis(t.get("reply"))
            if t.get("reasoning"):
                parts.append(f'<details class="reasoning"><summary>reasoning ({_e(t.get("reasoning_tokens", 0))} tokens)</summary><pre>{_e(t["reasoning"])}</pre></details>')
            if analysis:
                parts.append(f'<div class="analysis">{_e(analysis)}</div>')
            parts.append(f'<div class="command">command: <code>{_e(t.get("action"))}</code></div>')
            if t.get("parse_error"):
                parts.append(f'<div class="perr">parse error: {_e(t["parse_error"])}</div>')
            parts.append(
                f'<div class="dim">{_e(t.get("policy"))} · {_e(t.get("prompt_tokens", 0))} prompt + {_e(t.get("completion_tokens", 0))} completion tokens'
                f' · {float(t.get("latency") or 0):.2f} s{" · finish " + _e(t["finish_reason"]) if t.get("finish_reason") else ""}</div>'
            )
            parts.append(f'<details class="prompt"><summary>prompt</summary><pre>{_e(t.get("prompt"))}</pre></details>')
            parts.append(f'<details class="reply"><summary>raw reply</summary><pre>{_e(t.get("reply"))}</pre></details>')
        elif t.get("parse_error"):
            parts.append(f'<div class="perr">{_e(t["parse_error"])}</div>')
    parts.append("</li>")
    return "".join(parts)


def _lanes(view: EpisodeView, colors: dict[str, str]) -> str:
    lanes = []
    for r in view.robots:
        steps = view.steps.get(r, [])
        items = "".join(_step_html(s) for s in steps)
        lanes.append(
            f'<div class="lane" data-robot="{_e(r)}"><h3 style="border-color:{colors[r]}">{_e(r)} '
            f'<span class="dim">{_e(view.header["models"].get(r))} · {len(steps)} steps</span></h3><ol>{items}</ol></div>'
        )
    return f'<section id="lanes-section"><h2>Robots</h2><div id="lanes">{"".join(lanes)}</div></section>'


def _messages(view: EpisodeView, colors: dict[str, str]) -> str:
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
    return ('<section id="messages"><h2>Messages</h2><table class="grid"><tr><th>sent at tick</th><th>from &#8594; to</th>'
            f'<th>delivered at tick</th><th>content</th></tr>{"".join(rows)}</table></section>')


LABELLED_KEYS = ("rejected_by_reason", "failed_by_code")  # breakdowns by kind or outcome code; the others are by name or skill


def _diagnostic_value(key: str, value: Any) -> str:
    """A diagnostics value: a breakdown's kinds and outcome codes labelled, object names and skills as they are."""
    if isinstance(value, dict) and value:
        def name(k: str) -> str:
            return f'<span title="{_e(k)}">{_e(diagnostic_label(k))}</span>' if key in LABELLED_KEYS else f"<code>{_e(k)}</code>"

        def inner(v: Any) -> str:
            if isinstance(v, dict):  # failed_by_skill: skill -> outcome code -> count
                return ", ".join(f'{_e(diagnostic_label(c))} &#215;{_e(n)}' for c, n in v.items())
            return _e(v)

        return "".join(f"<div>{name(str(k))}: {inner(v)}</div>" for k, v in value.items())
    if value in (0, None, {}) and not isinstance(value, bool):
        return f'<span class="dim">{"none" if value in (None, {}) else 0}</span>'
    return value_html(value)


def _failures(diagnostics: dict[str, Any] | None, note: str | None) -> str:
    """mhrc.core.diagnostics' findings with the labels people read (mhrc.core.diagnostics.LABELS); the key in each row's title."""
    if diagnostics is None:
        return f'<section id="failures"><h2>Failures</h2><p class="note">{_e(note)}</p></section>'
    rows = "".join(
        f'<tr data-key="{_e(k)}"><th title="{_e(k)}">{_e(diagnostic_label(str(k)))}</th><td>{_diagnostic_value(str(k), v)}</td></tr>'
        for k, v in diagnostics.items()
    )
    return f'<section id="failures"><h2>Failures</h2><table class="kv diag">{rows}</table></section>'


def _data(view: EpisodeView, colors: dict[str, str]) -> str:
    calls = {s.goal_id: {"robot": s.robot, "call": s.call, "ok": bool((s.result or {}).get("outcome", {}).get("succeeded"))}
             for lane in view.steps.values() for s in lane}
    data = {
        "robots": view.robots,
        "colors": colors,
        "frames": view.frames,
        "framesFrom": view.frames_from,
        "messages": [{"sender": m.sender, "to": m.to, "content": m.content, "sent": m.sent, "delivered": m.delivered, "frame": m.frame}
                     for m in view.messages],
        "calls": calls,
        "routes": view.routes,
        "roles": view.task.roles() if view.task else {},
        "goals": view.task.goals if view.task else {},
        "bobBase": view.scene["bob_base"] if view.scene else None,
    }
    text = json.dumps(data, separators=(",", ":"), ensure_ascii=False)
    # inside <script>: no "</script>" or "<!--" can end it early
    return text.replace("<", "\\u003c").replace("\u2028", "\\u2028").replace("\u2029", "\\u2029")


def render_page(view: EpisodeView, diagnostics: dict[str, Any] | None = None, diagnostics_note: str | None = None) -> str:
    colors = robot_colors(view.robots)
    title = f"mhrc {view.header.get('task') or ''} {view.header.get('scene') or ''} seed {view.header.get('seed')}"
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><meta name="viewport" content="width=device-width, initial-scale=1">
<title>{_e(title)}</title><style>{CSS}</style></head>
<body>
{_header(view)}
{_targets(view.task)}
{_map(view, colors)}
{_lanes(view, colors)}
{_messages(view, colors)}
{_failures(diagnostics, diagnostics_note)}
<script type="application/json" id="mhrc-data">{_data(view, colors)}</script>
<script>{JS}</script>
</body></html>
"""


CSS = """
body{font:14px/1.4 system-ui,sans-serif;margin:0 1.2em 2em;color:#222;background:#fafafa}
h1{font-size:1.4em;margin:.6em 0}h2{font-size:1.15em;margin:1.2em 0 .4em;border-bottom:1px solid #ccc}
.warning{background:#fff3cd;border:1px solid #e0b400;padding:.35em .6em;margin:.3em 0;border-radius:4px}
.note{background:#eef;border:1px solid #99c;padding:.35em .6em;border-radius:4px}
.dim{color:#777;font-size:.9em}
.cols{display:flex;gap:2em;flex-wrap:wrap;align-items:flex-start}
table.kv,table.grid{border-collapse:collapse}table.kv th,table.kv td,table.grid th,table.grid td{border:1px solid #ddd;padding:2px 6px;text-align:left;vertical-align:top}
table.kv th{background:#f0f0f0;font-weight:600}table.grid th{background:#f0f0f0}
.metrics{display:flex;gap:.8em;flex-wrap:wrap;margin-bottom:.5em}
.metric{background:#fff;border:1px solid #ccc;border-radius:6px;padding:.4em .8em;text-align:center;min-width:4.5em}
.mv{font-size:1.4em;font-weight:600}.mvs{font-size:.6em;font-weight:400;color:#555}.mk{color:#666;font-size:.85em}
.controls{display:flex;gap:.6em;align-items:center;margin:.4em 0}
#tick-slider{width:min(60vw,700px)}#tick-label{font-weight:600;min-width:8em}
.map-wrap{display:flex;gap:1em;flex-wrap:wrap;align-items:flex-start}
#map{width:min(100%,900px);background:#fff;border:1px solid #ccc}
#frame-info{flex:1;min-width:16em;font-size:.9em}
.floor{fill:#f4f1ea}.wall{fill:#444}.furniture{stroke:#333;stroke-width:1;opacity:.75}
.container{stroke-dasharray:4 2;stroke-width:1.5}.container.is-open{stroke:#e07000;stroke-width:3;stroke-dasharray:none}
.open-footprint{fill:none;stroke:none}.open-footprint.is-open{fill:#ffd9a8;stroke:#e07000;stroke-dasharray:3 2}
.goal-area{fill:#ffe680;fill-opacity:.55;stroke:#c9a000;stroke-width:2;stroke-dasharray:6 3}
.fixture{fill:#b0905a;stroke:#6b5020}
.fname{text-anchor:middle;fill:#111;paint-order:stroke;stroke:#fff;stroke-width:3px}
.gname{text-anchor:middle;fill:#806000;paint-order:stroke;stroke:#fff;stroke-width:3px}
.leader{stroke:#555;stroke-width:.8;stroke-dasharray:2 1.5}
.path{fill:none;stroke-width:2.5;stroke-opacity:.6;stroke-linejoin:round}
.obj{fill:#fff;stroke:#333;stroke-width:1.2}.obj.target{fill:#ff8c00}.obj.target.placed{fill:#137a13}.obj.distractor{fill:#d0d0d0;stroke:#777}
.obj.inside{stroke-dasharray:2 1;fill-opacity:.6}.obj.held{stroke:#000;stroke-width:2.5}
.ring{fill:none;stroke:#d00000;stroke-width:2;stroke-dasharray:3 2}
.oname{font-size:9px;fill:#333;paint-order:stroke;stroke:#fff;stroke-width:2.5px}.oname.target.unplaced{font-weight:700;fill:#a04800}.oname.distractor{fill:#777}
.rname{font-size:11px;font-weight:700;paint-order:stroke;stroke:#fff;stroke-width:3px}
.msgline{stroke-width:2;stroke-dasharray:6 4;fill:none}
.legend{margin-bottom:.5em;line-height:1.8}.legend .li{white-space:nowrap}.chip,.odot{display:inline-block;width:.9em;height:.9em;border-radius:50%;margin:0 .25em 0 .6em;vertical-align:middle;box-sizing:border-box}
.odot{border:1px solid #333;background:#fff}.odot.target{background:#ff8c00}.odot.target.placed{background:#137a13}.odot.distractor{background:#d0d0d0;border-color:#777}
.odot.ring{border:2px dashed #d00000;background:none}
#targets .tsum{font-size:1.05em}.unplaced-count{color:#b00000;font-weight:700}.placed-count{color:#1a7a1a;font-weight:700}
table.objs tr.unplaced td{background:#fdeaea}table.objs tr.placed td.state{color:#1a7a1a}table.objs tr.unplaced td.state{color:#b00000;font-weight:600}
table.objs tr.distractor td{color:#555}
#frame-objects li.target.unplaced{color:#a04800}
table.diag th{font-weight:600;white-space:nowrap}
#lanes{display:flex;gap:.8em;align-items:flex-start;overflow-x:auto}
.lane{flex:1;min-width:20em;max-height:80vh;overflow-y:auto;background:#fff;border:1px solid #ccc;border-radius:6px}
.lane h3{margin:0;padding:.4em .6em;border-bottom:4px solid;position:sticky;top:0;background:#fff;z-index:1}
.lane ol{list-style:none;margin:0;padding:.3em}
.step{border:1px solid #ddd;border-left:5px solid #999;border-radius:4px;margin:.3em 0;padding:.3em .5em;cursor:pointer}
.step.ok{border-left-color:#2a2}.step.failed{border-left-color:#d22}.step.rejected{border-left-color:#a0a;background:#fbeefb}.step.pending{border-left-color:#aaa}
.step.current{outline:3px solid #1f77b4;background:#eef6ff}.step.future{opacity:.45}
.badge{font-size:.8em;padding:0 .4em;border-radius:3px;background:#eee}.badge.ok{background:#d4f4d4}.badge.failed{background:#fbd4d4}.badge.rejected{background:#f0c8f0}
.tick{color:#666;font-size:.85em}.feedback{margin:.2em 0}.analysis{white-space:pre-wrap;color:#333;font-style:italic;margin:.2em 0}
.perr{color:#b00}pre{white-space:pre-wrap;word-break:break-word;max-height:30em;overflow:auto;background:#f6f6f6;padding:.4em;font-size:.85em}
tr.msg.current{background:#eef6ff}
"""

JS = r"""
(function(){
  const data = JSON.parse(document.getElementById('mhrc-data').textContent);
  const svg = document.getElementById('map');
  const NS = svg.namespaceURI;
  const dyn = document.getElementById('dyn');
  const slider = document.getElementById('tick-slider');
  const label = document.getElementById('tick-label');
  const frames = data.frames;
  const xmin = parseFloat(svg.dataset.xmin), ymax = parseFloat(svg.dataset.ymax), S = parseFloat(svg.dataset.scale);
  const vb = svg.viewBox.baseVal, W = vb.width, H = vb.height;
  const px = x => ((x - xmin) * S).toFixed(1), py = y => ((ymax - y) * S).toFixed(1);
  const esc = s => String(s).replace(/[&<>"']/g, c => ({'&':'&amp;','<':'&lt;','>':'&gt;','"':'&quot;',"'":'&#39;'}[c]));
  const last = frames.length - 1;
  let current = -1;

  // ---- label layout: every label of a frame takes the first spot around its dot that covers no
  // other label (the fixed ones included) and no robot or object, else the least covering one
  const overlap = (a, b) => { const w = Math.min(a.x1, b.x1) - Math.max(a.x0, b.x0), h = Math.min(a.y1, b.y1) - Math.max(a.y0, b.y0); return w > 0 && h > 0 ? w * h : 0; };
  const grow = (b, d) => ({x0: b.x0 - d, y0: b.y0 - d, x1: b.x1 + d, y1: b.y1 + d});
  let fixedBoxes = null;
  function fixed(){
    if (fixedBoxes === null) fixedBoxes = Array.from(document.querySelectorAll('#static text')).map(t => { const b = t.getBBox(); return grow({x0: b.x, y0: b.y, x1: b.x + b.width, y1: b.y + b.height}, 1); });
    return fixedBoxes;
  }
  function spots(it, w, h){
    const g = it.r + 3, out = [[it.x + g + w / 2, it.y], [it.x - g - w / 2, it.y], [it.x, it.y - g - h / 2], [it.x, it.y + g + h / 2],
      [it.x + g + w / 2, it.y - g - h / 2 + 4], [it.x - g - w / 2, it.y - g - h / 2 + 4], [it.x + g + w / 2, it.y + g + h / 2 - 4], [it.x - g - w / 2, it.y + g + h / 2 - 4]];
    for (const d of [10, 20, 32, 46, 62, 80, 100]) for (let k = 0; k < 16; k++){
      const t = Math.PI * 2 * k / 16;
      out.push([it.x + Math.cos(t) * (g + d + w / 2), it.y + Math.sin(t) * (g + d + h / 2)]);
    }
    return out;
  }
  function layoutLabels(items, layer){
    const taken = fixed().slice();
    const dots = items.map(it => ({x0: it.x - it.r, y0: it.y - it.r, x1: it.x + it.r, y1: it.y + it.r}));
    items.forEach((it, idx) => {
      const t = document.createElementNS(NS, 'text');
      t.setAttribute('class', it.cls); if (it.fill) t.setAttribute('fill', it.fill);
      t.setAttribute('x', '0'); t.setAttribute('y', '0'); t.textContent = it.text;
      if (it.name) t.dataset.for = it.name;
      layer.appendChild(t);
      const bb = t.getBBox();
      let best = null;
      spots(it, bb.width, bb.height).forEach((c, k) => {
        if (best && best.clean) return;
        const b = {x0: c[0] - bb.width / 2, y0: c[1] - bb.height / 2, x1: c[0] + bb.width / 2, y1: c[1] + bb.height / 2};
        if (b.x0 < 0 || b.y0 < 0 || b.x1 > W || b.y1 > H) return;
        const hard = taken.reduce((s, o) => s + overlap(b, o), 0);
        const soft = dots.reduce((s, o, j) => s + (j === idx ? 0 : overlap(b, o)), 0);
        const cost = hard * 1000 + soft * 10 + k * 4;
        if (!best || cost < best.cost) best = {cost: cost, b: b, clean: hard === 0 && soft === 0};
      });
      if (!best) best = {b: {x0: it.x + it.r, y0: it.y - bb.height / 2, x1: it.x + it.r + bb.width, y1: it.y + bb.height / 2}};
      const b = best.b;
      t.setAttribute('x', (b.x0 - bb.x).toFixed(1)); t.setAttribute('y', (b.y0 - bb.y).toFixed(1));
      taken.push(grow(b, 1));
      if (!overlap(b, grow(dots[idx], 5))){  // away from its dot: a leader line to it
        const cx = Math.min(Math.max(it.x, b.x0), b.x1), cy = Math.min(Math.max(it.y, b.y0), b.y1);
        const d = Math.hypot(cx - it.x, cy - it.y) || 1;
        const l = document.createElementNS(NS, 'line');
        l.setAttribute('class', 'leader'); l.setAttribute('x1', (it.x + (cx - it.x) * it.r / d).toFixed(1)); l.setAttribute('y1', (it.y + (cy - it.y) * it.r / d).toFixed(1));
        l.setAttribute('x2', cx.toFixed(1)); l.setAttribute('y2', cy.toFixed(1));
        layer.insertBefore(l, layer.firstChild);
      }
    });
  }

  function state(name, o){
    const role = data.roles[name] || 'unknown';
    if (role !== 'target') return role;
    const goal = data.goals[name];
    if (goal === undefined) return 'target';
    return (o.on === goal && !o.held_by) ? 'target placed' : 'target unplaced';
  }

  function draw(i){
    if (!frames.length) return;
    i = Math.max(0, Math.min(last, i));
    current = i;
    slider.value = i;
    const f = frames[i];
    label.textContent = (i === 0 ? 'start, ' : '') + 'tick ' + f.tick + ' (frame ' + (i + 1) + '/' + frames.length + (i === last ? ', the end' : '') + ')';
    label.dataset.tick = f.tick; label.dataset.frame = i;
    let out = '';
    // open containers
    document.querySelectorAll('#static .container, #static .open-footprint').forEach(el => {
      const name = el.dataset.name || el.dataset.for;
      el.classList.toggle('is-open', !!f.open[name]);
    });
    // paths up to this frame: a navigate's planned route where its result carries one, else straight
    for (const r of data.robots){
      const pts = [];
      let routed = 0;
      const add = (x, y) => { const s = px(x) + ',' + py(y); if (pts[pts.length - 1] !== s) pts.push(s); };
      for (let k = 0; k <= i; k++){
        const p = frames[k].robots[r];
        if (!p) continue;
        if (k > 0) for (const g of frames[k].goals){
          const c = data.calls[g], route = data.routes[g];
          if (c && c.robot === r && route){ route.forEach(q => add(q[0], q[1])); routed++; }
        }
        add(p.x, p.y);
      }
      if (pts.length > 1) out += '<polyline class="path" data-robot="' + esc(r) + '" data-routes="' + routed + '" stroke="' + data.colors[r] + '" points="' + pts.join(' ') + '"/>';
    }
    // messages sent in this frame's tick: sender -> receiver
    for (const m of data.messages){
      if (m.frame !== i) continue;
      const a = f.robots[m.sender], b = f.robots[m.to];
      if (!a || !b) continue;
      out += '<line class="msgline" stroke="' + (data.colors[m.sender] || '#555') + '" x1="' + px(a.x) + '" y1="' + py(a.y) + '" x2="' + px(b.x) + '" y2="' + py(b.y) + '"><title>' + esc(m.sender + ' -> ' + m.to + ': ' + m.content) + '</title></line>';
      out += '<circle r="5" fill="' + (data.colors[m.sender] || '#555') + '" cx="' + px(b.x) + '" cy="' + py(b.y) + '"/>';
    }
    // objects, styled by role: a target on its goal, a target elsewhere, a distractor
    const objs = [], labels = [];
    for (const [name, o] of Object.entries(f.objects)){
      const st = state(name, o);
      let cls = 'obj ' + st;
      if (o.held_by && f.robots[o.held_by]) cls += ' held';
      if (o.inside) cls += ' inside';
      const x = px(o.x), y = py(o.y), rad = st.startsWith('target') ? 6 : 4.5;
      const where = o.held_by ? 'held by ' + o.held_by : (o.on ? (o.inside ? 'in ' : 'on ') + o.on : 'on the floor');
      const role = st === 'target placed' ? 'target, placed' : st === 'target unplaced' ? 'target, not placed' : st;
      out += '<g class="object" data-name="' + esc(name) + '" data-role="' + esc(st) + '">'
        + (i === last && st === 'target unplaced' ? '<circle class="ring" r="11" cx="' + x + '" cy="' + y + '"/>' : '')
        + '<circle class="' + cls + '" r="' + rad + '" cx="' + x + '" cy="' + y + '"><title>' + esc(name + ' (' + role + '): ' + where) + '</title></circle></g>';
      labels.push({text: name, cls: 'oname ' + st, x: parseFloat(x), y: parseFloat(y), r: i === last && st === 'target unplaced' ? 11 : rad, name: name, order: st === 'target unplaced' ? 1 : st.startsWith('target') ? 2 : 3});
      objs.push('<li class="' + esc(st) + '"><b>' + esc(name) + '</b> <span class="dim">' + esc(role) + '</span>: ' + esc(where) + '</li>');
    }
    // robots
    for (const r of data.robots){
      const p = f.robots[r];
      if (!p) continue;
      const c = data.colors[r], x = px(p.x), y = py(p.y), yaw = p.yaw || 0;
      const hx = (parseFloat(x) + Math.cos(yaw) * 16).toFixed(1), hy = (parseFloat(y) - Math.sin(yaw) * 16).toFixed(1);
      out += '<g class="robot" data-robot="' + esc(r) + '" data-x="' + p.x + '" data-y="' + p.y + '">'
        + '<circle r="10" cx="' + x + '" cy="' + y + '" fill="' + c + '" fill-opacity=".85" stroke="#000"/>'
        + '<line x1="' + x + '" y1="' + y + '" x2="' + hx + '" y2="' + hy + '" stroke="#000" stroke-width="2.5"/></g>';
      labels.push({text: r + (p.holding ? ' [' + p.holding + ']' : ''), cls: 'rname', fill: c, x: parseFloat(x), y: parseFloat(y), r: 11, name: r, order: 0});
    }
    dyn.innerHTML = out + '<g id="labels"></g>';
    labels.sort((a, b) => a.order - b.order);
    layoutLabels(labels, document.getElementById('labels'));
    // what just happened
    const steps = f.goals.map(g => data.calls[g]).filter(Boolean)
      .map(c => '<li><b style="color:' + data.colors[c.robot] + '">' + esc(c.robot) + '</b> ' + esc(c.call) + (c.ok ? ' &#10003;' : ' &#10007;') + '</li>');
    document.getElementById('frame-steps').innerHTML = steps.length ? '<b>executed:</b><ul>' + steps.join('') + '</ul>' : '<b>executed:</b> nothing (start)';
    document.getElementById('frame-objects').innerHTML = objs.length ? '<b>objects:</b><ul>' + objs.join('') + '</ul>' : '';
    // lanes and messages follow the slider: the step of this frame is current, later ones are future
    document.querySelectorAll('.step').forEach(el => {
      const fr = el.dataset.frame === undefined ? null : parseInt(el.dataset.frame, 10);
      el.classList.toggle('current', fr === i);
      el.classList.toggle('future', fr !== null && fr > i);
    });
    document.querySelectorAll('.lane').forEach(lane => {
      const cur = lane.querySelector('.step.current');
      if (cur) lane.scrollTop = cur.offsetTop - lane.offsetTop - 40;
    });
    document.querySelectorAll('tr.msg').forEach(el => el.classList.toggle('current', el.dataset.frame !== undefined && parseInt(el.dataset.frame, 10) === i));
  }

  slider.addEventListener('input', () => draw(parseInt(slider.value, 10)));
  document.getElementById('prev').addEventListener('click', () => draw(current - 1));
  document.getElementById('next').addEventListener('click', () => draw(current + 1));
  document.addEventListener('keydown', e => {
    if (e.target === slider) return;  // the slider moves itself and fires input
    const t = e.target.tagName;
    if (t === 'INPUT' || t === 'TEXTAREA') return;
    if (e.key === 'ArrowRight') { draw(current + 1); e.preventDefault(); }
    if (e.key === 'ArrowLeft') { draw(current - 1); e.preventDefault(); }
    if (e.key === 'Home') { draw(0); e.preventDefault(); }
    if (e.key === 'End') { draw(last); e.preventDefault(); }
  });
  document.querySelectorAll('.step[data-frame]').forEach(el => el.addEventListener('click', ev => {
    if (ev.target.closest('details')) return;
    draw(parseInt(el.dataset.frame, 10));
  }));
  draw(last);  // the page opens on the end: the state the episode was judged on
})();
"""
