
(function(){
  // every object of the data without a prototype: a robot, object or goal is looked up by its name,
  // and a name such as `constructor` must find nothing rather than Object.prototype's member
  const bare = (k, v) => (v !== null && typeof v === 'object' && !Array.isArray(v)) ? Object.assign(Object.create(null), v) : v;
  const data = JSON.parse(document.getElementById('mhrc-data').textContent, bare);
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
  const events = data.events || [];  // a dynamic episode's scenario events (mhrc/viewer/events.py)
  const glyphs = {relocate: '\u25c6', new_target: '\u2605', close: '\u25a0', breakdown: '\u25b2'};
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
      t.setAttribute('x', '0'); t.setAttribute('y', '0');
      if (it.lines){  // a stack: one line per object, top first, each styled by its own role
        it.lines.forEach((ln, k) => {
          const sp = document.createElementNS(NS, 'tspan');
          sp.setAttribute('x', '0'); if (k) sp.setAttribute('dy', '1.15em');
          sp.setAttribute('class', ln.cls); sp.textContent = ln.text;
          t.appendChild(sp);
        });
        t.dataset.stack = it.lines.map(ln => ln.text).join(',');
      } else t.textContent = it.text;
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
      t.querySelectorAll('tspan').forEach(sp => sp.setAttribute('x', t.getAttribute('x')));
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

  // objects whose dots lie over each other (a stack, a pile on one spot) get one label listing
  // them, top first, instead of labels crowded round one point
  function stacks(items){
    const groups = [];
    for (const it of items){
      const g = groups.find(g => Math.hypot(g[0].x - it.x, g[0].y - it.y) < Math.max(g[0].r, it.r));
      if (g) g.push(it); else groups.push([it]);
    }
    return groups.map(g => {
      if (g.length === 1) return g[0];
      g.sort((a, b) => b.z - a.z);
      return {lines: g.map(it => ({text: it.text, cls: it.cls})), cls: 'oname stack', x: g[0].x, y: g[0].y,
        r: Math.max(...g.map(it => it.r)), name: g[0].name, order: Math.min(...g.map(it => it.order))};
    });
  }

  function state(name, o){
    const role = data.roles[name] || 'unknown';
    if (role !== 'target') return role;
    const goal = data.goals[name];
    if (goal === undefined) return 'target';
    return (o.on === goal && !o.held_by) ? 'target placed' : 'target unplaced';
  }

  function shape(kind, x, y){
    if (kind === 'relocate') return '<polygon class="shape" points="' + [[x, y - 12], [x + 12, y], [x, y + 12], [x - 12, y]].map(p => p.join(',')).join(' ') + '"/>';
    if (kind === 'close') return '<rect class="shape" x="' + (x - 10) + '" y="' + (y - 10) + '" width="20" height="20"/>';
    if (kind === 'breakdown') return '<polygon class="shape" points="' + [[x, y - 8], [x + 7.5, y + 5], [x - 7.5, y + 5]].map(p => p.join(',')).join(' ') + '"/>';
    const pts = [];  // new_target: a five-pointed star
    for (let k = 0; k < 10; k++){ const a = -Math.PI / 2 + k * Math.PI / 5, rr = k % 2 ? 6 : 14; pts.push((x + Math.cos(a) * rr).toFixed(1) + ',' + (y + Math.sin(a) * rr).toFixed(1)); }
    return '<polygon class="shape" points="' + pts.join(' ') + '"/>';
  }
  function eventMarks(i, f, labels, broken){
    let out = '';
    for (const e of events){
      if (e.frame === null || e.frame > i || !e.applied) continue;
      const cls = 'ev-mark ev-' + esc(e.event) + (e.frame === i ? ' fresh' : '');
      const head = '<g class="' + cls + '" data-index="' + e.index + '" data-event="' + esc(e.event) + '"><title>' + esc(e.text) + '</title>';
      if (e.event === 'breakdown'){
        const p = f.robots[e.robot];
        if (!p || (e.until !== null && f.tick >= e.until)) continue;  // it works again
        const x = parseFloat(px(p.x)) + 11, y = parseFloat(py(p.y)) - 11;
        broken[e.robot] = head + shape('breakdown', x, y) + '</g>';
        continue;
      }
      if (!e.at) continue;
      const x = parseFloat(px(e.at[0])), y = parseFloat(py(e.at[1]));
      if (e.origin){
        const ox = parseFloat(px(e.origin[0])), oy = parseFloat(py(e.origin[1])), d = Math.hypot(x - ox, y - oy) || 1;
        out += '<line class="ev-arrow ev-' + esc(e.event) + '" data-index="' + e.index + '" x1="' + ox.toFixed(1) + '" y1="' + oy.toFixed(1) + '" x2="' + (x - (x - ox) * 13 / d).toFixed(1)
          + '" y2="' + (y - (y - oy) * 13 / d).toFixed(1) + '" marker-end="url(#ev-head)"><title>' + esc(e.text) + '</title></line>';
      }
      out += head + shape(e.event, x, y) + '</g>';
      labels.push({text: e.label, cls: 'evname ev-' + e.event, x: x, y: y, r: 13, name: 'event-' + e.index, order: 1});
    }
    return out ? '<defs><marker id="ev-head" viewBox="0 0 10 10" refX="8" refY="5" markerWidth="7" markerHeight="7" orient="auto"><path d="M0,0 L10,5 L0,10 z" fill="#7b3fb5"/></marker></defs>' + out : out;
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
    // scenario events from their frame on, where they happened (under the objects they mark);
    // a breakdown on its robot while it is broken down
    const labels = [], broken = Object.create(null);
    out += eventMarks(i, f, labels, broken);
    // objects, styled by role: a target on its goal, a target elsewhere, a distractor
    const objs = [], objLabels = [];
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
      objLabels.push({text: name, cls: 'oname ' + st, x: parseFloat(x), y: parseFloat(y), z: o.z || 0, r: i === last && st === 'target unplaced' ? 11 : rad, name: name, order: st === 'target unplaced' ? 1 : st.startsWith('target') ? 2 : 3});
      objs.push('<li class="' + esc(st) + '"><b>' + esc(name) + '</b> <span class="dim">' + esc(role) + '</span>: ' + esc(where) + '</li>');
    }
    stacks(objLabels).forEach(l => labels.push(l));
    // robots
    for (const r of data.robots){
      const p = f.robots[r];
      if (!p) continue;
      const c = data.colors[r], x = px(p.x), y = py(p.y), yaw = p.yaw || 0;
      const hx = (parseFloat(x) + Math.cos(yaw) * 16).toFixed(1), hy = (parseFloat(y) - Math.sin(yaw) * 16).toFixed(1);
      const alt = (data.fliers || Object.create(null))[r];  // a drone: a dashed ring for its rotors, its altitude on hover
      out += '<g class="robot' + (alt !== undefined ? ' flying' : '') + '" data-robot="' + esc(r) + '" data-x="' + p.x + '" data-y="' + p.y + '"' + (alt !== undefined ? ' data-altitude="' + alt + '"' : '') + '>'
        + (alt !== undefined ? '<title>' + esc(r + ' flies at ' + alt.toFixed(2) + ' m') + '</title><circle class="rotors" r="15" cx="' + x + '" cy="' + y + '" fill="none" stroke="' + c + '" stroke-width="2" stroke-dasharray="4 3"/>' : '')
        + '<circle r="10" cx="' + x + '" cy="' + y + '" fill="' + c + '" fill-opacity=".85" stroke="#000"/>'
        + '<line x1="' + x + '" y1="' + y + '" x2="' + hx + '" y2="' + hy + '" stroke="#000" stroke-width="2.5"/></g>';
      if (broken[r]) out += broken[r];
      labels.push({text: r + (alt !== undefined ? ' (' + alt.toFixed(1) + ' m up)' : '') + (p.holding ? ' [' + p.holding + ']' : '') + (broken[r] ? ' (broken down)' : ''), cls: 'rname', fill: c, x: parseFloat(x), y: parseFloat(y), r: broken[r] ? 20 : 11, name: r, order: 0});
    }
    dyn.innerHTML = out + '<g id="labels"></g>';
    labels.sort((a, b) => a.order - b.order);
    layoutLabels(labels, document.getElementById('labels'));
    // what just happened
    const steps = f.goals.map(g => data.calls[g]).filter(Boolean)
      .map(c => '<li><b style="color:' + data.colors[c.robot] + '">' + esc(c.robot) + '</b> ' + esc(c.call) + (c.ok ? ' &#10003;' : ' &#10007;') + '</li>');
    document.getElementById('frame-steps').innerHTML = steps.length ? '<b>executed:</b><ul>' + steps.join('') + '</ul>' : '<b>executed:</b> nothing (start)';
    document.getElementById('frame-objects').innerHTML = objs.length ? '<b>objects:</b><ul>' + objs.join('') + '</ul>' : '';
    const fe = document.getElementById('frame-events');
    if (fe){
      const now = events.filter(e => e.frame === i).map(e => '<li class="ev-' + esc(e.event) + (e.applied ? '' : ' skipped') + '"><span class="ev-glyph ev-' + esc(e.event) + '">' + (glyphs[e.event] || '?') + '</span> '
        + esc(e.text) + (e.applied || (e.skipped && e.text.includes(e.skipped)) ? '' : ' <span class="skip-why">(skipped: ' + esc(e.skipped || 'no reason given') + ')</span>') + '</li>');
      fe.innerHTML = now.length ? '<b>scenario events:</b><ul>' + now.join('') + '</ul>' : '';
    }
    // lanes and messages follow the slider: the step of this frame is current, later ones are future
    document.querySelectorAll('.step, .lane-event').forEach(el => {
      const fr = el.dataset.frame === undefined ? null : parseInt(el.dataset.frame, 10);
      el.classList.toggle('current', fr === i);
      el.classList.toggle('future', fr !== null && fr > i);
    });
    // the lanes scroll together, in their own box (never the page): this frame's tick row (or the next) to the top
    const box = document.getElementById('lanes');
    const cur = box && (box.querySelector('.step.current, .lane-event.current') || box.querySelector('.step.future, .lane-event.future'));
    if (cur){
      const head = box.querySelector('.lane h3');
      box.scrollTop = Math.max(0, cur.closest('.tick-cell').offsetTop - (head ? head.offsetHeight : 0) - 6);
    }
    document.querySelectorAll('.ev-marker').forEach(el => el.classList.toggle('current', el.dataset.frame !== undefined && parseInt(el.dataset.frame, 10) === i));
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
  document.querySelectorAll('.ev-marker[data-frame]').forEach(el => el.addEventListener('keydown', ev => {
    if (ev.key === 'Enter' || ev.key === ' ') { draw(parseInt(el.dataset.frame, 10)); ev.preventDefault(); }
  }));
  document.querySelectorAll('.step[data-frame], .lane-event[data-frame], .ev-marker[data-frame]').forEach(el => el.addEventListener('click', ev => {
    if (ev.target.closest('details')) return;
    draw(parseInt(el.dataset.frame, 10));
  }));
  draw(last);  // the page opens on the end: the state the episode was judged on
})();
