// hydrometra station: the instructor's page. Plain JavaScript, WebGL2 (views.js) and canvas 2D, no
// library: everything the page runs ships inside the station binary. Frame layouts: docs/station.md;
// status field offsets come from /layout.json (taken from the renderer contract by the station).
'use strict';

const S = (window.hydrometraStation = {
  layout: null,
  rigs: [], // per rig index: {info, status, history, mesh, flow, particles, ...}
  selected: 0,
  statusFrames: 0,
  connected: false,
  control: false,
  renders3d: 0,
  rendersEndoscope: 0,
  webgl: false,
  errors: [],
});

let token = '';
{
  const m = /token=([A-Za-z0-9._~-]+)/.exec(location.hash);
  token = m ? m[1] : sessionStorage.getItem('hydrometra-token') || '';
  if (token) sessionStorage.setItem('hydrometra-token', token);
}

const $ = (id) => document.getElementById(id);
const HISTORY_S = 600;
const ML = 1e6; // ml per m3
const ML_MIN = 6e7; // ml/min per m3/s

// ---------------------------------------------------------------- frames
function readField(dv, base, f) {
  const o = base + f.offset;
  switch (f.type) {
    case 'u64': return Number(dv.getBigUint64(o, true));
    case 'u32': return dv.getUint32(o, true);
    case 'f64': return dv.getFloat64(o, true);
    case 'f64x3': return [0, 1, 2].map((i) => dv.getFloat64(o + 8 * i, true));
    case 'f64x4': return [0, 1, 2, 3].map((i) => dv.getFloat64(o + 8 * i, true));
  }
  return undefined;
}

function decodeStatus(dv, base) {
  const s = {};
  for (const [name, f] of Object.entries(S.layout.status)) s[name] = readField(dv, base, f);
  // Exact 64-bit values where a double would round.
  s.procedure_id_text = dv.getBigUint64(base + S.layout.status.procedure_id.offset, true).toString();
  s.alarm_bits_big = dv.getBigUint64(base + S.layout.status.alarm_bits.offset, true);
  s.run_id_text = dv.getBigUint64(base + S.layout.status.run_id.offset, true).toString();
  return s;
}

function rigState(index) {
  if (!S.rigs[index]) {
    S.rigs[index] = {
      info: { index, id: 'rig ' + index },
      status: null,
      runId: null,
      hist: { t: [], p: [], pump: [], inflow: [], outflow: [], losses: [], deficit: [], limit: [], alarms: [] },
      pendingAlarms: 0,
      topology: null,
      topologyRevision: null,
      positions: null,
      positionsRevision: null,
      normals: null,
      flow: null,
      particles: null,
      dirty: true,
      geometryVersion: 0,
    };
  }
  return S.rigs[index];
}

// One plot point every 0.1 s of daemon time; `alarms` (the low 32 alarm bits) are or-ed over the
// statuses a point stands for, so a short alarm still shades the plots.
function pushHistory(r, t, p, pump, inflow, outflow, losses, deficit, limit, alarms) {
  const h = r.hist;
  const n = h.t.length;
  if (n && t < h.t[n - 1]) for (const k in h) h[k].length = 0; // another run
  r.pendingAlarms |= alarms;
  if (n && t - h.t[h.t.length - 1] < 0.1) return;
  h.t.push(t); h.p.push(p); h.pump.push(pump); h.inflow.push(inflow); h.outflow.push(outflow);
  h.losses.push(losses); h.deficit.push(deficit); h.limit.push(limit); h.alarms.push(r.pendingAlarms);
  r.pendingAlarms = 0;
  const cut = h.t.findIndex((x) => x >= t - HISTORY_S);
  if (cut > 0 && h.t.length > 7000) for (const k in h) h[k].splice(0, cut);
}

