// The status page's script: polls idm-web's JSON and draws with the DOM and canvas only.
'use strict';

const HISTORY_S = 60;
const COLORS = ['#1f77b4', '#d62728', '#2ca02c', '#9467bd', '#ff7f0e', '#17becf', '#8c564b'];
const view = { axes: [], control: false, token: '', history: {}, maps: {}, built: '' };

function el(tag, attrs, text) {
  const e = document.createElement(tag);
  for (const k in (attrs || {})) e.setAttribute(k, attrs[k]);
  if (text !== undefined) e.textContent = text;
  return e;
}

async function getJSON(url) {
  const r = await fetch(url, { cache: 'no-store' });
  const body = await r.json();
  if (!r.ok) throw new Error(body.error || (url + ': HTTP ' + r.status));
  return body;
}

async function post(url, params) {
  const headers = { 'X-Idm-Control': '1', 'Content-Type': 'application/x-www-form-urlencoded' };
  if (view.token) headers.Authorization = 'Bearer ' + view.token;
  const r = await fetch(url, { method: 'POST', headers, body: new URLSearchParams(params).toString() });
  const body = await r.json();
  if (!r.ok || !body.ok) throw new Error(body.error || ('HTTP ' + r.status));
}

function message(text) {
  document.getElementById('message').textContent = text || '';
}

function um(m) {
  if (m === null || m === undefined) return '\u2014';
  return (m * 1e6).toFixed(4) + ' \u00b5m';
}

// A speed limit as a person reads it: µm/s, 'none' for 0 (no limit).
function speed(mps) {
  if (mps === null || mps === undefined) return '\u2014';
  if (mps === 0) return 'none';
  return String(Number((mps * 1e6).toPrecision(9))) + ' \u00b5m/s';
}

function limit(m) {
  if (m === null || m === undefined) return 'none';
  return (m * 1e6).toFixed(3);
}

// The axis's state in words: STATus:OPERation?'s bits when the daemon answers it, else from STAT?.
function statusWords(a) {
  if (a.status_words) return a.status_words.length ? a.status_words.join(', ') : 'idle';
  const w = [];
  if (a.done === false) w.push('moving');
  if (a.fault && a.fault !== 'none') w.push('fault: ' + a.fault);
  if (a.eot) w.push('end of travel (' + a.eot + ')');
  w.push(a.position_valid ? 'position valid' : 'position not valid');
  if (a.position_valid && a.lower_m !== null && a.position_m <= a.lower_m) w.push('at lower limit');
  if (a.position_valid && a.upper_m !== null && a.position_m >= a.upper_m) w.push('at upper limit');
  if (a.device && a.device !== 'up') w.push('device ' + a.device);
  if (a.daemon_error && a.daemon_error !== 'none') w.push(a.daemon_error.replace(/_/g, ' '));
  return w.join(', ');
}

