// hydrometra station: the page's two 3D views in WebGL2, no library: the cavity with the flow and
// the particles (orbitable), and the endoscope's view from the scope tip. Loaded before
// station.js, which owns the data (`S`, the rigs) and calls makeRenderer, render3d,
// renderEndoscope and installOrbit.
'use strict';

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

// From the patient's left, slightly above: the sagittal view of an ultrasound, where the
// anteroposterior distension (the cavity's thin dimension, +y) shows in the outline.
const orbit = { yaw: 1.45, pitch: 0.2, zoom: 1 };
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
  if (s && $('show-scope').checked) {
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