function onFrame(buf) {
  const dv = new DataView(buf);
  const kind = dv.getUint8(0);
  const version = dv.getUint8(1);
  if (version !== S.layout.frame_version) return;
  const r = rigState(dv.getUint16(2, true));
  const origin = dv.getBigUint64(8, true);
  const H = S.layout.header_bytes;
  const K = S.layout.kinds;
  if (kind === K.status) {
    const s = decodeStatus(dv, H);
    if (r.runId !== null && r.runId !== s.run_id) r.topology = null;
    r.runId = s.run_id;
    r.status = s;
    r.dirty = true;
    S.statusFrames++;
    pushHistory(r, s.sim_time_s, s.cavity_pressure_pa, s.pump_set_pressure_pa, s.inflow_m3_per_s,
      s.outflow_m3_per_s, s.leak_m3_per_s + s.absorption_m3_per_s + s.perforation_m3_per_s,
      s.deficit_m3, s.deficit_limit_m3, Number(s.alarm_bits_big & 0xffffffffn));
    updateCard(r);
    if (r.info.index === S.selected) updateNumbers(r);
    send({ type: 'ack', rig: r.info.index, origin_ns: origin.toString() });
  } else if (kind === K.topology) {
    const vertexCount = dv.getUint32(H + 4, true);
    const triangles = dv.getUint32(H + 8, true);
    r.topologyRevision = Number(dv.getBigUint64(H + 16, true));
    const T = S.layout.topology_header_bytes;
    r.topology = new Uint32Array(buf.slice(H + T, H + T + 12 * triangles));
    r.vertexCount = vertexCount;
    r.geometryVersion++;
  } else if (kind === K.positions) {
    const n = dv.getUint32(H + 4, true);
    r.positionsRevision = Number(dv.getBigUint64(H + 24, true));
    const P = S.layout.positions_header_bytes;
    r.positions = new Float32Array(buf.slice(H + P, H + P + 12 * n));
    r.normals = null;
    r.geometryVersion++;
  } else if (kind === K.flow) {
    const n = dv.getUint32(H, true);
    r.flow = {
      blockM: dv.getFloat32(H + 4, true),
      maxSpeed: dv.getFloat32(H + 24, true),
      arrows: new Float32Array(buf.slice(H + 32, H + 32 + 24 * n)),
    };
    r.flowVersion = (r.flowVersion || 0) + 1;
  } else if (kind === K.particles) {
    const n = dv.getUint32(H + 4, true);
    const pos = new Float32Array(3 * n);
    const kinds = new Float32Array(n);
    for (let i = 0; i < n; i++) {
      const o = H + S.layout.particles_header_bytes + S.layout.particle_bytes * i;
      pos[3 * i] = dv.getFloat32(o, true);
      pos[3 * i + 1] = dv.getFloat32(o + 4, true);
      pos[3 * i + 2] = dv.getFloat32(o + 8, true);
      kinds[i] = dv.getUint32(o + 24, true);
    }
    r.particles = { pos, kinds, count: n };
    r.particlesVersion = (r.particlesVersion || 0) + 1;
  } else if (kind === K.history) {
    const n = dv.getUint32(H, true);
    const size = dv.getUint32(H + 4, true);
    for (let i = 0; i < n; i++) {
      const o = H + 8 + size * i;
      const f = (k) => dv.getFloat32(o + 8 + 4 * k, true);
      pushHistory(r, dv.getFloat64(o, true), f(0), f(1), f(2), f(3), f(4), f(5), f(6), dv.getUint32(o + 36, true));
    }
  }
}

// ---------------------------------------------------------------- connection
let ws = null;
function send(msg) {
  if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(msg));
}

function connect() {
  ws = new WebSocket((location.protocol === 'https:' ? 'wss:' : 'ws:') + '//' + location.host + '/ws');
  ws.binaryType = 'arraybuffer';
  ws.onopen = () => send({ type: 'hello', token: token || undefined });
  ws.onmessage = (ev) => {
    if (typeof ev.data === 'string') {
      const m = JSON.parse(ev.data);
      if (m.type === 'hello' || m.type === 'rigs') {
        S.connected = true;
        S.control = !!m.control;
        for (const info of m.rigs) rigState(info.index).info = info;
        renderRigCards();
        setConnection();
      } else if (m.type === 'error') {
        S.errors.push(m.message);
        setConnection(m.message);
      }
    } else {
      onFrame(ev.data);
    }
  };
  ws.onclose = () => {
    S.connected = false;
    setConnection();
    setTimeout(connect, 1000);
  };
}