function buildTable(axes) {
  const tbody = document.querySelector('#axes tbody');
  tbody.textContent = '';
  for (const a of axes) {
    const tr = el('tr', { id: 'axis-' + a.axis });
    tr.appendChild(el('td', {}, a.name + ' (' + a.axis + ')'));
    for (const k of ['pos', 'target']) tr.appendChild(el('td', { id: k + '-' + a.axis, class: 'num' }));
    for (const k of ['state', 'status']) tr.appendChild(el('td', { id: k + '-' + a.axis }));
    for (const k of ['limits', 'ref', 'moves', 'speed-limit']) tr.appendChild(el('td', { id: k + '-' + a.axis, class: 'num' }));
    const ctl = el('td', { class: 'ctl' });
    if (view.control) {
      const stop = el('button', { class: 'stop', id: 'stop-' + a.axis }, 'STOP');
      stop.onclick = () => post('/api/stop', { axis: a.axis }).then(() => message(''), e => message('STOP: ' + e.message));
      const input = el('input', { id: 'target-input-' + a.axis, size: 10, placeholder: '\u00b5m' });
      const go = el('button', { id: 'move-' + a.axis }, 'move');
      go.onclick = () => {
        const t = Number(input.value) * 1e-6;
        if (!input.value.trim() || !isFinite(t)) { message('move: a target in \u00b5m is needed'); return; }
        post('/api/move', { axis: a.axis, target: t }).then(() => message(''), e => message('move: ' + e.message));
      };
      const speedInput = el('input', { id: 'speed-input-' + a.axis, size: 8, placeholder: '\u00b5m/s' });
      const setSpeed = el('button', { id: 'speed-' + a.axis }, 'set speed limit');
      setSpeed.onclick = () => {
        const v = Number(speedInput.value) * 1e-6;
        if (!speedInput.value.trim() || !isFinite(v)) { message('speed limit: a speed in \u00b5m/s is needed (0: no limit)'); return; }
        post('/api/velocity', { axis: a.axis, speed: v.toPrecision(12) }).then(() => message(''), e => message('speed limit: ' + e.message));
      };
      ctl.append(stop, ' ', input, go, ' ', jogButton(a.axis, 'negative', '\u25c0 jog'),
                 jogButton(a.axis, 'positive', 'jog \u25b6'), ' ', speedInput, setSpeed);
    } else {
      ctl.textContent = 'read-only';
    }
    tr.appendChild(ctl);
    tbody.appendChild(tr);
  }
  document.querySelectorAll('.ctl').forEach(c => { c.style.display = view.control ? '' : 'none'; });
  const legend = document.getElementById('plot-legend');
  legend.textContent = '';
  axes.forEach((a, i) => {
    legend.appendChild(el('span', { style: 'background:' + COLORS[i % COLORS.length] }));
    legend.appendChild(document.createTextNode(a.name));
  });
  const maps = document.getElementById('maps');
  maps.textContent = '';
  for (const a of axes) {
    const box = el('div');
    box.appendChild(el('div', {}, 'axis ' + a.name + ': rows frequency (Hz), columns duty'));
    box.appendChild(el('canvas', { id: 'regions-' + a.axis, width: 420, height: 300 }));
    maps.appendChild(box);
    loadRegions(a.axis);
  }
}

// A jog button: pressed, the axis jogs that way (POST /api/jog: toward the soft limit at the
// speed limit); released (or the press lost: pointer cancelled, the window left), STOP of that
// axis, sent after the jog's own request has been answered so that it cannot overtake it.
function jogButton(axis, direction, label) {
  const b = el('button', { class: 'jog', id: 'jog-' + direction.slice(0, 3) + '-' + axis,
                           title: 'hold to jog ' + direction + ' (release: STOP)' }, label);
  let jog = null;
  const release = () => {
    if (!jog) return;
    const started = jog;
    jog = null;
    b.classList.remove('active');
    started.finally(() => post('/api/stop', { axis }).then(() => {}, e => message('STOP: ' + e.message)));
  };
  b.addEventListener('pointerdown', ev => {
    if (ev.button !== 0 || jog) return;
    if (b.setPointerCapture) b.setPointerCapture(ev.pointerId);
    b.classList.add('active');
    jog = post('/api/jog', { axis, direction }).then(() => message(''), e => message('jog: ' + e.message));
  });
  for (const t of ['pointerup', 'pointercancel', 'lostpointercapture']) b.addEventListener(t, release);
  window.addEventListener('blur', release);
  return b;
}

function buildControl(tokenRequired) {
  const c = document.getElementById('control');
  c.textContent = '';
  if (!view.control) {
    c.appendChild(el('span', { class: 'muted' }, 'read-only (idm-web --control enables STOP, moves, jogs and the speed limit)'));
    return;
  }
  const stop = el('button', { class: 'stop', id: 'stop-all' }, 'STOP all axes');
  stop.onclick = () => post('/api/stop', {}).then(() => message(''), e => message('STOP: ' + e.message));
  c.appendChild(stop);
  if (tokenRequired) {
    // The control token (idm-web --token-file): kept in this page only, sent with each POST.
    const input = el('input', { id: 'token', type: 'password', size: 24, autocomplete: 'off',
                                placeholder: 'control token' });
    input.oninput = () => { view.token = input.value.trim(); };
    c.append(' ', input);
  }
}

