// The `soma view` page: markers of a capture in 3D (three.js), playback,
// colour modes, a timeline strip and hover information. The data is the
// JSON that `soma view` puts into #soma-view-data (see data.js).
//
// For tests and scripts the page mirrors its state into data-* attributes
// of #status (data-ready, data-frames, data-shown-frames, data-points,
// data-frame, data-frame-points, data-frame-wrong, data-frame-ghost,
// data-frame-missed, data-frame-accuracy, data-webgl) and `window.somaView`.
// The URL hash `#frame=N` (0-based take frame) opens the page paused there;
// `&mode=label|confidence|correctness` picks the colour mode, and
// `&hover=error|wrong|ghost|missed|<i>` hovers that point (data-hover),
// `&timeline=<fraction>` clicks the timeline strip there.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { decodeViewData, frameCounts, shownFrameOf, STATUS, UNKNOWN_CONFIDENCE } from './data.js';

const $ = (id) => document.getElementById(id);
const MARKER_RADIUS = 0.014;  // metres
const NULL_COLOR = new THREE.Color(0x8a8f98);
const STATUS_COLORS = {
  [STATUS.NO_TRUTH]: new THREE.Color(0x6fa8dc),
  [STATUS.CORRECT]: new THREE.Color(0x58b368),
  [STATUS.WRONG]: new THREE.Color(0xe53935),
  [STATUS.GHOST]: new THREE.Color(0xff9800),
  [STATUS.MISSED]: new THREE.Color(0xffffff),
};
const REJECTED_GHOST_COLOR = new THREE.Color(0x50555e);  // true null, labelled null

function labelColor(id) {
  const c = new THREE.Color();
  c.setHSL(((id * 137.508) % 360) / 360, 0.68, 0.56);
  return c;
}

// Heat: 0 red, 0.5 yellow, 1 green.
function heatColor(value) {
  const c = new THREE.Color();
  c.setHSL((Math.max(0, Math.min(1, value)) * 120) / 360, 0.85, 0.5);
  return c;
}

