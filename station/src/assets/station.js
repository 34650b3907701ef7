// hydrometra station: the instructor's page. Plain JavaScript, WebGL2 and canvas 2D, no library:
// everything the page runs ships inside the station binary. Frame layouts: docs/station.md;
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
      hist: { t: [], p: [], pump: [], inflow: [], outflow: [], losses: [], deficit: [], limit: [] },
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

function pushHistory(r, t, p, pump, inflow, outflow, losses, deficit, limit) {
  const h = r.hist;
  const n = h.t.length;
  if (n && t < h.t[n - 1]) for (const k in h) h[k].length = 0; // another run
  if (n && t - h.t[h.t.length - 1] < 0.1) return;
  h.t.push(t); h.p.push(p); h.pump.push(pump); h.inflow.push(inflow); h.outflow.push(outflow);
  h.losses.push(losses); h.deficit.push(deficit); h.limit.push(limit);
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
      s.deficit_m3, s.deficit_limit_m3);
    updateCard(r);
    if (r.info.index === S.selected) updateNumbers(r);
    send({ type: 'ack', rig: r.info.index, origin_ns: origin.toString() });
  } else if (kind === K.topology) {
    const vertexCount = dv.getUint32(H + 4, true);
    const triangles = dv.getUint32(H + 8, true);
    r.topologyRevision = Number(dv.getBigUint64(H + 16, true));
    r.topology = new Uint32Array(buf.slice(H + 24, H + 24 + 12 * triangles));
    r.vertexCount = vertexCount;
    r.geometryVersion++;
  } else if (kind === K.positions) {
    const n = dv.getUint32(H + 4, true);
    r.positionsRevision = Number(dv.getBigUint64(H + 24, true));
    r.positions = new Float32Array(buf.slice(H + 40, H + 40 + 12 * n));
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
      const o = H + 32 + 32 * i;
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
      pushHistory(r, dv.getFloat64(o, true), f(0), f(1), f(2), f(3), f(4), f(5), f(6));
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
const CRITICAL = ['terminated', 'deficit-limit', 'overpressure', 'rig-link-lost'];
const WARNING = ['deficit-50', 'deficit-75', 'deficit-rate', 'deadline-missed', 'scope-pose-invalid', 'rig-safe-state'];

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
    const what = terminated ? 'PROCEDURE TERMINATED (deficit limit reached, pump stopped)' : names.join(', ');
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

// series: [{values, color, label, dash}], t: times; xs: [t0, t1]
function drawPlot(canvas, t, series, xRange, yLabel, xLabel) {
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
  hi += 0.05 * (hi - lo);
  const X = (x) => L + ((x - t0) / (t1 - t0)) * (w - L - R);
  const Y = (y) => T + (1 - (y - lo) / (hi - lo)) * (h - T - B);
  g.font = '11px system-ui, sans-serif';
  g.strokeStyle = '#2a303a';
  g.fillStyle = '#8b95a5';
  g.lineWidth = 1;
  for (let k = 0; k <= 4; k++) {
    const y = lo + ((hi - lo) * k) / 4;
    g.beginPath(); g.moveTo(L, Y(y)); g.lineTo(w - R, Y(y)); g.stroke();
    g.fillText(y.toFixed(hi - lo < 10 ? 1 : 0), 4, Y(y) + 4);
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
}

function drawPlots() {
  const r = S.rigs[S.selected];
  if (!r) return;
  const h = r.hist;
  const n = h.t.length;
  const win = Number($('window').value);
  const tEnd = n ? h.t[n - 1] : 0;
  const xr = [tEnd - win, tEnd];
  const xl = `last ${win / 60} min (daemon time, s)`;
  const conv = (a, f) => a.map(f);
  drawPlot($('plot-pressure'), h.t, [
    { values: conv(h.p, mmHg), color: '#4ea1ff', label: 'cavity pressure' },
    { values: conv(h.pump, mmHg), color: '#f0a030', label: 'pump setting', dash: [5, 3] },
  ], xr, 'mmHg', xl);
  drawPlot($('plot-flows'), h.t, [
    { values: conv(h.inflow, (v) => v * ML_MIN), color: '#3fb950', label: 'inflow' },
    { values: conv(h.outflow, (v) => v * ML_MIN), color: '#4ea1ff', label: 'outflow' },
    { values: conv(h.losses, (v) => v * ML_MIN), color: '#e5484d', label: 'losses' },
  ], xr, 'ml/min', xl);
  drawPlot($('plot-deficit'), h.t, [
    { values: conv(h.deficit, (v) => v * ML), color: '#e5484d', label: 'deficit' },
    { values: conv(h.limit, (v) => v * ML), color: '#8b95a5', label: 'limit', dash: [6, 4] },
  ], xr, 'ml', xl);
}

// ---------------------------------------------------------------- 3D (WebGL2)
const M4 = {
  mul(a, b) {
    const o = new Float32Array(16);
    for (let c = 0; c < 4; c++) for (let r = 0; r < 4; r++) {
      let s = 0;
      for (let k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
      o[c * 4 + r] = s;
    }
    return o;
  },
  perspective(fovy, aspect, near, far) {
    const f = 1 / Math.tan(fovy / 2), nf = 1 / (near - far);
    return new Float32Array([f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0]);
  },
  lookAt(eye, at, up) {
    const z = norm(sub(eye, at)), x = norm(cross(up, z)), y = cross(z, x);
    return new Float32Array([x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0,
      -dot(x, eye), -dot(y, eye), -dot(z, eye), 1]);
  },
};
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const scale = (a, k) => [a[0] * k, a[1] * k, a[2] * k];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = (a) => { const l = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / l, a[1] / l, a[2] / l]; };

const MESH_VS = `#version 300 es
in vec3 aPos; in vec3 aNormal;
uniform mat4 uMVP;
out vec3 vPos; out vec3 vNormal;
void main() { vPos = aPos; vNormal = aNormal; gl_Position = uMVP * vec4(aPos, 1.0); }`;
const MESH_FS = `#version 300 es
precision highp float;
in vec3 vPos; in vec3 vNormal;
uniform vec3 uEye; uniform vec4 uColor; uniform float uEndoscope; uniform float uTurbidity;
out vec4 outColor;
void main() {
  vec3 n = normalize(vNormal);
  vec3 toEye = uEye - vPos;
  float d = length(toEye);
  float lambert = abs(dot(n, toEye / max(d, 1e-6)));
  // Mucosa with a faint vessel pattern (positions in m).
  float vessels = 0.5 + 0.5 * sin(vPos.x * 700.0 + sin(vPos.z * 400.0) * 2.0) * sin(vPos.y * 650.0 + vPos.z * 300.0);
  vec3 base = uColor.rgb * (0.85 + 0.15 * vessels);
  vec3 c;
  if (uEndoscope > 0.5) {
    // The light sits at the scope tip: it falls off with distance; blood in the fluid clouds it.
    float fall = 1.0 / (1.0 + pow(d / 0.025, 2.0));
    c = base * (0.08 + 1.1 * lambert * fall);
    float fog = 1.0 - exp(-d * (10.0 + 160.0 * uTurbidity));
    c = mix(c, vec3(0.35, 0.04, 0.03) * (0.3 + uTurbidity), clamp(fog * (0.2 + uTurbidity), 0.0, 1.0));
  } else {
    c = base * (0.25 + 0.75 * lambert);
  }
  outColor = vec4(c, uColor.a);
}`;
const LINE_VS = `#version 300 es
in vec3 aPos; in vec4 aColor; uniform mat4 uMVP; uniform float uPointSize; uniform vec3 uEye;
out vec4 vColor;
void main() { vColor = aColor; gl_Position = uMVP * vec4(aPos, 1.0);
  gl_PointSize = uPointSize / max(0.002, length(aPos - uEye)); }`;
const LINE_FS = `#version 300 es
precision mediump float; in vec4 vColor; out vec4 outColor;
uniform float uRound;
void main() {
  if (uRound > 0.5) { vec2 q = gl_PointCoord * 2.0 - 1.0; float r = dot(q, q); if (r > 1.0) discard;
    outColor = vec4(vColor.rgb, vColor.a * (1.0 - r)); return; }
  outColor = vColor; }`;

function makeRenderer(canvas) {
  const gl = canvas.getContext('webgl2', { antialias: true, preserveDrawingBuffer: true, alpha: false });
  if (!gl) return null;
  const compile = (vs, fs) => {
    const p = gl.createProgram();
    for (const [type, src] of [[gl.VERTEX_SHADER, vs], [gl.FRAGMENT_SHADER, fs]]) {
      const sh = gl.createShader(type);
      gl.shaderSource(sh, src);
      gl.compileShader(sh);
      if (!gl.getShaderParameter(sh, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(sh));
      gl.attachShader(p, sh);
    }
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(p));
    const u = {};
    const nu = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
    for (let i = 0; i < nu; i++) { const name = gl.getActiveUniform(p, i).name; u[name] = gl.getUniformLocation(p, name); }
    return { p, u, a: (name) => gl.getAttribLocation(p, name) };
  };
  const mesh = compile(MESH_VS, MESH_FS);
  const lines = compile(LINE_VS, LINE_FS);
  const buf = () => gl.createBuffer();
  return { gl, mesh, lines, b: { pos: buf(), nrm: buf(), idx: buf(), lpos: buf(), lcol: buf() }, version: -1, tris: 0 };
}

function vertexNormals(pos, idx) {
  const n = new Float32Array(pos.length);
  for (let t = 0; t < idx.length; t += 3) {
    const a = 3 * idx[t], b = 3 * idx[t + 1], c = 3 * idx[t + 2];
    if (c + 2 >= pos.length || a + 2 >= pos.length || b + 2 >= pos.length) continue;
    const ux = pos[b] - pos[a], uy = pos[b + 1] - pos[a + 1], uz = pos[b + 2] - pos[a + 2];
    const vx = pos[c] - pos[a], vy = pos[c + 1] - pos[a + 1], vz = pos[c + 2] - pos[a + 2];
    const nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
    for (const i of [a, b, c]) { n[i] += nx; n[i + 1] += ny; n[i + 2] += nz; }
  }
  return n;
}

function uploadMesh(R, r) {
  const gl = R.gl;
  if (!r.normals) r.normals = vertexNormals(r.positions, r.topology);
  gl.bindBuffer(gl.ARRAY_BUFFER, R.b.pos);
  gl.bufferData(gl.ARRAY_BUFFER, r.positions, gl.DYNAMIC_DRAW);
  gl.bindBuffer(gl.ARRAY_BUFFER, R.b.nrm);
  gl.bufferData(gl.ARRAY_BUFFER, r.normals, gl.DYNAMIC_DRAW);
  gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, R.b.idx);
  gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, r.topology, gl.DYNAMIC_DRAW);
  R.tris = r.topology.length;
}