function update(s) {
  const conn = document.getElementById('conn');
  conn.textContent = s.connected ? 'connected to idmd' : ('idmd not reached: ' + s.error);
  conn.className = s.connected ? 'ok' : 'bad';
  document.getElementById('idn').textContent = s.idn;
  const shape = JSON.stringify([s.control, s.token_required, s.axes.map(a => [a.axis, a.name])]);
  if (shape !== view.built) {
    view.control = s.control;
    view.built = shape;
    buildControl(s.token_required);
    buildTable(s.axes);
  }
  view.axes = s.axes;
  for (const a of s.axes) {
    const pos = document.getElementById('pos-' + a.axis);
    document.getElementById('axis-' + a.axis).className = a.stale ? 'stale' : '';
    // Stale (idmd not reached): the last position is shown as such, never as the current one.
    pos.textContent = a.stale ? 'stale (last ' + um(a.last_position_m) + ')'
      : a.position_valid ? um(a.position_m) : 'not valid';
    pos.setAttribute('data-position-m', a.position_valid ? String(a.position_m) : '');
    document.getElementById('target-' + a.axis).textContent = um(a.target_m);
    const st = document.getElementById('state-' + a.axis);
    st.textContent = a.state || ('unknown: ' + (a.status_error || ''));
    st.className = 'state-' + a.state;
    document.getElementById('status-' + a.axis).textContent = a.stale ? 'idmd not reached'
      : statusWords(a) + (a.offset_m ? '; user offset ' + um(a.offset_m) + ' \u00b5m' : '');
    document.getElementById('limits-' + a.axis).textContent = a.stale ? '\u2014'
      : limit(a.lower_m) + ' .. ' + limit(a.upper_m) + ' \u00b5m';
    document.getElementById('ref-' + a.axis).textContent = a.referenced ? 'yes' : 'no';
    document.getElementById('moves-' + a.axis).textContent = a.moves === undefined ? '' : String(a.moves);
    document.getElementById('speed-limit-' + a.axis).textContent = a.stale ? '\u2014' : speed(a.speed_limit_m_s);
    if (a.position_valid && s.connected) {
      const h = view.history[a.axis] || (view.history[a.axis] = []);
      if (!h.length || h[h.length - 1][0] < s.time) h.push([s.time, a.position_m]);
      while (h.length && h[0][0] < s.time - HISTORY_S) h.shift();
    }
  }
  updateSweep(s.sweep);
  drawPlot(s.time);
}

function updateSweep(sw) {
  const box = document.getElementById('sweep');
  box.textContent = '';
  if (!sw || sw.state === 'NONE') { box.textContent = 'no sweep'; return; }
  const done = sw.written + sw.failed;
  const p = el('progress', { id: 'sweep-progress', max: Math.max(sw.planned, 1), value: done });
  const named = view.axes.find(a => a.axis === sw.axis);
  box.append(sw.state + ' on axis ' + sw.axis + (named ? ' (' + named.name + ')' : '') + ': ' +
             sw.written + ' of ' + sw.planned +
             ' trials written, ' + sw.failed + ' failed, into ' + sw.directory + ' ', p);
}