function setConnection(error) {
  const c = $('connection');
  c.textContent = S.connected ? 'live' : error ? 'refused: ' + error : 'reconnecting';
  c.className = 'pill ' + (S.connected ? 'ok' : 'bad');
  const cs = $('control-state');
  cs.textContent = S.control ? 'control unlocked' : 'view only';
  cs.className = 'pill ' + (S.control ? 'ok' : '');
  $('token-form').classList.toggle('hidden', S.control);
  for (const id of ['new-procedure', 'load-scene', 'record-start', 'record-stop']) $(id).disabled = !S.control;
}

// ---------------------------------------------------------------- numbers, cards, alarms
const fmt = (v, d) => (Number.isFinite(v) ? v.toFixed(d) : '-');
const mmHg = (pa) => pa / S.layout.pa_per_mmhg;
const CRITICAL = ['terminated', 'deficit-limit', 'overpressure', 'rig-link-lost', 'rig-incompatible'];
const WARNING = ['deficit-50', 'deficit-75', 'deficit-90', 'deficit-rate', 'deadline-missed', 'scope-pose-invalid',
  'rig-safe-state', 'recording-failed'];
// The alarm bits (low 32) of the named alarms, for shading the plots.
const alarmMask = (...names) => S.layout.alarms.filter((a) => names.includes(a.name) && a.bit < 32)
  .reduce((m, a) => m | (1 << a.bit), 0) >>> 0;

function alarmNames(s) {
  const out = [];
  for (const a of S.layout.alarms) if ((s.alarm_bits_big >> BigInt(a.bit)) & 1n) out.push(a.name);
  const perforated = S.layout.hydraulic_flags.find((f) => f.name === 'perforated');
  if (perforated && (s.hydraulic_flags / 2 ** perforated.bit) % 2 >= 1) out.push('perforated');
  return out;
}

function severity(names) {
  if (names.some((n) => CRITICAL.includes(n) || n === 'perforated')) return 'critical';
  if (names.some((n) => WARNING.includes(n))) return 'warning';
  return '';
}

function renderRigCards() {
  const box = $('rigs');
  for (const r of S.rigs) {
    if (!r || document.querySelector(`.rig-card[data-rig="${r.info.index}"]`)) continue;
    const d = document.createElement('div');
    d.className = 'rig-card';
    d.dataset.rig = r.info.index;
    d.innerHTML = `<div class="name"></div>
      <div class="vals"><span><b class="c-pressure">-</b> mmHg</span><span><b class="c-deficit">-</b> ml</span></div>
      <div class="bar"><div></div></div><div class="alarms"></div>`;
    d.querySelector('.name').textContent = r.info.id;
    d.title = r.info.source || '';
    d.onclick = () => select(r.info.index);
    box.appendChild(d);
  }
  select(S.selected);
}

function updateCard(r) {
  const d = document.querySelector(`.rig-card[data-rig="${r.info.index}"]`);
  const s = r.status;
  if (!d || !s) return;
  const p = d.querySelector('.c-pressure');
  p.textContent = fmt(mmHg(s.cavity_pressure_pa), 1);
  p.dataset.seq = s.sequence;
  const def = d.querySelector('.c-deficit');
  def.textContent = fmt(s.deficit_m3 * ML, 1);
  def.dataset.seq = s.sequence;
  const frac = s.deficit_limit_m3 > 0 ? s.deficit_m3 / s.deficit_limit_m3 : 0;
  const bar = d.querySelector('.bar div');
  bar.style.width = Math.min(100, 100 * frac).toFixed(1) + '%';
  bar.style.background = frac >= 1 ? 'var(--red)' : frac >= 0.5 ? 'var(--amber)' : 'var(--green)';
  const names = alarmNames(s);
  d.querySelector('.alarms').textContent = names.join(' ');
  d.classList.toggle('critical', severity(names) === 'critical');
  d.classList.toggle('warning', severity(names) === 'warning');
  updateBanner();
}