function drawMesh(R, mvp, eye, color, endoscope, turbidity) {
  const gl = R.gl, m = R.mesh;
  gl.useProgram(m.p);
  gl.uniformMatrix4fv(m.u.uMVP, false, mvp);
  gl.uniform3fv(m.u.uEye, eye);
  gl.uniform4fv(m.u.uColor, color);
  gl.uniform1f(m.u.uEndoscope, endoscope ? 1 : 0);
  gl.uniform1f(m.u.uTurbidity, turbidity);
  gl.bindBuffer(gl.ARRAY_BUFFER, R.b.pos);
  gl.enableVertexAttribArray(m.a('aPos'));
  gl.vertexAttribPointer(m.a('aPos'), 3, gl.FLOAT, false, 0, 0);
  gl.bindBuffer(gl.ARRAY_BUFFER, R.b.nrm);
  gl.enableVertexAttribArray(m.a('aNormal'));
  gl.vertexAttribPointer(m.a('aNormal'), 3, gl.FLOAT, false, 0, 0);
  gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, R.b.idx);
  gl.drawElements(gl.TRIANGLES, R.tris, gl.UNSIGNED_INT, 0);
}

// Lines or points: positions (xyz) and colours (rgba) as Float32Arrays.
function drawPrims(R, mode, mvp, eye, pos, col, pointSize) {
  const gl = R.gl, l = R.lines;
  const count = pos.length / 3;
  if (!count) return;
  gl.useProgram(l.p);
  gl.uniformMatrix4fv(l.u.uMVP, false, mvp);
  gl.uniform3fv(l.u.uEye, eye);
  gl.uniform1f(l.u.uPointSize, pointSize || 1);
  gl.uniform1f(l.u.uRound, mode === gl.POINTS ? 1 : 0);
  gl.bindBuffer(gl.ARRAY_BUFFER, R.b.lpos);
  gl.bufferData(gl.ARRAY_BUFFER, pos, gl.STREAM_DRAW);
  gl.enableVertexAttribArray(l.a('aPos'));
  gl.vertexAttribPointer(l.a('aPos'), 3, gl.FLOAT, false, 0, 0);
  gl.bindBuffer(gl.ARRAY_BUFFER, R.b.lcol);
  gl.bufferData(gl.ARRAY_BUFFER, col, gl.STREAM_DRAW);
  gl.enableVertexAttribArray(l.a('aColor'));
  gl.vertexAttribPointer(l.a('aColor'), 4, gl.FLOAT, false, 0, 0);
  gl.drawArrays(mode, 0, count);
}

