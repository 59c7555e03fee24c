
(function(){
  'use strict';
  const $ = s => document.querySelector(s);
  const esc = s => String(s).replace(/[&<>"']/g, c => ({'&':'&amp;','<':'&lt;','>':'&gt;','"':'&quot;',"'":'&#39;'}[c]));
  const statusEl = $('#status'), clockEl = $('#clock'), refusalEl = $('#refusal');
  const formsEl = $('#forms'), obsEl = $('#observation .body'), msgsEl = $('#messages .body');
  let hello = null, view = null, shownAt = 0, clockTimer = null, mapScene = null, ended = false;

  function setStatus(state, text, extra){
    statusEl.dataset.status = state;
    statusEl.textContent = text;
    if (extra && 'success' in extra) statusEl.dataset.success = extra.success;
    if (view) statusEl.dataset.tick = view.tick;
  }
  function refuse(code, reason){
    refusalEl.hidden = !reason;
    refusalEl.dataset.code = code || '';
    refusalEl.dataset.refusal = reason || '';
    refusalEl.textContent = reason ? 'refused: ' + reason : '';
  }
  function clock(on){
    if (clockTimer) { clearInterval(clockTimer); clockTimer = null; }
    if (!on) { clockEl.hidden = true; clockEl.dataset.clock = ''; return; }
    const tick = () => {
      const s = Math.floor((Date.now() - shownAt) / 1000);
      clockEl.hidden = false; clockEl.dataset.clock = String(s);
      clockEl.textContent = hello && hello.waits ? 'the world waits for you: ' + s + ' s' : 'your teammates go on while you think: ' + s + ' s';
    };
    tick(); clockTimer = setInterval(tick, 1000);
  }

  // The page's secret (the address's token) goes on to the socket; the tab's id, kept across its
  // reloads in sessionStorage, lets a reload take over the robot instead of being refused.
  const token = new URLSearchParams(location.search).get('token') || '';
  let tab = '';
  try {
    tab = sessionStorage.getItem('mhrc-play-tab') || '';
    if (!tab){ tab = crypto.randomUUID ? crypto.randomUUID() : String(Math.random()).slice(2); sessionStorage.setItem('mhrc-play-tab', tab); }
  } catch (e) { tab = ''; }
  const ws = new WebSocket((location.protocol === 'https:' ? 'wss://' : 'ws://') + location.host + '/ws?token=' + encodeURIComponent(token) + '&tab=' + encodeURIComponent(tab));
  let replaced = false;
  function send(obj){ if (ws.readyState === 1) ws.send(JSON.stringify(obj)); }
  function submit(skill, values){
    if (!view) return;
    refuse('', '');
    send(Object.assign({type: 'submit', tick: view.tick, skill: skill}, values));
  }

  // ---- drawing
  const LABEL_PX = 13;  // a map label's size on screen, whatever the map's scale
  const boxOf = (x, y, w, h, pad) => ({x: x - pad, y: y - pad, w: w + 2 * pad, h: h + 2 * pad});
  const hits = (a, b) => a.x < b.x + b.w && b.x < a.x + a.w && a.y < b.y + b.h && b.y < a.y + a.h;
  // Put the text `t` at the first of `spots` ([x, y], text-anchor middle) where it overlaps nothing
  // in `taken` and stays on the map (else where it overlaps least); its box joins `taken`.
  function placeLabel(t, spots, taken, vb, pad){
    t.setAttribute('x', '0'); t.setAttribute('y', '0');
    const b = t.getBBox();
    let best = null, bestCost = Infinity;
    for (const [x, y] of spots){
      const box = boxOf(x + b.x, y + b.y, b.width, b.height, pad);
      let cost = (box.x < 0 || box.y < 0 || box.x + box.w > vb.width || box.y + box.h > vb.height) ? 1e9 : 0;
      for (const o of taken) if (hits(box, o)) cost += 1e6 + (Math.min(box.x + box.w, o.x + o.w) - Math.max(box.x, o.x)) * (Math.min(box.y + box.h, o.y + o.h) - Math.max(box.y, o.y));
      if (cost < bestCost){ best = [x, y, box]; bestCost = cost; }
      if (cost === 0) break;
    }
    t.setAttribute('x', best[0].toFixed(1)); t.setAttribute('y', best[1].toFixed(1));
    taken.push(best[2]);
  }
  function furnitureSpots(t, fs){
    const [x, y, w, h] = t.dataset.box.split(' ').map(parseFloat), cx = x + w / 2, cy = y + h / 2;
    const spots = [[cx, cy + 0.35 * fs]];
    for (let k = 0; k < 6; k++){
      for (const sy of [y + h + (0.95 + 1.1 * k) * fs, y - (0.3 + 1.1 * k) * fs])
        for (const dx of [0, w / 2, -w / 2, w, -w]) spots.push([cx + dx, sy]);
    }
    return spots;
  }
  function objectSpots(x, y, r, fs, w){
    const spots = [];
    for (let k = 0; k < 6; k++){
      const dy = 1.1 * k * fs;
      spots.push([x + r + 3 + w / 2, y + 0.35 * fs + dy], [x - r - 3 - w / 2, y + 0.35 * fs + dy],
                 [x, y - r - 3 - dy], [x, y + r + 0.95 * fs + dy],
                 [x + r + 3 + w / 2, y + 0.35 * fs - dy], [x - r - 3 - w / 2, y + 0.35 * fs - dy]);
    }
    return spots;
  }
  function drawMap(v){
    if (v.map && v.map_scene !== mapScene){ $('#map-box').innerHTML = v.map; mapScene = v.map_scene; }
    const svg = $('#map'); if (!svg) return;
    const xmin = parseFloat(svg.dataset.xmin), ymax = parseFloat(svg.dataset.ymax), S = parseFloat(svg.dataset.scale);
    const vb = svg.viewBox.baseVal, shown = svg.getBoundingClientRect().width;
    const u = shown > 0 ? vb.width / shown : 1;  // the SVG's units in one screen pixel
    const fs = LABEL_PX * u, pad = 1.5 * u;
    const px = x => (x - xmin) * S, py = y => (ymax - y) * S;
    const o = v.observation, st = o.status;
    const taken = [];
    for (const t of svg.querySelectorAll('text[data-label="furniture"]')){
      t.style.fontSize = fs.toFixed(1) + 'px'; t.style.strokeWidth = (3 * u).toFixed(1) + 'px';
      placeLabel(t, furnitureSpots(t, fs), taken, vb, pad);
    }
    const r = 6 * u, known = [];
    let out = '';
    for (const ob of o.objects){
      if (ob.last_seen_on && !ob.on && !ob.held_by) continue;
      const x = px(ob.position[0]), y = py(ob.position[1]);
      known.push([ob, x, y]);
      taken.push(boxOf(x - r, y - r, 2 * r, 2 * r, 0));
      const cls = 'obj' + (ob.told_by ? ' told' : '');
      out += '<circle class="' + cls + '" data-object="' + esc(ob.name) + '" cx="' + x.toFixed(1) + '" cy="' + y.toFixed(1) + '" r="' + r.toFixed(1) + '"><title>' + esc(ob.name) + (ob.told_by ? ' (told by ' + esc(ob.told_by) + ')' : '') + '</title></circle>';
    }
    const at = st.base ? [st.base.x, st.base.y, st.base.yaw] : (st.arm_base ? [st.arm_base[0], st.arm_base[1], 0] : null);
    if (at){
      const x = px(at[0]), y = py(at[1]), R = 9 * u;
      taken.push(boxOf(x - R, y - R, 2 * R, 2 * R, 0));
      out += '<circle class="me" data-robot="' + esc(st.name) + '" cx="' + x.toFixed(1) + '" cy="' + y.toFixed(1) + '" r="' + R.toFixed(1) + '"><title>you</title></circle>';
      out += '<line stroke="#000" stroke-width="' + (2 * u).toFixed(1) + '" x1="' + x.toFixed(1) + '" y1="' + y.toFixed(1) + '" x2="' + (x + 1.5 * R * Math.cos(at[2])).toFixed(1) + '" y2="' + (y - 1.5 * R * Math.sin(at[2])).toFixed(1) + '"/>';
    }
    for (const [ob] of known) out += '<text class="oname" data-label="object" data-name="' + esc(ob.name) + '">' + esc(ob.name) + '</text>';
    const dyn = $('#dyn');
    dyn.innerHTML = out;
    const labels = dyn.querySelectorAll('text[data-label="object"]');
    known.forEach(([ob, x, y], i) => {
      const t = labels[i];
      t.style.fontSize = fs.toFixed(1) + 'px'; t.style.strokeWidth = (3 * u).toFixed(1) + 'px';
      t.setAttribute('x', '0'); t.setAttribute('y', '0');
      placeLabel(t, objectSpots(x, y, r, fs, t.getBBox().width), taken, vb, pad);
    });
  }
  let resizing = null;
  window.addEventListener('resize', () => { clearTimeout(resizing); resizing = setTimeout(() => { if (view) drawMap(view); }, 150); });
  function drawText(v){
    const t = v.text, h = v.histories;
    const hist = (title, rows) => '<h3>' + esc(title) + '</h3><pre>' + (rows.length ? rows.map(e => 'step ' + e.step + ': ' + esc(e.text)).join('\n') : '(none yet)') + '</pre>';
    obsEl.innerHTML = '<h3>Status</h3><pre data-section="status">' + esc(t.status) + '</pre>'
      + '<h3>Task</h3><pre data-section="task">' + esc(t.task) + (t.progress ? '\n\n' + esc(t.progress) : '') + '</pre>'
      + '<h3>Teammates</h3><pre data-section="teammates">' + esc(t.teammates) + '</pre>'
      + '<h3>Scene graph (what you know)</h3><pre data-section="scene_graph">' + esc(t.scene_graph) + '</pre>'
      + '<div data-section="feedback">' + hist('Feedback on your actions', h.feedback) + '</div>'
      + '<div data-section="actions">' + hist('Your actions so far', h.actions) + '</div>';
    msgsEl.innerHTML = h.messages.length ? h.messages.map(e => '<li data-step="' + e.step + '">step ' + e.step + ': ' + esc(e.text) + '</li>').join('') : '<li class="dim">none yet</li>';
    msgsEl.scrollTop = msgsEl.scrollHeight;  // the newest in sight
  }
  function field(f, form){
    if (f.kind === 'choice'){
      const opts = f.choices.map(c => '<option value="' + esc(c) + '">' + esc(c) + '</option>').join('');
      return '<label>' + esc(f.name) + ' <select name="' + esc(f.name) + '">' + opts + '</select></label>';
    }
    if (f.kind === 'number') return '<label>' + esc(f.name) + ' <input type="number" step="0.05" value="0" name="' + esc(f.name) + '"></label>';
    return '<input type="text" name="' + esc(f.name) + '" placeholder="your message">';
  }
  function drawForms(v){
    formsEl.innerHTML = v.forms.map(f => {
      const why = f.disabled || '';
      return '<form data-skill="' + esc(f.skill) + '" data-disabled="' + esc(why) + '"><fieldset' + (why ? ' disabled' : '') + '>'
        + '<span class="skill">' + esc(f.skill) + '</span>' + f.fields.map(x => field(x, f)).join('')
        + '<button type="submit" data-submit>' + esc(f.skill === 'wait' ? 'wait (w)' : f.skill) + '</button>'
        + (why ? '<span class="why" data-why>' + esc(why) + '</span>' : '') + '</fieldset></form>';
    }).join('');
    for (const f of v.forms){
      const form = formsEl.querySelector('form[data-skill="' + f.skill + '"]');
      const target = form.querySelector('select[name="target"]'), pose = form.querySelector('select[name="stand_pose"]');
      if (f.skill === 'navigate' && target && pose){  // a target's own stand poses
        const fit = () => { const n = f.stand_poses[target.value] || 0; for (const o of pose.options) o.hidden = parseInt(o.value, 10) >= n; if (parseInt(pose.value, 10) >= n) pose.value = '0'; };
        target.addEventListener('change', fit); fit();
      }
      form.addEventListener('submit', ev => {
        ev.preventDefault();
        const values = {};
        for (const el of form.querySelectorAll('select, input')) values[el.name] = el.value;
        submit(f.skill, values);
      });
    }
    enable(v.deciding);
  }
  function enable(on){
    for (const fs of formsEl.querySelectorAll('fieldset')){
      const why = fs.parentElement.dataset.disabled;
      fs.disabled = !on || !!why;
    }
  }

  // ---- messages from the server
  function handle(m){
    if (ended) return;  // the end is said once (the last action's result may come after it)
    if (m.type === 'hello'){
      hello = m;
      setStatus('starting', m.started ? 'attaching ' + m.robot + '…' : 'waiting for the episode to start (it starts when every robot is attached)…');
    } else if (m.type === 'started'){
      if (!view) setStatus('starting', 'the episode started: waiting for your first observation…');
    } else if (m.type === 'view'){
      view = m; shownAt = Date.now() - 1000 * (m.waited || 0);
      drawMap(m); drawText(m); drawForms(m);
      if (m.deciding){ setStatus('deciding', 'tick ' + m.tick + ': your turn: choose an action'); clock(true); }
      else { setStatus('acting', 'tick ' + m.tick + ': waiting for the world'); clock(false); }
    } else if (m.type === 'accepted'){
      if (view) view.deciding = false;
      enable(false); clock(false);
      setStatus('acting', 'tick ' + m.tick + ': ' + m.action + ' sent: waiting for the world (and your teammates)');
    } else if (m.type === 'refused'){
      refuse(m.code, m.reason);
    } else if (m.type === 'result'){
      setStatus('acting', 'tick ' + m.tick + ': ' + m.action + (m.ok ? ' succeeded' : ' failed') + ': ' + m.feedback);
    } else if (m.type === 'detached'){
      if (hello && m.robot === hello.robot) setStatus('closed', 'the world detached you: ' + m.reason);
    } else if (m.type === 'done'){
      ended = true; enable(false); clock(false);
      const verdict = m.success ? 'success' : 'no success';  // the reason is said only when it adds to the verdict
      const why = m.reason && m.reason !== verdict && !(m.success && m.reason === 'success') ? ' (' + m.reason + ')' : '';
      setStatus('done', 'the episode is over: ' + verdict + why + ', ' + m.placed + '/' + m.total + ' placed in ' + m.temporal_steps + ' steps', {success: m.success ? 'yes' : 'no'});
    } else if (m.type === 'refused_tab'){
      refuse('second_driver', m.reason); setStatus('refused', 'this page does not drive ' + (document.body.dataset.robot || 'the robot') + ': ' + m.reason);
    } else if (m.type === 'replaced'){
      replaced = true; enable(false); clock(false); setStatus('closed', m.reason);
    } else if (m.type === 'error'){
      setStatus('closed', 'the robot\u2019s agent ended: ' + m.reason);
    }
  }
  ws.onmessage = ev => handle(JSON.parse(ev.data));
  ws.onclose = () => {
    enable(false); clock(false);
    if (!ended && !replaced && statusEl.dataset.status !== 'refused') setStatus('closed', 'the page\u2019s server closed the connection');
  };

  // ---- for scripts and tests: send a submission as given (the server checks it as any other)
  // (show: draw a view as the server would send it, here only: a check of the page's drawing)
  window.mhrcPlay = {send: obj => send(Object.assign({type: 'submit'}, obj)), view: () => view, show: v => handle(Object.assign({}, v, {type: 'view'}))};

  // ---- keys: w waits, r repeats the last action (not while typing)
  document.addEventListener('keydown', ev => {
    const tag = (ev.target && ev.target.tagName) || '';
    if (['INPUT', 'TEXTAREA', 'SELECT'].includes(tag) || ev.ctrlKey || ev.metaKey || ev.altKey || !view || !view.deciding) return;
    if (ev.key === 'w'){ ev.preventDefault(); submit('wait', {}); }
    else if (ev.key === 'r' && view.last){ ev.preventDefault(); const last = Object.assign({}, view.last); const skill = last.skill; delete last.skill; submit(skill, last); }
  });
})();