function updateBanner() {
  const lines = [];
  let worst = '';
  for (const r of S.rigs) {
    if (!r || !r.status) continue;
    const names = alarmNames(r.status);
    const sev = severity(names);
    if (!sev) continue;
    if (sev === 'critical') worst = 'critical';
    else if (!worst) worst = 'warning';
    const terminated = names.includes('terminated');
    const pumpStopped = r.status.pump_set_pressure_pa === 0 ? ', pump stopped' : '';
    const others = names.filter((n) => !['terminated', 'deficit-limit'].includes(n));
    const what = terminated
      ? `PROCEDURE TERMINATED: deficit limit reached${pumpStopped}` + (others.length ? ` (${others.join(', ')})` : '')
      : names.join(', ');
    lines.push(`${r.info.id}: ${what}`);
  }
  const b = $('banner');
  b.textContent = lines.join(' | ');
  b.classList.toggle('hidden', lines.length === 0);
  b.classList.toggle('warn', worst === 'warning');
  b.dataset.severity = worst;
}

function setNum(id, text, seq, raw) {
  const e = $(id);
  e.textContent = text;
  if (seq !== undefined) e.dataset.seq = seq;
  if (raw !== undefined) e.dataset.raw = raw;
}

function updateNumbers(r) {
  const s = r.status;
  setNum('v-pressure', fmt(mmHg(s.cavity_pressure_pa), 1), s.sequence, s.cavity_pressure_pa);
  setNum('v-pump', fmt(mmHg(s.pump_set_pressure_pa), 1), s.sequence);
  setNum('v-deficit', fmt(s.deficit_m3 * ML, 1), s.sequence, s.deficit_m3);
  setNum('v-limit', fmt(s.deficit_limit_m3 * ML, 0));
  setNum('v-deficit-rate', fmt(s.deficit_rate_m3_per_s * ML_MIN, 1));
  setNum('v-inflow', fmt(s.inflow_m3_per_s * ML_MIN, 1));
  setNum('v-outflow', fmt(s.outflow_m3_per_s * ML_MIN, 1));
  setNum('v-losses', fmt((s.leak_m3_per_s + s.absorption_m3_per_s + s.perforation_m3_per_s) * ML_MIN, 1));
  setNum('v-valves', `${fmt(100 * s.valve_in_opening, 0)} / ${fmt(100 * s.valve_out_opening, 0)}`);
  setNum('v-clarity', fmt(s.view_clarity, 2));
  const link = S.layout.link_states[s.link_state] || 'unknown';
  setNum('v-link', link);
  $('v-link').parentElement.className = 'num' + (link === 'connected' ? '' : ' alarm');
  const reason = s.link_down_reason ? S.layout.link_down_reasons[s.link_down_reason] || 'unknown' : '';
  $('v-link-detail').textContent = `${reason} frames ${s.link_frames} crc ${s.link_crc_errors} gaps ${s.link_sequence_gaps} reconnects ${s.link_reconnects} age ${fmt(1e3 * s.last_sample_age_s, 0)} ms`;
  setNum('v-misses', String(s.deadline_misses));
  $('v-misses').parentElement.className = 'num' + (s.deadline_misses > 0 ? ' warn' : '');
  $('v-ticks').textContent = `of ${s.ticks} ticks, worst ${fmt(1e3 * s.tick_work_max_s, 2)} ms`;
  setNum('v-latency', `${fmt(1e3 * s.latency_p50_s, 2)} / ${fmt(1e3 * s.latency_p99_s, 2)} / ${fmt(1e3 * s.latency_max_s, 1)}`);
  setNum('v-scene', S.layout.scene_states[s.scene_state] || 'unknown');
  $('v-scene-detail').textContent = `frames ${s.scene_frames}, step p99 ${fmt(1e3 * s.scene_step_p99_s, 2)} ms`;
  const pe = $('procedure');
  pe.textContent = `procedure ${s.procedure_id_text}, ${fmt(s.procedure_time_s, 0)} s`;
  pe.dataset.procedureId = s.procedure_id_text;
  const names = alarmNames(s);
  $('v-pressure').parentElement.className = 'num big' + (names.includes('overpressure') ? ' alarm' : '');
  $('v-deficit').parentElement.className = 'num big' +
    (names.includes('deficit-limit') || names.includes('terminated') ? ' alarm' : names.includes('deficit-50') ? ' warn' : '');
}

