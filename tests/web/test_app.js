// The status page's script under node (CTest web.js): its round ticks and its plot, drawn on a
// context that records every call, with generated positions (a seeded generator: each run the
// same cases, and many of them). The rest of the page is covered in a browser by test_browser.py.
'use strict';
const assert = require('assert');
const path = require('path');

const app = require(path.resolve(process.argv[2] || path.join(__dirname, '..', '..', 'web', 'app.js')));

// mulberry32: a small seeded generator
function generator(seed) {
  let a = seed >>> 0;
  return () => {
    a = (a + 0x6d2b79f5) >>> 0;
    let t = a;
    t = Math.imul(t ^ (t >>> 15), t | 1);
    t ^= t + Math.imul(t ^ (t >>> 7), t | 61);
    return ((t ^ (t >>> 14)) >>> 0) / 4294967296;
  };
}

const UNITS = { mm: 1e3, '\u00b5m': 1e6, nm: 1e9 };

// The ticks of [lo, hi]: 1-2-5 steps, every tick a whole number of steps, covering the range,
// labelled with their value in the label's unit and distinct.
function checkTicks(lo, hi, most) {
  const s = app.niceTicks(lo, hi, most);
  const what = JSON.stringify({ lo, hi, most, step: s.step, ticks: s.ticks.map(t => t.label) });
  const mantissa = s.step / Math.pow(10, Math.floor(Math.log10(s.step) + 1e-9));
  assert.ok([1, 2, 5, 10].some(m => Math.abs(mantissa - m) < 1e-6), 'step not 1-2-5: ' + what);
  assert.ok(s.ticks.length >= 2 && s.ticks.length <= 2 * most + 1, 'tick count: ' + what);
  assert.ok(s.lo <= lo + 1e-15 && s.hi >= hi - 1e-15, 'range not covered: ' + what);
  const labels = new Set();
  for (const t of s.ticks) {
    const k = t.m / s.step;
    assert.ok(Math.abs(k - Math.round(k)) < 1e-6, 'tick off the step: ' + what);
    const m = /^(-?\d+(?:\.(\d+))?) (mm|\u00b5m|nm)$/.exec(t.label);
    assert.ok(m, 'label: ' + t.label);
    const decimals = m[2] ? m[2].length : 0;
    assert.ok(Math.abs(Number(m[1]) - t.m * UNITS[m[3]]) <= 0.5 * Math.pow(10, -decimals) + 1e-9,
              'label not the value: ' + t.label + ' for ' + t.m);
    // no more decimals than the step needs
    const stepInUnit = s.step * UNITS[m[3]];
    assert.ok(stepInUnit * Math.pow(10, decimals) >= 1 - 1e-6 &&
              (decimals === 0 || stepInUnit * Math.pow(10, decimals - 1) < 1 - 1e-9),
              'decimals ' + decimals + ' for a step of ' + stepInUnit + ' ' + m[3]);
    labels.add(t.label);
  }
  assert.strictEqual(labels.size, s.ticks.length, 'labels repeat: ' + what);
  return s;
}

// A 2D context that records its calls.
function recorder() {
  const calls = [];
  const g = new Proxy({ calls }, {
    get(target, name) {
      if (name in target) return target[name];
      return (...args) => calls.push([name, ...args]);
    },
    set(target, name, value) { calls.push(['set ' + String(name), value]); return true; },
  });
  return g;
}

function checkPlot(history, now) {
  const W = 900, H = 260, L = 90, R = 10, T = 10, B = 30;
  const g = recorder();
  const axes = Object.keys(history).map(k => ({ axis: Number(k), name: 'a' + k }));
  const scale = app.plotOn(g, W, H, history, axes, now);
  const calls = g.calls;
  const clip = calls.findIndex(c => c[0] === 'clip');
  assert.ok(clip > 0, 'the plot is not clipped');
  assert.deepStrictEqual(calls[clip - 1], ['rect', L, T, W - L - R, H - T - B], 'clipped to the plot area');
  const firstLine = calls.findIndex(c => c[0] === 'moveTo' || c[0] === 'lineTo');
  const restore = calls.map(c => c[0]).lastIndexOf('restore');
  const lastStroke = calls.map(c => c[0]).lastIndexOf('stroke');
  assert.ok(firstLine > clip && restore > lastStroke, 'lines drawn outside the clip');
  assert.ok(calls.slice(0, clip).findIndex(c => c[0] === 'save') >= 0, 'no save before the clip');
  // The tick labels are the round ones, each beside its place on the scale, inside the plot.
  const labels = calls.filter(c => c[0] === 'fillText' && / (mm|\u00b5m|nm)$/.test(c[1]));
  assert.deepStrictEqual(labels.map(c => c[1]), scale.ticks.map(t => t.label));
  for (const c of labels) assert.ok(c[3] >= T + 4 - 1e-6 && c[3] <= H - B + 4 + 1e-6, 'label off the plot: ' + c);
  return scale;
}

const rand = generator(20240607);
let cases = 0;
// The case: a stage resting near 1150.001 um, a few nanometres of noise.
{
  const s = checkTicks(1150.0012e-6, 1150.0047e-6, 6);
  for (const t of s.ticks) assert.match(t.label, /^1150\.00\d \u00b5m$/);
  cases++;
}
for (let i = 0; i < 2000; i++) {
  const centre = (rand() * 2 - 1) * 5e-3;
  const span = Math.pow(10, -11 + 9 * rand());
  const lo = centre - span * rand(), hi = lo + span;
  checkTicks(lo, hi, 2 + Math.floor(rand() * 9));
  cases++;
}
checkTicks(1e-3, 1e-3, 6);  // a flat line
for (let i = 0; i < 300; i++) {
  const now = 1.7e9 + rand() * 1e6;
  const history = {};
  for (let a = 1; a <= 1 + Math.floor(rand() * 3); a++) {
    const base = (rand() * 2 - 1) * 5e-3, spread = Math.pow(10, -10 + 6 * rand());
    // points from 90 s ago (outside the minute: clipped away) to now
    const n = 5 + Math.floor(rand() * 50);
    history[a] = Array.from({ length: n }, (_, j) => [now - 90 + 90 * j / (n - 1), base + spread * rand()]);
  }
  checkPlot(history, now);
  cases++;
}
// Nothing to draw yet: no clip, no lines, and it says so.
{
  const g = recorder();
  assert.strictEqual(app.plotOn(g, 900, 260, {}, [], 1e9), null);
  assert.ok(g.calls.some(c => c[0] === 'fillText' && c[1] === 'no valid position yet'));
}
// The speed limit as the page shows it: µm/s to 9 digits, 'none' for 0 (no limit), a dash for
// none known; generated speeds read back from the text within its rounding.
{
  assert.strictEqual(app.speed(0), 'none');
  assert.strictEqual(app.speed(null), '\u2014');
  assert.strictEqual(app.speed(undefined), '\u2014');
  assert.strictEqual(app.speed(4e-4), '400 \u00b5m/s');
  assert.strictEqual(app.speed(2.5e-7), '0.25 \u00b5m/s');
  const rand = generator(32);
  for (let k = 0; k < 1000; k++) {
    const v = Math.pow(10, -9 + 9 * rand());
    const m = /^(\d+(?:\.\d+)?(?:e[-+]\d+)?) \u00b5m\/s$/.exec(app.speed(v));
    assert.ok(m, 'speed text: ' + app.speed(v));
    assert.ok(Math.abs(Number(m[1]) * 1e-6 - v) <= v * 1e-8, 'speed ' + v + ': ' + app.speed(v));
    cases++;
  }
}
console.log('test_app.js: ' + cases + ' cases passed');