function speedColor(f) {
  // dark blue -> cyan -> yellow -> red
  const c = [[0.1, 0.2, 0.8], [0.1, 0.85, 0.95], [1.0, 0.9, 0.2], [1.0, 0.2, 0.1]];
  const x = Math.min(0.999, Math.max(0, f)) * 3, i = Math.floor(x), t = x - i;
  return [0, 1, 2].map((k) => c[i][k] * (1 - t) + c[i + 1][k] * t);
}

function arrowPrims(flow) {
  const a = flow.arrows, n = a.length / 6;
  const pos = new Float32Array(n * 18), col = new Float32Array(n * 24);
  const k = flow.maxSpeed > 0 ? (1.6 * flow.blockM) / flow.maxSpeed : 0;
  for (let i = 0; i < n; i++) {
    const p = [a[6 * i], a[6 * i + 1], a[6 * i + 2]];
    const v = [a[6 * i + 3], a[6 * i + 4], a[6 * i + 5]];
    const speed = Math.hypot(v[0], v[1], v[2]);
    const head = add(p, scale(v, k));
    const dir = norm(v);
    const side = norm(cross(dir, Math.abs(dir[2]) < 0.9 ? [0, 0, 1] : [1, 0, 0]));
    const len = speed * k * 0.3;
    const w1 = add(sub(head, scale(dir, len)), scale(side, len * 0.5));
    const w2 = sub(sub(head, scale(dir, len)), scale(side, len * 0.5));
    const segs = [p, head, head, w1, head, w2];
    const c = speedColor(flow.maxSpeed > 0 ? speed / flow.maxSpeed : 0);
    const alpha = 0.25 + 0.75 * Math.min(1, speed / (flow.maxSpeed || 1) * 3);
    for (let s = 0; s < 6; s++) {
      pos.set(segs[s], 18 * i + 3 * s);
      const dim = s === 0 ? 0.35 : 1;
      col.set([c[0] * dim, c[1] * dim, c[2] * dim, alpha], 24 * i + 4 * s);
    }
  }
  return { pos, col };
}