function select(index) {
  S.selected = index;
  for (const d of document.querySelectorAll('.rig-card')) d.classList.toggle('selected', Number(d.dataset.rig) === index);
  const r = S.rigs[index];
  $('rig-title').textContent = r ? r.info.id : 'no rig';
  if (r && r.status) updateNumbers(r);
  if (r) {
    r.dirty = true;
    r.geometryVersion++;
  }
  const control = r && r.info.control;
  $('control-panel').classList.toggle('hidden', r ? !control : true);
  $('recordings-panel').classList.toggle('hidden', r ? !r.info.recordings : true);
}

// ---------------------------------------------------------------- plots (canvas 2D)
function sizeCanvas(c) {
  const dpr = window.devicePixelRatio || 1;
  const w = Math.max(1, Math.round(c.clientWidth * dpr));
  const h = Math.max(1, Math.round(c.clientHeight * dpr));
  if (c.width !== w || c.height !== h) { c.width = w; c.height = h; }
  return dpr;
}

// series: [{values, color, label, dash}], t: times; xRange: [t0, t1]; bands: [{mask, color, label}]
// shade the times at which `alarms[i] & mask` (the alarm raised there).
function drawPlot(canvas, t, series, xRange, yLabel, xLabel, bands, alarms) {
  const dpr = sizeCanvas(canvas);
  const g = canvas.getContext('2d');
  const W = canvas.width, Hh = canvas.height;
  g.setTransform(1, 0, 0, 1, 0, 0);
  g.clearRect(0, 0, W, Hh);
  g.scale(dpr, dpr);
  const w = W / dpr, h = Hh / dpr;
  const L = 48, R = 8, T = 18, B = 18;
  const [t0, t1] = xRange;
  let lo = Infinity, hi = -Infinity;
  for (const s of series) {
    for (let i = 0; i < t.length; i++) {
      if (t[i] < t0) continue;
      const v = s.values[i];
      if (Number.isFinite(v)) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
    }
  }
  if (!Number.isFinite(lo)) { lo = 0; hi = 1; }
  lo = Math.min(lo, 0);
  if (hi - lo < 1e-9) hi = lo + 1;
  // Round ticks: a step of 1, 2, 2.5 or 5 times a power of ten, about 4 of them.
  const raw = (hi - lo) / 4, p10 = 10 ** Math.floor(Math.log10(raw));
  const step = p10 * [1, 2, 2.5, 5, 10].find((m) => m * p10 >= raw);
  lo = Math.floor(lo / step + 1e-9) * step;
  hi = Math.ceil(hi / step - 1e-9) * step;
  const ticks = Math.round((hi - lo) / step);
  const X = (x) => L + ((x - t0) / (t1 - t0)) * (w - L - R);
  const Y = (y) => T + (1 - (y - lo) / (hi - lo)) * (h - T - B);
  g.font = '11px system-ui, sans-serif';
  for (const b of bands || []) {
    g.fillStyle = b.color;
    let from = -1;
    for (let i = 0; i <= t.length; i++) {
      const on = i < t.length && t[i] >= t0 && (alarms[i] & b.mask) !== 0;
      if (on && from < 0) from = i;
      if (!on && from >= 0) {
        const x0 = X(t[from]), x1 = Math.max(X(t[i - 1]) + 2, x0 + 2);
        g.fillRect(x0, T, x1 - x0, h - T - B);
        from = -1;
      }
    }
  }
  g.strokeStyle = '#2a303a';
  g.fillStyle = '#8b95a5';
  g.lineWidth = 1;
  for (let k = 0; k <= ticks; k++) {
    const y = lo + step * k;
    g.beginPath(); g.moveTo(L, Y(y)); g.lineTo(w - R, Y(y)); g.stroke();
    g.fillText(String(+y.toFixed(2)), 4, Y(y) + 4);
  }
  g.fillText(xLabel, w - R - g.measureText(xLabel).width, h - 4);
  g.fillText(yLabel, 4, 12);
  let lx = L + 90;
  for (const s of series) {
    g.strokeStyle = s.color;
    g.lineWidth = 1.6;
    g.setLineDash(s.dash || []);
    g.beginPath();
    let started = false;
    for (let i = 0; i < t.length; i++) {
      if (t[i] < t0 || !Number.isFinite(s.values[i])) continue;
      const x = X(t[i]), y = Y(s.values[i]);
      if (started) g.lineTo(x, y); else { g.moveTo(x, y); started = true; }
    }
    g.stroke();
    g.setLineDash([]);
    g.fillStyle = s.color;
    g.fillText(s.label, lx, 12);
    lx += g.measureText(s.label).width + 14;
  }
  for (const b of bands || []) {
    g.fillStyle = b.color;
    g.fillRect(lx, 4, 10, 10);
    g.fillStyle = '#c9d1dc';
    g.fillText(b.label, lx + 13, 12);
    lx += g.measureText(b.label).width + 27;
  }
}

