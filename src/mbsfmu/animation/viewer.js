// mbsfmu animation viewer: draws precomputed frames (no physics here) with three.js.
// Data (id "mbsfmu-data"): t (float64, base64), frames (float32, base64, `stride` numbers per frame:
// per body position + quaternion x y z w, then elastic node positions, then spring end points), scene.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

const D = JSON.parse(document.getElementById('mbsfmu-data').textContent);
const bytes = (b64) => Uint8Array.from(atob(b64), (c) => c.charCodeAt(0)).buffer;
const T = new Float64Array(bytes(D.t));
const F = new Float32Array(bytes(D.frames));
const S = D.stride, N = T.length, W = D.scene, size = W.size;

// -- renderer, camera, controls, lights --------------------------------------------------------------
const renderer = new THREE.WebGLRenderer({ antialias: true });
renderer.setPixelRatio(window.devicePixelRatio);
renderer.setSize(window.innerWidth, window.innerHeight);
document.body.prepend(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0xf3f4f6);
const C = W.camera;
const camera = new THREE.PerspectiveCamera(C.fov, window.innerWidth / window.innerHeight, C.near, C.far);
camera.up.fromArray(C.up);
camera.position.fromArray(C.position);
const controls = new OrbitControls(camera, renderer.domElement);
controls.target.fromArray(C.target);
controls.update();
scene.add(new THREE.AmbientLight(0xffffff, 1.2));
const headlight = new THREE.DirectionalLight(0xffffff, 2.0);
camera.add(headlight);
headlight.position.set(0.3, 0.6, 0.2);
scene.add(camera);

// -- helpers -----------------------------------------------------------------------------------------
const material = (color, opacity = 1) => new THREE.MeshStandardMaterial({
  color, roughness: 0.55, metalness: 0.05, transparent: opacity < 1, opacity });
const unitRod = new THREE.CylinderGeometry(1, 1, 1, 16).translate(0, 0.5, 0);  // y from 0 to 1
const Y = new THREE.Vector3(0, 1, 0), tmp = new THREE.Vector3();
function placeRod(mesh, a, b, r) {  // a rod of radius r from point a to point b
  tmp.subVectors(b, a);
  const len = tmp.length();
  mesh.position.copy(a);
  mesh.scale.set(r, Math.max(len, 1e-9), r);
  if (len > 0) mesh.quaternion.setFromUnitVectors(Y, tmp.divideScalar(len));
}
function rod(color, r, a, b) {
  const m = new THREE.Mesh(unitRod, material(color));
  if (a) placeRod(m, a, b, r);
  return m;
}
function label(text, color, at, h) {  // text that always faces the camera
  const cv = document.createElement('canvas');
  cv.width = 64; cv.height = 64;
  const g = cv.getContext('2d');
  g.fillStyle = color; g.font = 'bold 48px sans-serif'; g.textAlign = 'center'; g.textBaseline = 'middle';
  g.fillText(text, 32, 34);
  const s = new THREE.Sprite(new THREE.SpriteMaterial({ map: new THREE.CanvasTexture(cv), depthTest: false }));
  s.position.copy(at); s.scale.set(h, h, 1);
  return s;
}
const yAxis = new THREE.Vector3(0, 1, 0), zAxis = new THREE.Vector3(0, 0, 1);
function shapeMesh(s, fallback) {
  let geo;
  if (s.type === 'box') geo = new THREE.BoxGeometry(...s.size);
  else if (s.type === 'sphere') geo = new THREE.SphereGeometry(s.radius, 32, 16);
  else if (s.type === 'cylinder') geo = new THREE.CylinderGeometry(s.radius, s.radius, s.length, 32);
  else if (s.type === 'capsule') geo = new THREE.CapsuleGeometry(s.radius, s.length, 8, 24);
  else {
    geo = new THREE.BufferGeometry();
    geo.setAttribute('position', new THREE.BufferAttribute(new Float32Array(bytes(s.triangles)), 3));
    geo.computeVertexNormals();
  }
  if (s.type === 'cylinder' || s.type === 'capsule') {  // three.js builds them along y; the scene format along z
    geo.applyQuaternion(new THREE.Quaternion().setFromUnitVectors(yAxis, zAxis));
  }
  const m = new THREE.Mesh(geo, material(s.color || fallback, s.opacity));
  m.position.fromArray(s.at);
  m.quaternion.fromArray(s.quaternion);
  return m;
}

