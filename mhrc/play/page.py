"""The play page: one HTML document with its style and script inline (nothing is fetched from
the network, as the report), talking to its server over one WebSocket (`/ws`).

The stable contract for tests and scripts: the observation panel is `[data-panel="observation"]`,
the messages `[data-panel="messages"]`, the status line `[data-status]` (its value: connecting,
starting, deciding, acting, done, refused, closed; `data-tick`, `data-success`); each skill's form
`form[data-skill="<skill>"]` with inputs named as the protocol's fields and a `[data-submit]`
button, a disabled form's reason in its `data-disabled`; a refused submission's reason in
`[data-refusal]` (`data-code`). Keys: w waits, r repeats the last action. The messages sit at
the top of the right column, beside the map, above the scene graph: a teammate's orders first.

The style and the script are inline and allowed by their hashes in the page's
Content-Security-Policy (mhrc.play.gate): an inline `style` attribute or handler would not run.
"""

from __future__ import annotations

from importlib.resources import files

from mhrc.viewer.wording import html_text as _e

CSS = files("mhrc.play").joinpath("page.css").read_text(encoding="utf-8")
JS = files("mhrc.play").joinpath("page.js").read_text(encoding="utf-8")


def page_html(robot: str) -> str:
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>mhrc play: {_e(robot)}</title>
<meta name="viewport" content="width=device-width, initial-scale=1"><style>{CSS}</style></head>
<body data-robot="{_e(robot)}">
<header><h1>mhrc play: you are <span class="who">{_e(robot)}</span></h1>
<div id="status" data-status="connecting" data-tick="" data-success="">connecting to the page's server…</div>
<div id="clock" data-clock="" hidden></div>
<div id="refusal" data-refusal="" data-code="" hidden></div></header>
<main>
<section id="left"><div id="map-box"><p class="dim">the map comes with the first observation</p></div>
<section id="controls"><h2>Your next action</h2><p class="dim">keys: <kbd>w</kbd> wait, <kbd>r</kbd> repeat your last action</p>
<div id="forms"></div></section></section>
<section id="right">
<section data-panel="messages" id="messages"><h2>Messages you received</h2><ol class="body"></ol></section>
<section data-panel="observation" id="observation"><h2>What you know</h2><div class="body"><p class="dim">nothing yet</p></div></section>
</section></main>
<script>{JS}</script></body></html>
"""