const PARTICLE_COLORS = [[0.55, 0.02, 0.02, 0.8], [0.9, 0.95, 1.0, 0.8], [0.95, 0.65, 0.6, 0.9]];
function particlePrims(parts, alpha) {
  const col = new Float32Array(4 * parts.count);
  for (let i = 0; i < parts.count; i++) {
    const c = PARTICLE_COLORS[parts.kinds[i]] || PARTICLE_COLORS[0];
    col.set([c[0], c[1], c[2], c[3] * alpha], 4 * i);
  }
  return { pos: parts.pos, col };
}

const orbit = { yaw: 0.6, pitch: 0.35, zoom: 1 };
let renderer3d = null, rendererEndo = null;

function bounds(pos) {
  const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  for (let i = 0; i < pos.length; i += 3) for (let k = 0; k < 3; k++) {
    lo[k] = Math.min(lo[k], pos[i + k]); hi[k] = Math.max(hi[k], pos[i + k]);
  }
  return { centre: scale(add(lo, hi), 0.5), radius: 0.5 * Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) };
}

function meshReady(r) {
  return r && r.topology && r.positions && r.positionsRevision === r.topologyRevision;
}

function render3d() {
  const r = S.rigs[S.selected];
  const canvas = $('view3d');
  if (!renderer3d) return;
  const R = renderer3d, gl = R.gl;
  const dpr = sizeCanvas(canvas);
  gl.viewport(0, 0, canvas.width, canvas.height);
  gl.clearColor(0.04, 0.05, 0.06, 1);
  gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  $('view3d-note').textContent = meshReady(r) ? '' : 'waiting for the cavity (scene preparing or not running)';
  if (!meshReady(r)) return;
  if (R.version !== r.geometryVersion || R.rig !== r.info.index) {
    uploadMesh(R, r);
    R.version = r.geometryVersion;
    R.rig = r.info.index;
    if (!R.bounds || R.boundsRig !== r.info.index || R.boundsTopology !== r.topologyRevision) {
      R.bounds = bounds(r.positions);
      R.boundsRig = r.info.index;
      R.boundsTopology = r.topologyRevision;
    }
  }
  const { centre, radius } = R.bounds;
  const d = 2.6 * radius * orbit.zoom;
  const eye = add(centre, scale([Math.cos(orbit.pitch) * Math.sin(orbit.yaw), Math.cos(orbit.pitch) * Math.cos(orbit.yaw), Math.sin(orbit.pitch)], d));
  const proj = M4.perspective(0.8, canvas.width / canvas.height, d * 0.05, d * 4);
  const mvp = M4.mul(proj, M4.lookAt(eye, centre, [0, 0, 1]));
  gl.enable(gl.DEPTH_TEST);
  gl.enable(gl.BLEND);
  gl.blendFunc(gl.SRC_ALPHA, gl.ONE_MINUS_SRC_ALPHA);
  const s = r.status;
  if ($('show-flow').checked && r.flow) {
    const a = arrowPrims(r.flow);
    drawPrims(R, gl.LINES, mvp, eye, a.pos, a.col);
  }
  if ($('show-particles').checked && r.particles && r.particles.count) {
    const p = particlePrims(r.particles, 1);
    drawPrims(R, gl.POINTS, mvp, eye, p.pos, p.col, 3.0 * dpr * 0.05);
  }
  if (s) {
    const tip = s.scope_tip_position_m, dir = norm(s.scope_view_direction);
    const tail = sub(tip, scale(dir, 0.08));
    drawPrims(R, gl.LINES, mvp, eye, new Float32Array([...tail, ...tip]), new Float32Array([0.75, 0.75, 0.8, 1, 0.95, 0.95, 1, 1]));
    drawPrims(R, gl.POINTS, mvp, eye, new Float32Array(tip), new Float32Array([1, 0.85, 0.2, 1]), 12 * dpr * 0.05);
  }
  // The wall last and translucent, so the flow inside shows through.
  gl.depthMask(false);
  drawMesh(R, mvp, eye, [0.85, 0.45, 0.45, 0.35], false, 0);
  gl.depthMask(true);
  S.renders3d++;
}