// -- world frame and gravity -------------------------------------------------------------------------
const axisLen = 0.15 * size;
scene.add(new THREE.AxesHelper(axisLen));
['x', 'y', 'z'].forEach((n, k) => {
  const at = new THREE.Vector3(); at.setComponent(k, 1.12 * axisLen);
  scene.add(label(n, ['#c02020', '#209020', '#2040c0'][k], at, 0.05 * size));
});
const g = new THREE.Vector3().fromArray(W.gravity);
if (g.lengthSq() > 0) {
  const up = new THREE.Vector3().fromArray(C.up), target = new THREE.Vector3().fromArray(C.target);
  const side = new THREE.Vector3().crossVectors(up, new THREE.Vector3().subVectors(camera.position, target)).normalize();
  const from = target.clone().addScaledVector(side, -0.45 * size).addScaledVector(up, 0.3 * size);
  const len = 0.2 * size;
  scene.add(new THREE.ArrowHelper(g.clone().normalize(), from, len, 0x303030, 0.3 * len, 0.15 * len));
  scene.add(label('g', '#303030', from.clone().addScaledVector(side, 0.04 * size), 0.05 * size));
}

// -- bodies: a group per body frame; links, markers and shapes are fixed in it -------------------------
const rLink = 0.006 * size;
const groups = W.bodies.map((b) => {
  const grp = new THREE.Group();
  grp.matrixAutoUpdate = true;
  if (b.shapes.length) {
    b.shapes.forEach((s) => grp.add(shapeMesh(s, b.color)));
  } else {
    const o = new THREE.Vector3();
    b.links.forEach((p) => grp.add(rod(b.color, rLink, o, new THREE.Vector3().fromArray(p))));
    grp.add(new THREE.Mesh(new THREE.SphereGeometry(1.8 * rLink, 16, 8), material(0x555555)));
    if (b.marker > 0) {
      const m = new THREE.Mesh(new THREE.SphereGeometry(b.marker, 24, 12), material(b.color));
      m.position.fromArray(b.com);
      grp.add(m);
    }
  }
  grp.add(new THREE.AxesHelper(0.05 * size));
  scene.add(grp);
  return grp;
});
const elastic = W.elastic.map((e) => {
  const segs = [];
  for (let k = 0; k + 1 < e.nodes; k++) {
    const m = rod(W.bodies[e.body].color, 1.3 * rLink);
    scene.add(m); segs.push(m);
  }
  return segs;
});
const springs = [];
for (let k = 0; k < W.springs; k++) {
  const m = rod(0x909090, 0.6 * rLink);
  scene.add(m); springs.push(m);
}

