
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

  const ws = new WebSocket((location.protocol === 'https:' ? 'wss://' : 'ws://') + location.host + '/ws');
  function send(obj){ if (ws.readyState === 1) ws.send(JSON.stringify(obj)); }
  function submit(skill, values){
    if (!view) return;
    refuse('', '');
    send(Object.assign({type: 'submit', tick: view.tick, skill: skill}, values));
  }

  // ---- drawing
  function drawMap(v){
    if (v.map && v.map_scene !== mapScene){ $('#map-box').innerHTML = v.map; mapScene = v.map_scene; }
    const svg = $('#map'); if (!svg) return;
    const xmin = parseFloat(svg.dataset.xmin), ymax = parseFloat(svg.dataset.ymax), S = parseFloat(svg.dataset.scale);
    const px = x => ((x - xmin) * S).toFixed(1), py = y => ((ymax - y) * S).toFixed(1);
    const o = v.observation, st = o.status;
    let out = '';
    for (const ob of o.objects){
      if (ob.last_seen_on && !ob.on && !ob.held_by) continue;
      const cls = 'obj' + (ob.told_by ? ' told' : '');
      out += '<circle class="' + cls + '" data-object="' + esc(ob.name) + '" cx="' + px(ob.position[0]) + '" cy="' + py(ob.position[1]) + '" r="5"><title>' + esc(ob.name) + (ob.told_by ? ' (told by ' + esc(ob.told_by) + ')' : '') + '</title></circle>';
      out += '<text class="oname" x="' + (parseFloat(px(ob.position[0])) + 7) + '" y="' + (parseFloat(py(ob.position[1])) - 5) + '">' + esc(ob.name) + '</text>';
    }
    const at = st.base ? [st.base.x, st.base.y, st.base.yaw] : (st.arm_base ? [st.arm_base[0], st.arm_base[1], 0] : null);
    if (at){
      const x = parseFloat(px(at[0])), y = parseFloat(py(at[1]));
      out += '<circle class="me" data-robot="' + esc(st.name) + '" cx="' + x + '" cy="' + y + '" r="10"><title>you</title></circle>';
      out += '<line stroke="#000" stroke-width="2" x1="' + x + '" y1="' + y + '" x2="' + (x + 14 * Math.cos(at[2])).toFixed(1) + '" y2="' + (y - 14 * Math.sin(at[2])).toFixed(1) + '"/>';
    }
    $('#dyn').innerHTML = out;
  }
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
  ws.onmessage = ev => {
    const m = JSON.parse(ev.data);
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
      setStatus('done', 'the episode is over (' + m.reason + '): ' + (m.success ? 'success' : 'no success') + ', ' + m.placed + '/' + m.total + ' placed in ' + m.temporal_steps + ' steps', {success: m.success ? 'yes' : 'no'});
    } else if (m.type === 'refused_tab'){
      refuse('second_driver', m.reason); setStatus('refused', 'this page does not drive ' + (document.body.dataset.robot || 'the robot') + ': ' + m.reason);
    } else if (m.type === 'error'){
      setStatus('closed', 'the robot\u2019s agent ended: ' + m.reason);
    }
  };
  ws.onclose = () => {
    enable(false); clock(false);
    if (!ended && statusEl.dataset.status !== 'refused') setStatus('closed', 'the page\u2019s server closed the connection');
  };

  // ---- for scripts and tests: send a submission as given (the server checks it as any other)
  window.mhrcPlay = {send: obj => send(Object.assign({type: 'submit'}, obj)), view: () => view};

  // ---- keys: w waits, r repeats the last action (not while typing)
  document.addEventListener('keydown', ev => {
    const tag = (ev.target && ev.target.tagName) || '';
    if (['INPUT', 'TEXTAREA', 'SELECT'].includes(tag) || ev.ctrlKey || ev.metaKey || ev.altKey || !view || !view.deciding) return;
    if (ev.key === 'w'){ ev.preventDefault(); submit('wait', {}); }
    else if (ev.key === 'r' && view.last){ ev.preventDefault(); const last = Object.assign({}, view.last); const skill = last.skill; delete last.skill; submit(skill, last); }
  });
})();