function parseHash() {
  const out = {};
  for (const part of location.hash.replace(/^#/, '').split('&')) {
    const [k, v] = part.split('=');
    if (k) out[decodeURIComponent(k)] = v === undefined ? '' : decodeURIComponent(v);
  }
  return out;
}

function fmt(value, digits) {
  return Number.isFinite(value) ? value.toFixed(digits) : 'n/a';
}

class Viewer {
  constructor(data) {
    this.data = data;
    this.frame = 0;  // shown frame index
    this.playing = false;
    this.speed = 1;
    this.accum = 0;
    this.mode = data.has_truth ? 'correctness' : 'label';
    this.labelColors = data.labels.map((_, i) => labelColor(i));
    this.status = $('status');
    this.setupDom();
    try {
      this.setupScene();
      this.status.dataset.webgl = 'ok';
    } catch (e) {
      this.renderer = null;
      this.status.dataset.webgl = 'failed';
      this.showMessage(`3D view unavailable (WebGL: ${e.message}); the timeline and counts still work.`);
    }
    const hash = parseHash();
    if (hash.mode && ['label', 'confidence', 'correctness'].includes(hash.mode)) this.mode = hash.mode;
    $('mode').value = this.mode;
    this.drawTimeline();
    this.buildLegend();
    const start = hash.frame !== undefined ? shownFrameOf(data, Number(hash.frame) || 0) : 0;
    this.seek(start);
    window.addEventListener('hashchange', () => {
      const h = parseHash();
      if (h.frame !== undefined) { this.setPlaying(false); this.seek(shownFrameOf(data, Number(h.frame) || 0)); }
    });
    this.last = performance.now();
    if (hash.timeline !== undefined) this.clickTimeline(Number(hash.timeline));
    if (hash.hover !== undefined && this.renderer) this.hoverPoint(hash.hover);
    requestAnimationFrame((t) => this.tick(t));
    this.status.dataset.ready = '1';
  }

  showMessage(text) {
    const m = $('message');
    m.textContent = text;
    m.hidden = false;
  }

  setupDom() {
    const d = this.data;
    $('title').textContent = `soma view: ${d.title}`;
    document.title = `soma view: ${d.title}`;
    const parts = [`${d.take_frames} frames at ${d.frame_rate} Hz`, `${d.labels.length} labels`];
    parts.push(`capture ${d.source}`);
    if (d.truth_source) parts.push(`ground truth ${d.truth_source}`);
    if (d.confidence_source) parts.push(`confidences ${d.confidence_source}`);
    if (d.has_mesh) parts.push(`body ${d.mesh_source} (${d.mesh_frame.length} meshes, every ${d.mesh_step} frames)`);
    $('sources').textContent = parts.join(' · ');
    if (d.note) { $('note').textContent = d.note; $('note').hidden = false; }
    const slider = $('slider');
    slider.max = String(d.num_frames - 1);
    slider.addEventListener('input', () => { this.setPlaying(false); this.seek(Number(slider.value)); });
    $('play').addEventListener('click', () => this.setPlaying(!this.playing));
    $('speed').addEventListener('change', (e) => { this.speed = Number(e.target.value); });
    const mode = $('mode');
    if (!d.has_confidence) mode.querySelector('option[value=confidence]').disabled = true;
    if (!d.has_truth) mode.querySelector('option[value=correctness]').disabled = true;
    mode.addEventListener('change', () => { this.mode = mode.value; this.buildLegend(); this.updateFrame(); });
    $('show-sticks').addEventListener('change', () => this.updateFrame());
    $('show-null').addEventListener('change', () => this.updateFrame());
    $('mesh-toggle').hidden = !d.has_mesh;
    $('show-mesh').addEventListener('change', () => this.updateFrame());
    window.addEventListener('keydown', (e) => {
      if (e.target.tagName === 'SELECT' || e.target.tagName === 'INPUT' && e.target.type !== 'range') return;
      if (e.code === 'Space') { e.preventDefault(); this.setPlaying(!this.playing); }
      if (e.code === 'ArrowRight') { this.setPlaying(false); this.seek(Math.min(this.frame + 1, d.num_frames - 1)); }
      if (e.code === 'ArrowLeft') { this.setPlaying(false); this.seek(Math.max(this.frame - 1, 0)); }
    });
    const timeline = $('timeline');
    const seekFromEvent = (e) => {
      const r = timeline.getBoundingClientRect();
      const x = Math.max(0, Math.min(r.width - 1, e.clientX - r.left));
      this.setPlaying(false);
      this.seek(Math.floor((x / r.width) * d.num_frames));
    };
    timeline.addEventListener('mousedown', (e) => {
      seekFromEvent(e);
      const move = (ev) => seekFromEvent(ev);
      const up = () => { window.removeEventListener('mousemove', move); window.removeEventListener('mouseup', up); };
      window.addEventListener('mousemove', move);
      window.addEventListener('mouseup', up);
    });
    window.addEventListener('resize', () => { this.resize(); this.drawTimeline(); });
    const stats = this.status.dataset;
    stats.frames = String(d.take_frames);
    stats.shownFrames = String(d.num_frames);
    stats.frameStep = String(d.frame_step);
    stats.points = String(d.num_points);
    stats.labels = String(d.labels.length);
  }

  setupScene() {
    const canvas = $('canvas');
    const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
    renderer.setPixelRatio(window.devicePixelRatio || 1);
    this.renderer = renderer;
    const scene = new THREE.Scene();
    scene.background = new THREE.Color(0x14171c);
    this.scene = scene;
    const camera = new THREE.PerspectiveCamera(40, 1, 0.01, 200);
    camera.up.set(0, 0, 1);  // mocap: z up
    this.camera = camera;
    scene.add(new THREE.HemisphereLight(0xffffff, 0x303840, 2.2));
    const sun = new THREE.DirectionalLight(0xffffff, 1.4);
    sun.position.set(3, -4, 6);
    scene.add(sun);

    // Where the subject is: the median of all shown points.
    const d = this.data;
    const center = new THREE.Vector3();
    if (d.num_points > 0) {
      const step = Math.max(1, Math.floor(d.num_points / 20000));
      const axes = [[], [], []];
      for (let i = 0; i < d.num_points; i += step) {
        for (let a = 0; a < 3; a++) axes[a].push(d.position[3 * i + a]);
      }
      const median = (v) => { v.sort((x, y) => x - y); return v[v.length >> 1]; };
      center.set(median(axes[0]), median(axes[1]), median(axes[2]));
    }
    const grid = new THREE.GridHelper(12, 24, 0x4a5160, 0x2b303a);
    grid.rotation.x = Math.PI / 2;  // the XY plane (z = 0 floor)
    grid.position.set(Math.round(center.x), Math.round(center.y), 0);
    scene.add(grid);
    // The capture's origin; x magenta, y cyan, z blue (red and orange mean
    // labelling errors here).
    const axes = new THREE.AxesHelper(0.3);
    axes.setColors(new THREE.Color(0xd070ff), new THREE.Color(0x40d0d0), new THREE.Color(0x6080ff));
    axes.position.set(0, 0, 0.001);
    scene.add(axes);

    camera.position.set(center.x + 1.8, center.y - 2.5, Math.max(center.z, 0.9) + 0.6);
    const controls = new OrbitControls(camera, canvas);
    controls.target.set(center.x, center.y, Math.max(center.z, 0.9));
    controls.enableDamping = false;
    controls.update();
    controls.addEventListener('change', () => { this.dirty = true; });
    this.controls = controls;

    const n = Math.max(d.maxPoints, 1);
    const sphere = new THREE.SphereGeometry(MARKER_RADIUS, 16, 12);
    this.solid = new THREE.InstancedMesh(sphere, new THREE.MeshStandardMaterial({ roughness: 0.5 }), n);
    this.solid.instanceMatrix.setUsage(THREE.DynamicDrawUsage);
    this.solid.count = 0;
    this.solid.frustumCulled = false;
    this.solid.setColorAt(0, new THREE.Color());
    scene.add(this.solid);
    // Missed markers: hollow rings (sprites that always face the camera).
    const ring = document.createElement('canvas');
    ring.width = ring.height = 64;
    const g = ring.getContext('2d');
    g.strokeStyle = '#ffffff';
    g.lineWidth = 7;
    g.beginPath();
    g.arc(32, 32, 25, 0, 2 * Math.PI);
    g.stroke();
    const hollowGeometry = new THREE.BufferGeometry();
    this.hollowPositions = new Float32Array(3 * n);
    this.hollowColors = new Float32Array(3 * n);
    hollowGeometry.setAttribute('position', new THREE.BufferAttribute(this.hollowPositions, 3).setUsage(THREE.DynamicDrawUsage));
    hollowGeometry.setAttribute('color', new THREE.BufferAttribute(this.hollowColors, 3).setUsage(THREE.DynamicDrawUsage));
    this.hollow = new THREE.Points(hollowGeometry, new THREE.PointsMaterial({
      size: 11 * MARKER_RADIUS, sizeAttenuation: true, map: new THREE.CanvasTexture(ring),
      vertexColors: true, transparent: true, alphaTest: 0.3, depthWrite: false }));
    this.hollow.frustumCulled = false;
    scene.add(this.hollow);
    const stickGeometry = new THREE.BufferGeometry();
    this.stickPositions = new Float32Array(Math.max(d.sticks.length, 1) * 6);
    stickGeometry.setAttribute('position', new THREE.BufferAttribute(this.stickPositions, 3).setUsage(THREE.DynamicDrawUsage));
    this.sticks = new THREE.LineSegments(stickGeometry, new THREE.LineBasicMaterial({ color: 0x9aa3b2, transparent: true, opacity: 0.7 }));
    this.sticks.frustumCulled = false;
    scene.add(this.sticks);

    if (d.has_mesh) {
      // The solve's body: one geometry whose vertices change with the frame.
      this.meshVertexCount = d.mesh_vertices.length / d.mesh_frame.length / 3;
      const geometry = new THREE.BufferGeometry();
      geometry.setAttribute('position', new THREE.BufferAttribute(new Float32Array(3 * this.meshVertexCount), 3).setUsage(THREE.DynamicDrawUsage));
      geometry.setIndex(new THREE.BufferAttribute(d.mesh_faces, 1));
      this.body = new THREE.Mesh(geometry, new THREE.MeshStandardMaterial({
        color: 0xd9c2a7, roughness: 0.8, transparent: true, opacity: 0.35, depthWrite: false, side: THREE.DoubleSide }));
      this.body.frustumCulled = false;
      this.body.visible = false;
      this.bodyMesh = -1;
      scene.add(this.body);
    }
    const canvasEl = canvas;
    canvasEl.addEventListener('mousemove', (e) => this.hover(e));
    canvasEl.addEventListener('mouseleave', () => { $('tooltip').hidden = true; });
    this.resize();
  }

  resize() {
    if (!this.renderer) return;
    const view = $('view');
    const w = Math.max(view.clientWidth, 1), h = Math.max(view.clientHeight, 1);
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.dirty = true;
  }

  setPlaying(playing) {
    this.playing = playing;
    $('play').innerHTML = playing ? '&#10074;&#10074;' : '&#9654;';
  }

  seek(f) {
    this.frame = Math.max(0, Math.min(this.data.num_frames - 1, f));
    $('slider').value = String(this.frame);
    this.updateFrame();
  }

  colorOf(i) {
    const d = this.data;
    if (this.mode === 'correctness' && d.has_truth) {
      const s = d.status[i];
      if (s === STATUS.CORRECT && d.label[i] === d.nullId) return REJECTED_GHOST_COLOR;
      return STATUS_COLORS[s];
    }
    if (this.mode === 'confidence' && d.has_confidence) {
      const c = d.confidence[i];
      return c === UNKNOWN_CONFIDENCE ? NULL_COLOR : heatColor(c / 65534);
    }
    return d.label[i] === d.nullId ? NULL_COLOR : this.labelColors[d.label[i]];
  }

  updateFrame() {
    const d = this.data;
    const f = this.frame;
    const counts = frameCounts(d, f);
    const stats = this.status.dataset;
    stats.frame = String(d.frame[f]);
    stats.shownFrame = String(f);
    stats.framePoints = String(counts.points);
    stats.frameLabelled = String(counts.labelled);
    if (d.has_truth) {
      stats.frameWrong = String(counts.wrong);
      stats.frameGhost = String(counts.ghost);
      stats.frameMissed = String(counts.missed);
      stats.frameAccuracy = fmt(d.accuracy[f], 6);
    }
    let text = `frame ${d.frame[f]} / ${d.take_frames - 1}  ·  ${counts.points} points, ${counts.labelled} labelled`;
    if (d.has_truth) {
      text += `  ·  accuracy ${fmt(100 * d.accuracy[f], 1)}%  ·  ${counts.wrong} wrong, ${counts.ghost} ghosts as markers, ${counts.missed} missed`;
    } else if (d.has_confidence) {
      text += `  ·  mean confidence ${fmt(d.confidence_mean[f], 3)}`;
    }
    this.status.textContent = text;
    if (this.legendCounts) {
      const rejected = counts.correct - counts.labelledCorrect;
      const values = { correctMarker: counts.labelledCorrect, rejected, wrong: counts.wrong, ghost: counts.ghost, missed: counts.missed, noTruth: counts.noTruth };
      for (const [key, el] of Object.entries(this.legendCounts)) el.textContent = String(values[key]);
    }
    this.drawCursor();
    if (!this.renderer) return;

    const showNull = $('show-null').checked;
    const m = new THREE.Matrix4();
    let ns = 0, nh = 0;
    this.byLabel = new Map();
    this.shown = [];
    for (let i = d.offset[f]; i < d.offset[f + 1]; i++) {
      const x = d.position[3 * i], y = d.position[3 * i + 1], z = d.position[3 * i + 2];
      if (d.label[i] !== d.nullId && !this.byLabel.has(d.label[i])) this.byLabel.set(d.label[i], i);
      const missed = this.mode === 'correctness' && d.has_truth && d.status[i] === STATUS.MISSED;
      if (!showNull && d.label[i] === d.nullId && !missed) continue;
      m.makeTranslation(x, y, z);
      const color = this.colorOf(i);
      if (missed) {
        this.hollowPositions.set([x, y, z], 3 * nh);
        this.hollowColors.set([color.r, color.g, color.b], 3 * nh);
        nh++;
      } else {
        this.solid.setMatrixAt(ns, m); this.solid.setColorAt(ns, color); ns++;
      }
      this.shown.push(i);
    }
    this.solid.count = ns;
    this.solid.instanceMatrix.needsUpdate = true;
    if (this.solid.instanceColor) this.solid.instanceColor.needsUpdate = true;
    this.hollow.geometry.setDrawRange(0, nh);
    this.hollow.geometry.attributes.position.needsUpdate = true;
    this.hollow.geometry.attributes.color.needsUpdate = true;
    let k = 0;
    if ($('show-sticks').checked) {
      for (const [a, b] of d.sticks) {
        const ia = this.byLabel.get(a), ib = this.byLabel.get(b);
        if (ia === undefined || ib === undefined) continue;
        for (let c = 0; c < 3; c++) {
          this.stickPositions[6 * k + c] = d.position[3 * ia + c];
          this.stickPositions[6 * k + 3 + c] = d.position[3 * ib + c];
        }
        k++;
      }
    }
    this.sticks.geometry.setDrawRange(0, 2 * k);
    this.sticks.geometry.attributes.position.needsUpdate = true;
    this.updateBody();
    this.dirty = true;
  }

  // The mesh nearest the frame, if one is within mesh_step frames.
  updateBody() {
    const d = this.data;
    if (!this.body) return;
    const t = d.frame[this.frame];
    let best = -1;
    for (let lo = 0, hi = d.mesh_frame.length - 1; lo <= hi;) {
      const mid = (lo + hi) >> 1;
      if (d.mesh_frame[mid] <= t) { best = mid; lo = mid + 1; } else hi = mid - 1;
    }
    if (best + 1 < d.mesh_frame.length && (best < 0 || d.mesh_frame[best + 1] - t < t - d.mesh_frame[best])) best++;
    const near = best >= 0 && Math.abs(d.mesh_frame[best] - t) <= d.mesh_step;
    this.body.visible = near && $('show-mesh').checked;
    this.status.dataset.meshFrame = near ? String(d.mesh_frame[best]) : '';
    if (!near || best === this.bodyMesh) return;
    this.bodyMesh = best;
    const n = 3 * this.meshVertexCount;
    const scale = d.mesh_unit === 'mm' ? 0.001 : 1;
    const position = this.body.geometry.attributes.position;
    for (let i = 0; i < n; i++) position.array[i] = d.mesh_vertices[best * n + i] * scale;
    position.needsUpdate = true;
    this.body.geometry.computeVertexNormals();
  }

  // `#timeline=<fraction>`: a mouse click on the timeline strip at that
  // fraction of its width (to the element under the point, as a user's).
  clickTimeline(fraction) {
    const r = $('timeline').getBoundingClientRect();
    const x = r.left + Math.max(0, Math.min(1, fraction)) * r.width, y = r.top + r.height / 2;
    const under = document.elementFromPoint(x, y);
    if (!under) return;
    under.dispatchEvent(new MouseEvent('mousedown', { clientX: x, clientY: y, bubbles: true }));
    window.dispatchEvent(new MouseEvent('mouseup', { clientX: x, clientY: y }));
  }

  // `#hover=error|wrong|ghost|missed|<point index>`: hovers the first such point
  // of the frame through a real mouse event, as a user would (for scripts:
  // the tooltip text lands in data-hover).
  hoverPoint(which) {
    const d = this.data;
    const kinds = { error: [STATUS.WRONG, STATUS.GHOST, STATUS.MISSED], wrong: [STATUS.WRONG], ghost: [STATUS.GHOST], missed: [STATUS.MISSED] };
    const wanted = kinds[which];
    let target = -1;
    for (let i = d.offset[this.frame]; i < d.offset[this.frame + 1]; i++) {
      const hit = wanted === undefined ? i - d.offset[this.frame] === Number(which) : d.has_truth && wanted.includes(d.status[i]);
      if (hit) { target = i; break; }
    }
    if (target < 0) { this.status.dataset.hover = ''; return; }
    this.resize();
    this.camera.updateMatrixWorld();
    const v = new THREE.Vector3(d.position[3 * target], d.position[3 * target + 1], d.position[3 * target + 2]).project(this.camera);
    const r = $('canvas').getBoundingClientRect();
    const x = r.left + (v.x * 0.5 + 0.5) * r.width, y = r.top + (-v.y * 0.5 + 0.5) * r.height;
    // To whatever is on top there, as the browser would (an overlay that
    // hides the canvas from the mouse fails this).
    const under = document.elementFromPoint(x, y);
    if (under) under.dispatchEvent(new MouseEvent('mousemove', { clientX: x, clientY: y, bubbles: true }));
    this.status.dataset.hover = $('tooltip').hidden ? '' : $('tooltip').textContent;
  }

  hover(e) {
    const d = this.data;
    const canvas = $('canvas');
    const r = canvas.getBoundingClientRect();
    const mx = e.clientX - r.left, my = e.clientY - r.top;
    let best = -1, bestDist = 12 * 12;
    const v = new THREE.Vector3();
    for (const i of this.shown || []) {
      v.set(d.position[3 * i], d.position[3 * i + 1], d.position[3 * i + 2]).project(this.camera);
      if (v.z > 1) continue;
      const sx = (v.x * 0.5 + 0.5) * r.width, sy = (-v.y * 0.5 + 0.5) * r.height;
      const dist = (sx - mx) ** 2 + (sy - my) ** 2;
      if (dist < bestDist) { bestDist = dist; best = i; }
    }
    const tip = $('tooltip');
    if (best < 0) { tip.hidden = true; return; }
    const name = (id) => (id === d.nullId ? 'null' : id === d.nullId + 1 ? '(no ground truth point)' : d.labels[id]);
    const lines = [`label       ${name(d.label[best])}`];
    if (d.has_truth) {
      lines.push(`true label  ${name(d.truth[best])}`);
      lines.push(`status      ${['no ground truth', 'correct', 'WRONG', 'ghost labelled as marker', 'missed (labelled null)'][d.status[best]]}`);
    }
    if (d.has_confidence) {
      const c = d.confidence[best];
      lines.push(`confidence  ${c === UNKNOWN_CONFIDENCE ? 'n/a' : (c / 65534).toFixed(3)}`);
    }
    lines.push(`trajectory  ${d.track[best]}`);
    lines.push(`position    ${[0, 1, 2].map((a) => (1000 * d.position[3 * best + a]).toFixed(1)).join(', ')} mm`);
    tip.textContent = lines.join('\n');
    tip.style.left = `${mx + 14}px`;
    tip.style.top = `${my + 10}px`;
    tip.hidden = false;
  }

  buildLegend() {
    const d = this.data;
    const legend = $('legend');
    legend.innerHTML = '';
    this.legendCounts = {};
    const row = (color, text, hollow = false, key = null) => {
      const div = document.createElement('div');
      div.className = 'legend-row';
      const sw = document.createElement('span');
      sw.className = hollow ? 'swatch hollow' : 'swatch';
      sw.style.background = `#${color.getHexString()}`;
      const label = document.createElement('span');
      label.textContent = text;
      div.append(sw, label);
      if (key) {
        const n = document.createElement('span');
        n.className = 'legend-count';
        n.title = 'in this frame';
        div.append(n);
        this.legendCounts[key] = n;
      }
      legend.append(div);
    };
    if (this.mode === 'correctness' && d.has_truth) {
      row(STATUS_COLORS[STATUS.CORRECT], 'correct marker', false, 'correctMarker');
      row(REJECTED_GHOST_COLOR, 'ghost labelled null (correct)', false, 'rejected');
      row(STATUS_COLORS[STATUS.WRONG], 'wrong label', false, 'wrong');
      row(STATUS_COLORS[STATUS.GHOST], 'ghost labelled as a marker', false, 'ghost');
      row(STATUS_COLORS[STATUS.MISSED], 'missed: marker labelled null', true, 'missed');
      row(STATUS_COLORS[STATUS.NO_TRUTH], 'no ground-truth point', false, 'noTruth');
    } else if (this.mode === 'confidence' && d.has_confidence) {
      const g = document.createElement('div');
      g.className = 'gradient';
      g.style.background = `linear-gradient(to right, #${heatColor(0).getHexString()}, #${heatColor(0.5).getHexString()}, #${heatColor(1).getHexString()})`;
      legend.append(g);
      const scale = document.createElement('div');
      scale.className = 'legend-row';
      scale.innerHTML = '<span>0</span><span style="margin:auto">confidence</span><span>1</span>';
      legend.append(scale);
      row(NULL_COLOR, 'no confidence');
    } else {
      d.labels.forEach((name, i) => row(this.labelColors[i], name));
      row(NULL_COLOR, 'null (unlabelled)');
    }
  }

  // Per pixel column: the worst frame (accuracy or confidence), or points.
  drawTimeline() {
    const d = this.data;
    const canvas = $('timeline');
    const width = Math.max(canvas.clientWidth, 100);
    canvas.width = width;
    const h = canvas.height;
    const ctx = canvas.getContext('2d');
    ctx.clearRect(0, 0, width, h);
    // Accuracy and confidence: a spike per bad frame, its height the shortfall
    // from 1 (full height at FULL_SCALE or more), its colour the value (heat);
    // a thin green line where every frame of the pixel is perfect.
    const FULL_SCALE = 0.25;
    let values, label, count = false, hi = 1;
    if (d.has_truth) {
      values = d.accuracy;
      label = `per-frame accuracy: spike height = 1 − accuracy of the worst frame under the pixel (full height: ≥ ${100 * FULL_SCALE}% wrong); click to jump`;
    } else if (d.has_confidence) {
      values = d.confidence_mean;
      label = `per-frame mean confidence: spike height = 1 − the lowest under the pixel (full height: ≤ ${1 - FULL_SCALE}); click to jump`;
    } else {
      count = true;
      values = new Float32Array(d.num_frames);
      for (let f = 0; f < d.num_frames; f++) { values[f] = d.offset[f + 1] - d.offset[f]; hi = Math.max(hi, values[f]); }
      label = 'points per frame; click to jump';
    }
    for (let x = 0; x < width; x++) {
      const f0 = Math.floor((x / width) * d.num_frames);
      const f1 = Math.max(f0 + 1, Math.floor(((x + 1) / width) * d.num_frames));
      let worst = Infinity;
      for (let f = f0; f < f1 && f < d.num_frames; f++) if (Number.isFinite(values[f])) worst = Math.min(worst, values[f]);
      if (!Number.isFinite(worst)) continue;
      if (count) {
        const bar = Math.max(2, Math.round((worst / hi) * (h - 2)));
        ctx.fillStyle = '#6fa8dc';
        ctx.fillRect(x, h - bar, 1, bar);
        continue;
      }
      const shortfall = Math.min(1, (1 - worst) / FULL_SCALE);
      ctx.fillStyle = `#${heatColor(1 - shortfall).getHexString()}`;
      const bar = worst >= 1 ? 2 : Math.max(3, Math.round(shortfall * (h - 2)));
      ctx.fillRect(x, h - bar, 1, bar);
    }
    this.timelineImage = ctx.getImageData(0, 0, width, h);
    $('timeline-label').textContent = label;
    this.drawCursor();
  }

  drawCursor() {
    if (!this.timelineImage) return;
    const canvas = $('timeline');
    const ctx = canvas.getContext('2d');
    ctx.putImageData(this.timelineImage, 0, 0);
    const x = Math.floor(((this.frame + 0.5) / this.data.num_frames) * canvas.width);
    ctx.fillStyle = '#ffffff';
    ctx.fillRect(x, 0, 1, canvas.height);
  }

  tick(now) {
    const dt = Math.min((now - this.last) / 1000, 0.25);
    this.last = now;
    if (this.playing && this.data.num_frames > 1) {
      this.accum += (dt * this.speed * this.data.frame_rate) / this.data.frame_step;
      if (this.accum >= 1) {
        const steps = Math.floor(this.accum);
        this.accum -= steps;
        this.seek((this.frame + steps) % this.data.num_frames);
      }
    }
    // Render only when something changed (a frame, the camera, the size).
    if (this.renderer && this.dirty) {
      this.renderer.render(this.scene, this.camera);
      this.dirty = false;
    }
    requestAnimationFrame((t) => this.tick(t));
  }
}

function main() {
  const status = $('status');
  try {
    const data = decodeViewData($('soma-view-data').textContent);
    window.somaView = new Viewer(data);
  } catch (e) {
    status.dataset.error = e.message;
    status.textContent = `error: ${e.message}`;
    const m = $('message');
    m.textContent = e.message;
    m.hidden = false;
  }
}

main();