// Round ticks over [lo, hi] m: a step of 1, 2 or 5 times a power of ten, at most about `most`
// ticks, the range widened to whole steps; labels in mm, µm or nm after the step's size, with as
// many decimals as the step needs.
function niceTicks(lo, hi, most) {
  if (!(hi > lo)) { const c = isFinite(lo) ? lo : 0; lo = c - 5e-10; hi = c + 5e-10; }
  const raw = (hi - lo) / Math.max(1, most - 1);
  const decade = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 5, 10].map(m => m * decade).find(v => v >= raw * (1 - 1e-9));
  const first = Math.floor(lo / step + 1e-9), last = Math.ceil(hi / step - 1e-9);
  const unit = step >= 1e-3 ? ['mm', 1e3] : step >= 1e-9 ? ['\u00b5m', 1e6] : ['nm', 1e9];
  const decimals = Math.max(0, -Math.floor(Math.log10(step * unit[1]) + 1e-9));
  const ticks = [];
  for (let k = first; k <= last; k++) {
    const v = k * step;
    ticks.push({ m: v, label: (v * unit[1]).toFixed(decimals) + ' ' + unit[0] });
  }
  return { lo: first * step, hi: last * step, step, ticks };
}

// The last minute of positions on a 2D context of W x H: axes and round ticks, each axis's line
// clipped to the plot area (a point older than the minute, or off the scale, is never drawn
// outside it).
function plotOn(g, W, H, history, axes, now) {
  const L = 90, R = 10, T = 10, B = 30, PW = W - L - R, PH = H - T - B;
  g.clearRect(0, 0, W, H);
  let lo = Infinity, hi = -Infinity;
  for (const k in history) for (const [t, x] of history[k]) {
    if (t < now - HISTORY_S) continue;
    lo = Math.min(lo, x); hi = Math.max(hi, x);
  }
  g.strokeStyle = '#999'; g.strokeRect(L, T, PW, PH);
  g.fillStyle = '#444'; g.font = '12px sans-serif';
  for (let s = 0; s <= HISTORY_S; s += 10) g.fillText((s - HISTORY_S) + ' s', L + PW * s / HISTORY_S - 12, H - 10);
  if (!isFinite(lo)) { g.fillText('no valid position yet', L + 10, T + 20); return null; }
  const scale = niceTicks(lo, hi, 6);
  const y = x => T + PH - PH * (x - scale.lo) / (scale.hi - scale.lo);
  for (const tick of scale.ticks) g.fillText(tick.label, 2, y(tick.m) + 4);
  g.save();
  g.beginPath(); g.rect(L, T, PW, PH); g.clip();
  axes.forEach((a, i) => {
    const h = history[a.axis] || [];
    g.strokeStyle = COLORS[i % COLORS.length]; g.lineWidth = 1.5; g.beginPath();
    h.forEach(([t, x], j) => {
      const px = L + PW * (t - (now - HISTORY_S)) / HISTORY_S;
      if (j) g.lineTo(px, y(x)); else g.moveTo(px, y(x));
    });
    g.stroke();
  });
  g.restore();
  return scale;
}

function drawPlot(now) {
  const c = document.getElementById('plot');
  plotOn(c.getContext('2d'), c.width, c.height, view.history, view.axes, now);
}

function cellColor(cell, maxLog, minLog) {
  if (!cell) return '#fff';
  if (cell.region === 'CUTOFF') return '#bdbdbd';
  if (cell.region === 'MULTISTEP') return 'hsl(25,85%,50%)';
  const v = Math.log10(Math.max(Math.abs(cell.step_m), 1e-15));
  const f = maxLog > minLog ? (v - minLog) / (maxLog - minLog) : 0.5;
  return 'hsl(120,60%,' + (75 - 45 * f).toFixed(0) + '%)';
}

async function loadRegions(axis) {
  try {
    const m = await getJSON('/api/regions?axis=' + axis);
    view.maps[axis] = m;
    drawRegions(axis);
  } catch (e) {
    const c = document.getElementById('regions-' + axis);
    if (c) c.getContext('2d').fillText('region map: ' + e.message, 10, 20);
  }
}