function drawPlots() {
  const r = S.rigs[S.selected];
  if (!r) return;
  const h = r.hist;
  const n = h.t.length;
  const win = Number($('window').value);
  const tEnd = n ? h.t[n - 1] : 0;
  // A young run fills the window from the left, like a chart recorder, instead of a sliver at
  // its right edge; once longer than the window, it scrolls.
  const t0 = n ? Math.max(h.t[0], tEnd - win) : 0;
  const xr = [t0, t0 + win];
  const xl = `${win / 60} min (daemon time, s)`;
  const conv = (a, f) => a.map(f);
  drawPlot($('plot-pressure'), h.t, [
    { values: conv(h.p, mmHg), color: '#4ea1ff', label: 'cavity pressure' },
    { values: conv(h.pump, mmHg), color: '#f0a030', label: 'pump setting', dash: [5, 3] },
  ], xr, 'mmHg', xl, [{ mask: alarmMask('overpressure'), color: 'rgba(229,72,77,0.30)', label: 'overpressure' }], h.alarms);
  drawPlot($('plot-flows'), h.t, [
    { values: conv(h.inflow, (v) => v * ML_MIN), color: '#3fb950', label: 'inflow' },
    { values: conv(h.outflow, (v) => v * ML_MIN), color: '#4ea1ff', label: 'outflow' },
    { values: conv(h.losses, (v) => v * ML_MIN), color: '#e5484d', label: 'losses' },
  ], xr, 'ml/min', xl, [{ mask: alarmMask('deficit-rate'), color: 'rgba(240,160,48,0.30)', label: 'deficit rate alarm' }], h.alarms);
  drawPlot($('plot-deficit'), h.t, [
    { values: conv(h.deficit, (v) => v * ML), color: '#e5484d', label: 'deficit' },
    { values: conv(h.limit, (v) => v * ML), color: '#8b95a5', label: 'limit', dash: [6, 4] },
  ], xr, 'ml', xl, [
    { mask: alarmMask('deficit-50', 'deficit-75', 'deficit-90'), color: 'rgba(240,160,48,0.22)', label: 'deficit warning' },
    { mask: alarmMask('deficit-limit', 'terminated'), color: 'rgba(229,72,77,0.40)', label: 'limit reached, terminated' },
  ], h.alarms);
}