function renderEndoscope() {
  const r = S.rigs[S.selected];
  const canvas = $('endoscope');
  if (!rendererEndo) return;
  const R = rendererEndo, gl = R.gl;
  const dpr = sizeCanvas(canvas);
  gl.viewport(0, 0, canvas.width, canvas.height);
  gl.clearColor(0, 0, 0, 1);
  gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  if (!meshReady(r) || !r.status) return;
  if (R.version !== r.geometryVersion || R.rig !== r.info.index) {
    uploadMesh(R, r);
    R.version = r.geometryVersion;
    R.rig = r.info.index;
  }
  const s = r.status;
  const eye = s.scope_tip_position_m;
  const dir = norm(s.scope_view_direction);
  // The image's up: the scope's own y axis (orientation quaternion), else anterior (+y).
  const [w, x, y, z] = s.scope_orientation_wxyz;
  let up = [2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)];
  up = sub(up, scale(dir, dot(up, dir)));
  if (Math.hypot(...up) < 1e-3) up = Math.abs(dir[1]) < 0.9 ? [0, 1, 0] : [1, 0, 0];
  const proj = M4.perspective(1.45, canvas.width / canvas.height, 0.0005, 0.2);
  const mvp = M4.mul(proj, M4.lookAt(eye, add(eye, dir), norm(up)));
  const clarity = Number.isFinite(s.view_clarity) ? s.view_clarity : 1;
  gl.enable(gl.DEPTH_TEST);
  gl.disable(gl.BLEND);
  drawMesh(R, mvp, eye, [0.92, 0.55, 0.5, 1], true, 1 - clarity);
  if (r.particles && r.particles.count) {
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.SRC_ALPHA, gl.ONE_MINUS_SRC_ALPHA);
    gl.depthMask(false);
    const p = particlePrims(r.particles, 0.5);
    drawPrims(R, gl.POINTS, mvp, eye, p.pos, p.col, 1.2 * dpr);
    gl.depthMask(true);
  }
  S.rendersEndoscope++;
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

function installOrbit(canvas) {
  let drag = null;
  canvas.addEventListener('pointerdown', (e) => { drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); });
  canvas.addEventListener('pointerup', () => { drag = null; });
  canvas.addEventListener('pointermove', (e) => {
    if (!drag) return;
    orbit.yaw -= (e.clientX - drag[0]) * 0.01;
    orbit.pitch = Math.max(-1.5, Math.min(1.5, orbit.pitch + (e.clientY - drag[1]) * 0.01));
    drag = [e.clientX, e.clientY];
  });
  canvas.addEventListener('wheel', (e) => { e.preventDefault(); orbit.zoom = Math.max(0.2, Math.min(5, orbit.zoom * Math.exp(e.deltaY * 0.001))); }, { passive: false });
}

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