function drawRegions(axis) {
  const m = view.maps[axis], c = document.getElementById('regions-' + axis);
  if (!m || !c) return;
  const g = c.getContext('2d'), L = 50, T = 5, B = 25;
  const nf = m.freqs_hz.length, nd = m.duties.length;
  const cw = (c.width - L - 5) / nd, ch = (c.height - T - B) / nf;
  let minLog = Infinity, maxLog = -Infinity;
  for (const row of m.cells) for (const cell of row) if (cell && cell.region === 'ONESTEP') {
    const v = Math.log10(Math.max(Math.abs(cell.step_m), 1e-15));
    minLog = Math.min(minLog, v); maxLog = Math.max(maxLog, v);
  }
  g.clearRect(0, 0, c.width, c.height);
  m.cells.forEach((row, f) => row.forEach((cell, d) => {
    g.fillStyle = cellColor(cell, maxLog, minLog);
    g.fillRect(L + d * cw, T + f * ch, Math.ceil(cw), Math.ceil(ch));
  }));
  g.fillStyle = '#444'; g.font = '11px sans-serif';
  const fstep = Math.max(1, Math.ceil(nf / 10));
  for (let f = 0; f < nf; f += fstep) g.fillText(String(m.freqs_hz[f]), 2, T + (f + 0.7) * ch);
  const dstep = Math.max(1, Math.ceil(nd / 6));
  for (let d = 0; d < nd; d += dstep) g.fillText(String(m.duties[d]), L + d * cw, c.height - 8);
  c.onmousemove = ev => {
    const r = c.getBoundingClientRect();
    const d = Math.floor((ev.clientX - r.left - L) / cw), f = Math.floor((ev.clientY - r.top - T) / ch);
    const info = document.getElementById('map-cell');
    if (f < 0 || d < 0 || f >= nf || d >= nd) { info.textContent = '\u00a0'; return; }
    const cell = m.cells[f][d];
    info.textContent = 'axis ' + axis + ': ' + m.freqs_hz[f] + ' Hz, duty ' + m.duties[d] + ': ' +
      (cell ? cell.region + ', step ' + (cell.step_m * 1e9).toFixed(2) + ' nm' : 'refused by the device');
  };
}

async function loadGap() {
  const box = document.getElementById('gap');
  try {
    const r = await getJSON('/api/gap');
    box.textContent = '';
    const d = r.diagnosis || {};
    const effects = (d.effects || []).join(', ') || 'none';
    box.appendChild(el('div', { id: 'gap-effects' }, 'effects: ' + effects));
    if (d.gap_before !== undefined)
      box.appendChild(el('div', {}, 'gap ' + Number(d.gap_before).toPrecision(3) + ' \u2192 ' +
        Number(d.gap_after).toPrecision(3) + ' (shrink ' + (100 * d.shrink).toFixed(0) + ' %)'));
    if (r.where && r.where.summary) box.appendChild(el('div', {}, r.where.summary));
    if (r.dataset) box.appendChild(el('div', { class: 'muted' }, 'dataset ' + r.dataset));
  } catch (e) {
    box.textContent = 'none (' + e.message + ')';
  }
}

let busy = false;
async function tick() {
  if (busy) return;
  busy = true;
  try {
    update(await getJSON('/api/state'));
  } catch (e) {
    const conn = document.getElementById('conn');
    conn.textContent = 'idm-web not reached: ' + e.message;
    conn.className = 'bad';
  } finally {
    busy = false;
  }
}

async function start() {
  try {
    const h = await getJSON('/api/history');
    for (const a of h.axes) view.history[a.axis] = a.t.map((t, i) => [h.time + t, a.position_m[i]]);
  } catch (e) {
    message('history: ' + e.message);
  }
  await tick();
  setInterval(tick, 250);
  loadGap();
  setInterval(loadGap, 30000);
  setInterval(() => { for (const a of view.axes) loadRegions(a.axis); }, 60000);
}

// In a browser: run. Under node (tests/web/test_app.js): only the functions, no page.
if (typeof document !== 'undefined') start();
if (typeof module !== 'undefined') module.exports = { niceTicks, plotOn, speed, HISTORY_S };