// ---------------------------------------------------------------- control and recordings
async function api(method, path, body) {
  const res = await fetch(path, {
    method,
    headers: Object.assign({ 'Content-Type': 'application/json' }, token ? { Authorization: 'Bearer ' + token } : {}),
    body: body ? JSON.stringify(body) : undefined,
  });
  let json = null;
  try { json = await res.json(); } catch (e) { json = { error: res.statusText }; }
  if (!res.ok) throw new Error(json.error || res.statusText);
  return json;
}

function showResult(text, error) {
  const e = $('control-result');
  e.textContent = text;
  e.classList.toggle('error', !!error);
}

async function control(command, argument) {
  const rig = S.selected;
  try {
    const r = await api('POST', `/api/rigs/${rig}/control`, { command, argument: argument || '' });
    showResult(`${command}: ${r.result}: ${r.message}`, r.result !== 'ok');
    if (r.recording_path !== undefined) $('record-state').textContent = r.recording ? `recording ${r.recording_path}` : 'not recording';
    return r;
  } catch (e) {
    showResult(`${command}: ${e.message}`, true);
    return null;
  }
}

let armTimer = null;
function newProcedureClick() {
  const b = $('new-procedure');
  if (!b.classList.contains('armed')) {
    b.classList.add('armed');
    b.textContent = 'Confirm: reset the deficit';
    armTimer = setTimeout(() => { b.classList.remove('armed'); b.textContent = 'New procedure'; }, 5000);
    return;
  }
  clearTimeout(armTimer);
  b.classList.remove('armed');
  b.textContent = 'New procedure';
  control('new_procedure').then(refreshRecordings);
}

async function refreshRecordings() {
  const r = S.rigs[S.selected];
  const body = $('recordings').querySelector('tbody');
  if (!r || !r.info.recordings) return;
  try {
    const list = await api('GET', `/api/rigs/${S.selected}/recordings`);
    body.innerHTML = '';
    for (const e of list.recordings) {
      const tr = document.createElement('tr');
      const td = (t) => { const c = document.createElement('td'); c.textContent = t; tr.appendChild(c); return c; };
      td(e.name);
      td((e.size_bytes / 1e6).toFixed(2) + ' MB');
      td(new Date(e.modified_unix_s * 1000).toLocaleString());
      const b = document.createElement('button');
      b.textContent = 'Debrief';
      b.onclick = () => showDebrief(e.name);
      td('').appendChild(b);
      body.appendChild(tr);
    }
  } catch (e) {
    body.innerHTML = '';
    const tr = document.createElement('tr');
    tr.innerHTML = '<td colspan="4" class="muted"></td>';
    tr.firstChild.textContent = e.message;
    body.appendChild(tr);
  }
}