// -- time --------------------------------------------------------------------------------------------
const qa = new THREE.Quaternion(), qb = new THREE.Quaternion(), pa = new THREE.Vector3(), pb = new THREE.Vector3();
let now = T[0], playing = false, speed = 1, dirty = true;
function frameAt(t) {  // index k and weight w with T[k] <= t <= T[k + 1]
  let lo = 0, hi = N - 1;
  while (hi - lo > 1) { const mid = (lo + hi) >> 1; if (T[mid] <= t) lo = mid; else hi = mid; }
  const w = N > 1 && T[hi] > T[lo] ? Math.min(1, Math.max(0, (t - T[lo]) / (T[hi] - T[lo]))) : 0;
  return [lo, hi, w];
}
function point(k0, k1, w, off, out) {
  return out.set(F[k0 * S + off], F[k0 * S + off + 1], F[k0 * S + off + 2]).lerp(
    pb.set(F[k1 * S + off], F[k1 * S + off + 1], F[k1 * S + off + 2]), w);
}
function show(t) {
  now = Math.min(T[N - 1], Math.max(T[0], t));
  const [k0, k1, w] = frameAt(now);
  groups.forEach((grp, i) => {
    const o = 7 * i;
    point(k0, k1, w, o, grp.position);
    qa.fromArray(F, k0 * S + o + 3); qb.fromArray(F, k1 * S + o + 3);
    grp.quaternion.slerpQuaternions(qa, qb, w);
  });
  let off = 7 * groups.length;
  elastic.forEach((segs) => {
    let a = point(k0, k1, w, off, new THREE.Vector3());
    segs.forEach((m) => { off += 3; const b = point(k0, k1, w, off, new THREE.Vector3()); placeRod(m, a, b, 1.3 * rLink); a = b; });
    off += 3;
  });
  springs.forEach((m) => {
    const a = point(k0, k1, w, off, new THREE.Vector3()), b = point(k0, k1, w, off + 3, new THREE.Vector3());
    placeRod(m, a, b, 0.6 * rLink); off += 6;
  });
  slider.value = T[N - 1] > T[0] ? Math.round(1000 * (now - T[0]) / (T[N - 1] - T[0])) : 0;
  clock.textContent = `t = ${now.toFixed(3)} s / ${T[N - 1].toFixed(3)} s`;
  dirty = true;
}

// -- controls: play/pause, slider, speed, keys, #t=<seconds> -----------------------------------------
const el = (id) => document.getElementById(id);
const slider = el('slider'), clock = el('clock'), playBtn = el('play'), speedSel = el('speed');
el('title').textContent = D.name;
el('desc').textContent = D.description;
const setPlaying = (p) => { playing = p; playBtn.textContent = p ? '❚❚' : '▶'; last = null; };
playBtn.onclick = () => { if (!playing && now >= T[N - 1]) show(T[0]); setPlaying(!playing); };
slider.oninput = () => { setPlaying(false); show(T[0] + (T[N - 1] - T[0]) * slider.value / 1000); };
speedSel.onchange = () => { speed = parseFloat(speedSel.value); };
window.addEventListener('keydown', (e) => {
  if (e.key === ' ') { e.preventDefault(); playBtn.onclick(); }
  if (e.key === 'ArrowRight' || e.key === 'ArrowLeft') {
    setPlaying(false);
    const [k0, k1] = frameAt(now);
    show(T[e.key === 'ArrowRight' ? Math.min(N - 1, k0 + 1) : (T[k0] < now ? k0 : Math.max(0, k0 - 1))]);
  }
});
function fromHash() {  // #t=1.5 opens paused at t = 1.5 s; &ui=0 hides the text and the control bar
  const hideUi = /(?:^|[#&])ui=0(?:&|$)/.test(window.location.hash);
  ['info', 'bar'].forEach((id) => { el(id).style.display = hideUi ? 'none' : ''; });
  dirty = true;
  const m = /(?:^|[#&])t=([-+0-9.eE]+)/.exec(window.location.hash);
  if (!m || !Number.isFinite(parseFloat(m[1]))) return false;
  setPlaying(false);
  show(parseFloat(m[1]));
  return true;
}
window.addEventListener('hashchange', fromHash);
controls.addEventListener('change', () => { dirty = true; });
window.addEventListener('resize', () => {
  camera.aspect = window.innerWidth / window.innerHeight;
  camera.updateProjectionMatrix();
  renderer.setSize(window.innerWidth, window.innerHeight);
  dirty = true;
});

let last = null;
function loop(ms) {
  if (playing) {
    if (last !== null) {
      const t = now + speed * (ms - last) / 1000;
      show(t > T[N - 1] ? T[0] + (t - T[N - 1]) % Math.max(T[N - 1] - T[0], 1e-9) : t);
    }
    last = ms;
  }
  if (dirty) {
    renderer.render(scene, camera);
    dirty = false;
    window.mbsfmuView = { ready: true, t: now, playing };  // for tests and scripts: what is on screen
  }
  requestAnimationFrame(loop);
}
if (!fromHash()) { show(T[0]); setPlaying(true); }
requestAnimationFrame(loop);