async function showDebrief(name) {
  $('debrief').classList.remove('hidden');
  $('debrief-title').textContent = 'debrief of ' + name + ' (computing)';
  try {
    const d = await api('GET', `/api/rigs/${S.selected}/recordings/${encodeURIComponent(name)}/debrief`);
    $('debrief-title').textContent = 'debrief of ' + name;
    const m = d.metrics;
    const rows = [
      ['duration', fmt(m.duration_s, 1) + ' s'], ['fluid in', fmt(m.fluid_in_ml, 1) + ' ml'],
      ['collected', fmt(m.fluid_collected_ml, 1) + ' ml'], ['deficit at end', `${fmt(m.deficit_ml, 1)} of ${fmt(m.deficit_limit_ml, 0)} ml`],
      ['deficit gained', fmt(m.deficit_gained_ml, 1) + ' ml'], ['peak deficit rate', `${fmt(m.peak_deficit_rate_ml_per_min, 1)} ml/min at ${fmt(m.peak_deficit_rate_at_s, 0)} s`],
      ['max cavity pressure', fmt(m.max_cavity_pressure_mmhg, 1) + ' mmHg'], ['time above overpressure', fmt(m.time_above_overpressure_s, 1) + ' s'],
      ['time distended', `${fmt(m.time_distended_s, 1)} s (>= ${fmt(m.distended_mmhg, 0)} mmHg)`],
      ['adjustments (valve in / out / pump)', `${m.valve_in_adjustments} / ${m.valve_out_adjustments} / ${m.pump_adjustments}`],
      ['perforation', m.perforation.occurred ? `at ${fmt(m.perforation.at_s, 1)} s, ${fmt(m.perforation.volume_ml, 1)} ml lost` : 'none'],
      ['scope path', fmt(m.scope_path_length_m * 1000, 0) + ' mm'], ['time in safe state', fmt(m.time_in_safe_state_s, 1) + ' s'],
      ['alarms', m.alarms.filter((a) => a.raised).map((a) => `${a.name} at ${fmt(a.t_s, 1)} s`).join(', ') || 'none'],
      ['recording', m.truncated ? 'unfinished (daemon stopped)' : 'complete'],
    ];
    const t = $('debrief-metrics');
    t.innerHTML = '';
    for (const [k, v] of rows) {
      const tr = t.insertRow();
      tr.insertCell().textContent = k;
      tr.insertCell().textContent = v;
    }
    const tEnd = d.t_s.length ? d.t_s[d.t_s.length - 1] : 1;
    drawPlot($('plot-debrief'), d.t_s, [
      { values: d.cavity_pressure_pa.map(mmHg), color: '#4ea1ff', label: 'cavity pressure (mmHg)' },
      { values: d.deficit_m3.map((v) => v * ML), color: '#e5484d', label: 'deficit (ml)' },
      { values: d.deficit_limit_m3.map((v) => v * ML), color: '#8b95a5', label: 'limit (ml)', dash: [6, 4] },
    ], [0, tEnd], '', 'time since the recording started, s');
  } catch (e) {
    $('debrief-title').textContent = `debrief of ${name}: ${e.message}`;
  }
}

// ---------------------------------------------------------------- loop and start
let lastPlots = 0, last3d = 0, lastRender = 0;
function frame(now) {
  lastRender = now;
  if (now - lastPlots > 200) { drawPlots(); lastPlots = now; }
  if (now - last3d > 30) {
    try { render3d(); renderEndoscope(); } catch (e) { S.errors.push(String(e)); }
    last3d = now;
  }
}
function loop(now) { frame(now); requestAnimationFrame(loop); }

async function start() {
  S.layout = await (await fetch('/layout.json')).json();
  try {
    renderer3d = makeRenderer($('view3d'));
    rendererEndo = makeRenderer($('endoscope'));
    S.webgl = !!(renderer3d && rendererEndo);
  } catch (e) {
    S.errors.push('WebGL: ' + e.message);
  }
  if (!S.webgl) $('view3d-note').textContent = 'this browser has no WebGL2: no 3D views';
  installOrbit($('view3d'));
  $('new-procedure').onclick = newProcedureClick;
  $('load-scene').onclick = () => control('load_scene', $('scene-file').value.trim() || $('scene-select').value);
  $('record-start').onclick = () => control('record_start').then(refreshRecordings);
  $('record-stop').onclick = () => control('record_stop').then(refreshRecordings);
  $('refresh-recordings').onclick = refreshRecordings;
  $('token-form').onsubmit = (e) => {
    e.preventDefault();
    token = $('token-input').value.trim();
    sessionStorage.setItem('hydrometra-token', token);
    if (ws) ws.close();
  };
  setConnection();
  connect();
  requestAnimationFrame(loop);
  // Hidden or headless pages may not get animation frames: draw at least every 100 ms.
  setInterval(() => { const now = performance.now(); if (now - lastRender > 100) frame(now); }, 100);
  setTimeout(refreshRecordings, 1500);
}

start();
