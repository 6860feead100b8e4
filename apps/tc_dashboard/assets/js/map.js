// The live 2D view: the world (walls, rooms, doors, obstacles, areas, an
// occupancy grid), beacons and waypoints, and for each robot its pose and
// footprint (true and estimated, with the estimate's covariance and the
// localizer's particles), the map it learned (obstacles it sensed
// included), laser and sonar readings, the Local Perceptual Space, the
// planned path and goal, and the people walking in a simulated world. Wheel to zoom, drag to pan, click to send the selected robot a
// goal (a waypoint when the click is on one), click a robot to select it.
//
// World coordinates are metres, x east, y north (REP-103); the view keeps
// the world point at the canvas centre and a scale in CSS pixels per metre.
//
// It draws from a source: the live store, or another object that reads
// alike (get(key), robots, selected, world), such as the black box's
// timeline (timeline.js) showing one past instant with this same code.

import { obj, pt, pose3, PALETTE } from './util.js';

const TAU = Math.PI * 2;

export const LAYERS = {
  grid: 'Occupancy grid',
  learned: 'Learned map',
  particles: 'Particles',
  metric: 'Metric grid',
  laser: 'Laser',
  sonar: 'Sonar',
  lps: 'LPS',
  path: 'Planned path',
  estimate: 'Pose estimate',
  beacons: 'Beacons',
  waypoints: 'Waypoints',
  labels: 'Labels',
  walkers: 'Walkers',
};

// more robots than this: only the selected one is labelled (a hundred
// labels hide the map and cost a text measure each per frame)
const LABELLED_ROBOTS = 20;

export class MapView {
  /**
   * @param {HTMLCanvasElement} canvas
   * @param {import('./store.js').Store} store
   */
  constructor(canvas, store, { onGoal, onSelect, onCursor } = {}) {
    this.canvas = canvas;
    this.ctx = canvas.getContext('2d', { alpha: false });
    /** the live store: its events, the robots' colours, the goals */
    this.live = store;
    /** what is drawn: the live store, or a replay (setSource) */
    this.store = store;
    this.onGoal = onGoal;
    this.onSelect = onSelect;
    this.onCursor = onCursor;
    this.scale = 40;
    this.cx = 0;
    this.cy = 0;
    this.fitted = false;
    /** whether the user zoomed or panned (then a resize keeps the view) */
    this.userMoved = false;
    this.follow = false;
    this.goalMode = true;
    this.layers = Object.fromEntries(Object.keys(LAYERS).map((k) => [k, true]));
    this.dirty = false;
    this.renders = 0;
    this.renderFps = 0;
    this._renderTimes = [];
    /** robot id → [sx, sy] where it was drawn last (CSS pixels), for tests and hit-testing */
    this.drawn = {};
    this.goalMarker = null;
    this._gridImage = null;
    /** robot id → {version, canvas} of its learned map, drawn once per version */
    this._learned = {};
    this._static = null;
    this._staticKey = '';
    this._bindInput();
    this._resize();
    new ResizeObserver(() => this._resize()).observe(canvas.parentElement);
    store.on('world', () => {
      this._gridImage = null;
      this._staticKey = '';
      this.fitted = false;
      this.invalidate();
    });
    store.on('telemetry', () => this.invalidate());
    store.on('select', () => this.invalidate());
  }

  /** Draws from `source` (null: the live store again), e.g. the black box's timeline. */
  setSource(source) {
    this.store = source || this.live;
    // learned maps are cached per robot and version: not across sources
    this._learned = {};
    this.invalidate();
  }

  /** Whether a replay is drawn, not the live store. */
  get replaying() {
    return this.store !== this.live;
  }

  // Asks for one draw in the next animation frame. No frame is requested
  // while nothing changed: an idle page costs the browser nothing.
  invalidate() {
    if (this.dirty) return;
    this.dirty = true;
    requestAnimationFrame(() => {
      this.dirty = false;
      this.draw();
    });
  }

  // ---- view ----------------------------------------------------------------

  _resize() {
    const r = this.canvas.parentElement.getBoundingClientRect();
    this.width = Math.max(1, r.width);
    this.height = Math.max(1, r.height);
    this.dpr = window.devicePixelRatio || 1;
    this.canvas.width = Math.round(this.width * this.dpr);
    this.canvas.height = Math.round(this.height * this.dpr);
    this.canvas.style.width = `${this.width}px`;
    this.canvas.style.height = `${this.height}px`;
    this._staticKey = '';
    if (!this.fitted || !this.userMoved) this.fit();
    this.invalidate();
  }

  worldToScreen(x, y) {
    return [(x - this.cx) * this.scale + this.width / 2, this.height / 2 - (y - this.cy) * this.scale];
  }

  screenToWorld(sx, sy) {
    return [(sx - this.width / 2) / this.scale + this.cx, (this.height / 2 - sy) / this.scale + this.cy];
  }

  /** The world's bounds [xmin, ymin, xmax, ymax], from its geometry, grid and the robots. */
  bounds() {
    const xs = [];
    const ys = [];
    const add = (p) => {
      if (p) {
        xs.push(p[0]);
        ys.push(p[1]);
      }
    };
    const w = this.store.world;
    if (w) {
      for (const seg of w.walls || []) seg.forEach((p) => add(pt(p)));
      for (const kind of ['rooms', 'corridors', 'obstacles', 'areas']) {
        for (const r of w[kind] || []) (obj(r)?.polygon || []).forEach((p) => add(pt(p)));
      }
      for (const kind of ['beacons', 'waypoints']) for (const b of w[kind] || []) add(pt(obj(b)?.at));
      const g = obj(w.grid);
      if (g && g.width) {
        const o = pose3(g.origin) || [0, 0, 0];
        const grid = this._gridCanvas(g);
        // the known part of the map (not the unknown margin around it)
        const k = grid && grid.known && !o[2] ? grid.known : [0, 0, g.width, g.height];
        add([o[0] + k[0] * g.resolution, o[1] + k[1] * g.resolution]);
        add([o[0] + k[2] * g.resolution, o[1] + k[3] * g.resolution]);
      }
    }
    for (const id of this.store.robots) {
      const p = this.robotPose(id);
      if (p) add(p);
    }
    if (!xs.length) return null;
    return [Math.min(...xs), Math.min(...ys), Math.max(...xs), Math.max(...ys)];
  }

  fit() {
    const b = this.bounds();
    if (!b) return;
    const [x0, y0, x1, y1] = b;
    const w = Math.max(x1 - x0, 1);
    const h = Math.max(y1 - y0, 1);
    this.scale = Math.max(2, Math.min((this.width - 40) / w, (this.height - 40) / h));
    this.cx = (x0 + x1) / 2;
    this.cy = (y0 + y1) / 2;
    this.fitted = true;
    this.userMoved = false;
    this._staticKey = '';
    this.invalidate();
  }

  zoomAt(factor, sx = this.width / 2, sy = this.height / 2) {
    const [wx, wy] = this.screenToWorld(sx, sy);
    this.scale = Math.min(2000, Math.max(1, this.scale * factor));
    this.userMoved = true;
    // keep the world point under the cursor where it was
    this.cx = wx - (sx - this.width / 2) / this.scale;
    this.cy = wy - (this.height / 2 - sy) / this.scale;
    this.invalidate();
  }

  _bindInput() {
    const c = this.canvas;
    let drag = null;
    c.addEventListener('wheel', (e) => {
      e.preventDefault();
      const r = c.getBoundingClientRect();
      this.zoomAt(Math.exp(-e.deltaY * 0.0015), e.clientX - r.left, e.clientY - r.top);
    }, { passive: false });
    c.addEventListener('pointerdown', (e) => {
      if (e.button !== 0 && e.button !== 1) return;
      c.setPointerCapture(e.pointerId);
      drag = { x: e.clientX, y: e.clientY, cx: this.cx, cy: this.cy, moved: false, button: e.button };
    });
    c.addEventListener('pointermove', (e) => {
      const r = c.getBoundingClientRect();
      const [wx, wy] = this.screenToWorld(e.clientX - r.left, e.clientY - r.top);
      if (this.onCursor) this.onCursor(wx, wy);
      if (!drag) return;
      const dx = e.clientX - drag.x;
      const dy = e.clientY - drag.y;
      if (!drag.moved && Math.hypot(dx, dy) < 4) return;
      drag.moved = true;
      this.userMoved = true;
      this.follow = false;
      c.classList.add('panning');
      this.cx = drag.cx - dx / this.scale;
      this.cy = drag.cy + dy / this.scale;
      this.invalidate();
    });
    const up = (e) => {
      if (!drag) return;
      const d = drag;
      drag = null;
      c.classList.remove('panning');
      if (d.moved || d.button !== 0 || e.type === 'pointercancel') return;
      const r = c.getBoundingClientRect();
      this._click(e.clientX - r.left, e.clientY - r.top);
    };
    c.addEventListener('pointerup', up);
    c.addEventListener('pointercancel', up);
    c.addEventListener('dblclick', (e) => e.preventDefault());
  }

  _click(sx, sy) {
    // a robot under the cursor: select it
    for (const [id, [rx, ry, rr]] of Object.entries(this.drawn)) {
      if (Math.hypot(sx - rx, sy - ry) <= Math.max(rr, 8)) {
        if (id !== this.store.selected && this.onSelect) this.onSelect(id);
        return;
      }
    }
    // a replay is the past: no goals sent from it
    if (!this.goalMode || !this.onGoal || this.replaying) return;
    // a waypoint under the cursor: go there by name
    const w = this.store.world;
    for (const wp of (w && w.waypoints) || []) {
      const o = obj(wp);
      const p = o && pt(o.at);
      if (!p) continue;
      const [px, py] = this.worldToScreen(p[0], p[1]);
      if (Math.hypot(sx - px, sy - py) <= 9) {
        this.goalMarker = { at: p, name: String(o.name), t: performance.now() };
        this.onGoal({ waypoint: String(o.name) }, p);
        this.invalidate();
        return;
      }
    }
    const [x, y] = this.screenToWorld(sx, sy);
    this.goalMarker = { at: [x, y], t: performance.now() };
    this.onGoal({ x, y }, [x, y]);
    this.invalidate();
  }

  // ---- robots ----------------------------------------------------------------

  /** The pose a robot is drawn at: the simulator's truth, else the estimate, else odometry. */
  robotPose(id) {
    const s = this.store;
    for (const tag of ['sim_pose', 'pose', 'odom']) {
      const v = s.get(`${tag}/${id}`);
      const p = v && pose3(v.pose);
      if (p) return p;
    }
    return null;
  }

  robotColor(id) {
    // the live robots' order: a robot keeps its colour in a replay
    const i = this.live.robots.indexOf(id);
    return PALETTE[(i < 0 ? 0 : i) % PALETTE.length];
  }

  // ---- drawing -----------------------------------------------------------------

  draw() {
    this.dirty = false;
    const now = performance.now();
    this._renderTimes.push(now);
    while (this._renderTimes.length && now - this._renderTimes[0] > 1000) this._renderTimes.shift();
    this.renderFps = this._renderTimes.length;
    this.renders += 1;

    if (!this.fitted && this.width > 1) this.fit();
    if (this.follow && this.store.selected) {
      const p = this.robotPose(this.store.selected);
      if (p) {
        this.cx = p[0];
        this.cy = p[1];
      }
    }

    const ctx = this.ctx;
    ctx.setTransform(this.dpr, 0, 0, this.dpr, 0, 0);
    this._drawStatic(ctx);
    if (this.layers.learned) for (const id of this.store.robots) this._drawLearned(ctx, id);

    const drawn = {};
    const robots = this.store.robots;
    // the selected robot last, on top
    const order = robots.filter((r) => r !== this.store.selected);
    if (this.store.selected) order.push(this.store.selected);
    for (const id of order) {
      const p = this.robotPose(id);
      if (!p) continue;
      this._drawRobotOverlays(ctx, id, p);
    }
    this.walkersDrawn = this.layers.walkers ? this._drawWalkers(ctx) : 0;
    for (const id of order) {
      const p = this.robotPose(id);
      if (!p) continue;
      drawn[id] = this._drawRobot(ctx, id, p);
    }
    this.drawn = drawn;
    this._drawGoalMarker(ctx, now);
    this._drawScaleBar(ctx);
  }

  // Everything that moves only with the view: cached in an offscreen canvas.
  _drawStatic(ctx) {
    const w = this.store.world;
    const key = [this.scale, this.cx, this.cy, this.width, this.height, this.dpr,
      this.layers.grid, this.layers.metric, this.layers.beacons, this.layers.waypoints, this.layers.labels].join(':');
    if (key !== this._staticKey || !this._static) {
      if (!this._static) this._static = document.createElement('canvas');
      const off = this._static;
      off.width = this.canvas.width;
      off.height = this.canvas.height;
      const o = off.getContext('2d');
      o.setTransform(this.dpr, 0, 0, this.dpr, 0, 0);
      o.fillStyle = '#0d1117';
      o.fillRect(0, 0, this.width, this.height);
      if (w && this.layers.grid) this._drawOccupancy(o, w);
      if (this.layers.metric) this._drawMetricGrid(o);
      if (w) this._drawWorld(o, w);
      this._staticKey = key;
    }
    ctx.save();
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.drawImage(this._static, 0, 0);
    ctx.restore();
  }

  _drawMetricGrid(ctx) {
    // 1 m lines, or 10 m / 0.1 m as the zoom asks
    let step = 1;
    while (step * this.scale < 25) step *= 5;
    while (step * this.scale > 200) step /= 5;
    const [x0, y0] = this.screenToWorld(0, this.height);
    const [x1, y1] = this.screenToWorld(this.width, 0);
    ctx.lineWidth = 1;
    ctx.strokeStyle = 'rgba(139,148,158,0.08)';
    ctx.beginPath();
    for (let x = Math.ceil(x0 / step) * step; x <= x1; x += step) {
      const [sx] = this.worldToScreen(x, 0);
      ctx.moveTo(Math.round(sx) + 0.5, 0);
      ctx.lineTo(Math.round(sx) + 0.5, this.height);
    }
    for (let y = Math.ceil(y0 / step) * step; y <= y1; y += step) {
      const [, sy] = this.worldToScreen(0, y);
      ctx.moveTo(0, Math.round(sy) + 0.5);
      ctx.lineTo(this.width, Math.round(sy) + 0.5);
    }
    ctx.stroke();
    // the origin's axes: x red, y green (as RViz)
    const [ox, oy] = this.worldToScreen(0, 0);
    ctx.lineWidth = 2;
    ctx.strokeStyle = 'rgba(239,83,80,0.7)';
    ctx.beginPath();
    ctx.moveTo(ox, oy);
    ctx.lineTo(ox + 24, oy);
    ctx.stroke();
    ctx.strokeStyle = 'rgba(102,187,106,0.7)';
    ctx.beginPath();
    ctx.moveTo(ox, oy);
    ctx.lineTo(ox, oy - 24);
    ctx.stroke();
  }

  _gridCanvas(g) {
    if (this._gridImage) return this._gridImage;
    const width = g.width | 0;
    const height = g.height | 0;
    // PROTOCOL.md calls the cells `cells`; the WDF struct (as sent) `data`
    const cells = typeof g.cells === 'string' ? g.cells : g.data;
    if (!width || !height || typeof cells !== 'string') return null;
    // base64, as the protocol says; but the server's JSON sends a binary
    // that happens to be valid UTF-8 (a map with no unknown cell) as is
    let bin;
    if (cells.length === width * height) bin = cells;
    else {
      try {
        bin = atob(cells);
      } catch (e) {
        console.warn('dashboard: the occupancy grid is neither base64 nor raw cells', e);
        this._gridImage = null;
        return null;
      }
    }
    const img = new ImageData(width, height);
    const d = img.data;
    // the known cells' bounds, in cells from the bottom left: [c0, r0, c1, r1)
    let c0 = width;
    let r0 = height;
    let c1 = 0;
    let r1 = 0;
    for (let r = 0; r < height; r++) {
      // cells are row-major from the bottom row; images from the top
      const row = height - 1 - r;
      for (let c = 0; c < width; c++) {
        const i = r * width + c;
        if (i >= bin.length) break;
        let v = bin.charCodeAt(i);
        if (v > 127) v -= 256;
        const k = (row * width + c) * 4;
        if (v < 0) {
          d[k] = 22; d[k + 1] = 27; d[k + 2] = 34; d[k + 3] = 255;
        } else {
          if (c < c0) c0 = c;
          if (c >= c1) c1 = c + 1;
          if (r < r0) r0 = r;
          if (r >= r1) r1 = r + 1;
          // free: dark blue-grey; occupied: light
          const t = Math.min(v, 100) / 100;
          d[k] = 30 + t * 170;
          d[k + 1] = 38 + t * 170;
          d[k + 2] = 48 + t * 170;
          d[k + 3] = 255;
        }
      }
    }
    const cv = document.createElement('canvas');
    cv.width = width;
    cv.height = height;
    cv.getContext('2d').putImageData(img, 0, 0);
    cv.known = c1 > c0 && r1 > r0 ? [c0, r0, c1, r1] : null;
    this._gridImage = cv;
    return cv;
  }

  _drawOccupancy(ctx, w) {
    const g = obj(w.grid);
    if (!g) return;
    const img = this._gridCanvas(g);
    if (!img) return;
    const [ox, oy, oth] = pose3(g.origin) || [0, 0, 0];
    const res = g.resolution;
    const [sx, sy] = this.worldToScreen(ox, oy);
    ctx.save();
    ctx.imageSmoothingEnabled = false;
    ctx.translate(sx, sy);
    ctx.rotate(-oth);
    const s = res * this.scale;
    ctx.scale(s, s);
    ctx.drawImage(img, 0, -img.height);
    ctx.restore();
  }

  // A robot's learned map (the map builder's occupancy grid): unknown cells
  // left clear, free ones a faint teal, occupied ones orange by degree.
  _learnedCanvas(id, m) {
    const cached = this._learned[id];
    const version = m.version ?? 0;
    if (cached && cached.version === version) return cached.canvas;
    const width = m.width | 0;
    const height = m.height | 0;
    if (!width || !height || typeof m.data !== 'string') return null;
    let bin;
    try {
      bin = atob(m.data);
    } catch (e) {
      console.warn('dashboard: a learned map whose cells are not base64', e);
      return null;
    }
    const img = new ImageData(width, height);
    const d = img.data;
    for (let r = 0; r < height; r++) {
      const row = height - 1 - r;
      for (let c = 0; c < width; c++) {
        const i = r * width + c;
        if (i >= bin.length) break;
        let v = bin.charCodeAt(i);
        if (v > 127) v -= 256;
        if (v < 0) continue;
        const k = (row * width + c) * 4;
        if (v >= 50) {
          d[k] = 255; d[k + 1] = 166; d[k + 2] = 87; d[k + 3] = 110 + v;
        } else {
          d[k] = 56; d[k + 1] = 139; d[k + 2] = 153; d[k + 3] = 40 + v;
        }
      }
    }
    const cv = document.createElement('canvas');
    cv.width = width;
    cv.height = height;
    cv.getContext('2d').putImageData(img, 0, 0);
    this._learned[id] = { version, canvas: cv };
    return cv;
  }

  _drawLearned(ctx, id) {
    const m = obj(this.store.get(`map/${id}`));
    if (!m) return;
    const img = this._learnedCanvas(id, m);
    if (!img) return;
    const [ox, oy] = pt(m.origin) || [0, 0];
    const [sx, sy] = this.worldToScreen(ox, oy);
    const s = m.resolution * this.scale;
    ctx.save();
    ctx.imageSmoothingEnabled = false;
    ctx.translate(sx, sy);
    ctx.scale(s, s);
    ctx.drawImage(img, 0, -img.height);
    ctx.restore();
  }

  _poly(ctx, points) {
    ctx.beginPath();
    points.forEach((p, i) => {
      const [sx, sy] = this.worldToScreen(p[0], p[1]);
      if (i === 0) ctx.moveTo(sx, sy);
      else ctx.lineTo(sx, sy);
    });
    ctx.closePath();
  }

  _drawWorld(ctx, w) {
    const polys = (list) => (list || []).map(obj).filter((o) => o && Array.isArray(o.polygon));
    // rooms and corridors: faint floors with their names
    for (const [kind, fill] of [['corridors', 'rgba(88,166,255,0.035)'], ['rooms', 'rgba(88,166,255,0.06)']]) {
      for (const r of polys(w[kind])) {
        this._poly(ctx, r.polygon.map(pt));
        ctx.fillStyle = fill;
        ctx.fill();
      }
    }
    // areas: tinted by kind
    for (const a of polys(w.areas)) {
      this._poly(ctx, a.polygon.map(pt));
      const forbidden = String(a.kind) === 'forbidden';
      ctx.fillStyle = forbidden ? 'rgba(248,81,73,0.12)' : 'rgba(63,185,80,0.12)';
      ctx.strokeStyle = forbidden ? 'rgba(248,81,73,0.5)' : 'rgba(63,185,80,0.5)';
      ctx.setLineDash([4, 4]);
      ctx.lineWidth = 1;
      ctx.fill();
      ctx.stroke();
      ctx.setLineDash([]);
    }
    // obstacles: solid
    for (const o of polys(w.obstacles)) {
      this._poly(ctx, o.polygon.map(pt));
      ctx.fillStyle = '#3d444d';
      ctx.fill();
      ctx.strokeStyle = '#8b949e';
      ctx.lineWidth = 1;
      ctx.stroke();
    }
    // walls
    ctx.strokeStyle = '#c9d1d9';
    ctx.lineWidth = Math.max(1.5, Math.min(4, 0.06 * this.scale));
    ctx.lineCap = 'round';
    ctx.beginPath();
    for (const seg of w.walls || []) {
      const a = pt(seg[0]);
      const b = pt(seg[1]);
      if (!a || !b) continue;
      const [ax, ay] = this.worldToScreen(a[0], a[1]);
      const [bx, by] = this.worldToScreen(b[0], b[1]);
      ctx.moveTo(ax, ay);
      ctx.lineTo(bx, by);
    }
    ctx.stroke();
    // doors: green dashed when open, red when shut
    for (const d of (w.doors || []).map(obj)) {
      if (!d) continue;
      const a = pt(d.from);
      const b = pt(d.to);
      if (!a || !b) continue;
      const open = d.open !== false;
      const [ax, ay] = this.worldToScreen(a[0], a[1]);
      const [bx, by] = this.worldToScreen(b[0], b[1]);
      ctx.strokeStyle = open ? 'rgba(63,185,80,0.8)' : '#f85149';
      ctx.lineWidth = open ? 1.5 : Math.max(2, Math.min(5, 0.08 * this.scale));
      ctx.setLineDash(open ? [3, 3] : []);
      ctx.beginPath();
      ctx.moveTo(ax, ay);
      ctx.lineTo(bx, by);
      ctx.stroke();
      ctx.setLineDash([]);
    }
    if (this.layers.labels) {
      ctx.font = '600 11px system-ui, sans-serif';
      ctx.fillStyle = 'rgba(139,148,158,0.55)';
      ctx.textAlign = 'center';
      ctx.textBaseline = 'middle';
      for (const r of [...polys(w.rooms), ...polys(w.corridors)]) {
        const pts = r.polygon.map(pt);
        const cx = pts.reduce((s, p) => s + p[0], 0) / pts.length;
        const cy = pts.reduce((s, p) => s + p[1], 0) / pts.length;
        const [sx, sy] = this.worldToScreen(cx, cy);
        ctx.fillText(String(r.name || '').toUpperCase(), sx, sy);
      }
    }
    if (this.layers.beacons) {
      for (const b of (w.beacons || []).map(obj)) {
        const p = b && pt(b.at);
        if (!p) continue;
        const [sx, sy] = this.worldToScreen(p[0], p[1]);
        ctx.fillStyle = '#e3b341';
        ctx.beginPath();
        ctx.moveTo(sx, sy - 6);
        ctx.lineTo(sx + 5, sy + 4);
        ctx.lineTo(sx - 5, sy + 4);
        ctx.closePath();
        ctx.fill();
        if (this.layers.labels) {
          ctx.font = '10px ui-monospace, monospace';
          ctx.fillStyle = 'rgba(227,179,65,0.8)';
          ctx.textAlign = 'left';
          ctx.fillText(String(b.name), sx + 7, sy);
        }
      }
    }
    if (this.layers.waypoints) {
      for (const wp of (w.waypoints || []).map(obj)) {
        const p = wp && pose3(wp.at);
        if (!p) continue;
        const [sx, sy] = this.worldToScreen(p[0], p[1]);
        ctx.strokeStyle = '#a371f7';
        ctx.fillStyle = 'rgba(163,113,247,0.25)';
        ctx.lineWidth = 1.5;
        ctx.beginPath();
        ctx.moveTo(sx, sy - 6);
        ctx.lineTo(sx + 6, sy);
        ctx.lineTo(sx, sy + 6);
        ctx.lineTo(sx - 6, sy);
        ctx.closePath();
        ctx.fill();
        ctx.stroke();
        if (Array.isArray(wp.at) && wp.at.length >= 3) {
          ctx.beginPath();
          ctx.moveTo(sx, sy);
          ctx.lineTo(sx + Math.cos(p[2]) * 12, sy - Math.sin(p[2]) * 12);
          ctx.stroke();
        }
        if (this.layers.labels) {
          ctx.font = '10px ui-monospace, monospace';
          ctx.fillStyle = 'rgba(163,113,247,0.9)';
          ctx.textAlign = 'left';
          ctx.textBaseline = 'middle';
          ctx.fillText(String(wp.name), sx + 8, sy);
        }
      }
    }
  }

  // the point (x, y) of a robot's frame, in the world, given its pose
  static _apply(p, x, y) {
    const c = Math.cos(p[2]);
    const s = Math.sin(p[2]);
    return [p[0] + c * x - s * y, p[1] + s * x + c * y];
  }

  _sensors(id) {
    const r = this.store.get(`robot/${id}`);
    const list = (r && Array.isArray(r.sensors) ? r.sensors : []).map(obj).filter(Boolean);
    if (list.length) return list;
    return [{ name: 'laser', type: 'laser' }, { name: 'sonar', type: 'sonar' }];
  }

  /** The people walking in a simulated world (`sim_walkers/<world>`): grey discs. Returns how many. */
  _drawWalkers(ctx) {
    const w = this.store.world;
    const v = w && this.store.get(`sim_walkers/${w.name}`);
    if (!v || !Array.isArray(v.walkers)) return 0;
    ctx.fillStyle = 'rgba(201,209,217,0.85)';
    ctx.strokeStyle = '#0d1117';
    ctx.lineWidth = 1;
    ctx.beginPath();
    let n = 0;
    for (const d of v.walkers) {
      if (!Array.isArray(d) || d.length < 2) continue;
      const [sx, sy] = this.worldToScreen(d[0], d[1]);
      const r = Math.max(3, (typeof d[2] === 'number' ? d[2] : 0.25) * this.scale);
      ctx.moveTo(sx + r, sy);
      ctx.arc(sx, sy, r, 0, TAU);
      n += 1;
    }
    ctx.fill();
    ctx.stroke();
    return n;
  }

  _radius(id) {
    const r = this.store.get(`robot/${id}`);
    const fp = r && obj(r.footprint);
    if (fp && typeof fp.radius === 'number') return fp.radius;
    return 0.2;
  }

  _drawRobotOverlays(ctx, id, p) {
    const s = this.store;
    const color = this.robotColor(id);
    const selected = id === s.selected;
    const radius = this._radius(id);

    if (this.layers.lps) {
      const lps = s.get(`lps/${id}`);
      if (lps && Array.isArray(lps.bins) && lps.bins.length) {
        const n = lps.bins.length;
        const range = lps.range || 5;
        ctx.beginPath();
        lps.bins.forEach((d, i) => {
          const a = -Math.PI + (i + 0.5) * (TAU / n);
          const r = Math.min(typeof d === 'number' ? d : range, range);
          const [wx, wy] = MapView._apply(p, r * Math.cos(a), r * Math.sin(a));
          const [sx, sy] = this.worldToScreen(wx, wy);
          if (i === 0) ctx.moveTo(sx, sy);
          else ctx.lineTo(sx, sy);
        });
        ctx.closePath();
        ctx.fillStyle = selected ? 'rgba(88,166,255,0.07)' : 'rgba(88,166,255,0.035)';
        ctx.strokeStyle = 'rgba(88,166,255,0.35)';
        ctx.lineWidth = 1;
        ctx.fill();
        ctx.stroke();
        // evidence (occupied degree) and extracted walls, robot frame
        if (selected && Array.isArray(lps.evidence)) {
          for (const e of lps.evidence) {
            if (!Array.isArray(e) || (e[2] || 0) < 0.3) continue;
            const [wx, wy] = MapView._apply(p, e[0], e[1]);
            const [sx, sy] = this.worldToScreen(wx, wy);
            ctx.fillStyle = `rgba(255,123,114,${Math.min(0.8, e[2])})`;
            ctx.fillRect(sx - 1.5, sy - 1.5, 3, 3);
          }
        }
        if (Array.isArray(lps.segments)) {
          ctx.strokeStyle = 'rgba(255,166,87,0.55)';
          ctx.lineWidth = 1.5;
          ctx.beginPath();
          for (const seg of lps.segments) {
            const a = pt(seg && seg[0]);
            const b = pt(seg && seg[1]);
            if (!a || !b) continue;
            const [ax, ay] = this.worldToScreen(...MapView._apply(p, a[0], a[1]));
            const [bx, by] = this.worldToScreen(...MapView._apply(p, b[0], b[1]));
            ctx.moveTo(ax, ay);
            ctx.lineTo(bx, by);
          }
          ctx.stroke();
        }
      }
    }

    for (const sensor of this._sensors(id)) {
      const type = String(sensor.type);
      const reading = s.get(`${sensor.name}/${id}`);
      if (!reading || !Array.isArray(reading.ranges)) continue;
      const sp = pose3(sensor.pose) || [0, 0, 0];
      if (type === 'laser' && this.layers.laser) this._drawLaser(ctx, p, sp, reading, selected);
      if (type === 'sonar' && this.layers.sonar) this._drawSonar(ctx, p, sensor, reading, radius, selected);
    }

    if (this.layers.beacons) {
      const det = s.get(`beacons/${id}`);
      const w = s.world;
      if (det && Array.isArray(det.detections) && w) {
        const byName = new Map((w.beacons || []).map(obj).filter(Boolean).map((b) => [String(b.name), pt(b.at)]));
        ctx.strokeStyle = 'rgba(227,179,65,0.35)';
        ctx.setLineDash([2, 4]);
        ctx.lineWidth = 1;
        ctx.beginPath();
        const [rx, ry] = this.worldToScreen(p[0], p[1]);
        for (const d of det.detections.map(obj)) {
          const b = d && byName.get(String(d.id));
          if (!b) continue;
          const [bx, by] = this.worldToScreen(b[0], b[1]);
          ctx.moveTo(rx, ry);
          ctx.lineTo(bx, by);
        }
        ctx.stroke();
        ctx.setLineDash([]);
      }
    }

    if (this.layers.path) {
      const plan = s.get(`plan/${id}`);
      if (plan) {
        const path = (Array.isArray(plan.path) ? plan.path : []).map(pt).filter(Boolean);
        if (path.length) {
          ctx.strokeStyle = color;
          ctx.globalAlpha = 0.85;
          ctx.lineWidth = 2;
          ctx.setLineDash([6, 4]);
          ctx.beginPath();
          const [rx, ry] = this.worldToScreen(p[0], p[1]);
          ctx.moveTo(rx, ry);
          for (const q of path) ctx.lineTo(...this.worldToScreen(q[0], q[1]));
          ctx.stroke();
          ctx.setLineDash([]);
          ctx.globalAlpha = 1;
        }
        const goal = pt(plan.goal);
        if (goal) this._drawFlag(ctx, goal, color);
      }
    }

    if (this.layers.particles) {
      const cloud = s.get(`particles/${id}`);
      const poses = cloud && Array.isArray(cloud.poses) ? cloud.poses : [];
      ctx.fillStyle = 'rgba(210,168,255,0.75)';
      for (const q of poses) {
        const e = pose3(q);
        if (!e) continue;
        const [qx, qy] = this.worldToScreen(e[0], e[1]);
        ctx.fillRect(qx - 1, qy - 1, 2, 2);
      }
    }

    if (this.layers.estimate) {
      const est = s.get(`pose/${id}`);
      const e = est && pose3(est.pose);
      if (e && s.get(`sim_pose/${id}`)) {
        const [ex, ey] = this.worldToScreen(e[0], e[1]);
        const cov = est.covariance;
        if (Array.isArray(cov) && Array.isArray(cov[0]) && Array.isArray(cov[1])) {
          // the 2σ ellipse of the position's covariance
          const a = cov[0][0];
          const b = cov[0][1];
          const d = cov[1][1];
          const tr = (a + d) / 2;
          const det = Math.sqrt(Math.max(0, ((a - d) / 2) ** 2 + b * b));
          const l1 = tr + det;
          const l2 = Math.max(0, tr - det);
          const ang = 0.5 * Math.atan2(2 * b, a - d);
          const r1 = Math.max(2, 2 * Math.sqrt(l1) * this.scale);
          const r2 = Math.max(2, 2 * Math.sqrt(l2) * this.scale);
          if (Number.isFinite(r1) && Number.isFinite(r2) && r1 < 5000) {
            ctx.strokeStyle = 'rgba(210,168,255,0.8)';
            ctx.fillStyle = 'rgba(210,168,255,0.08)';
            ctx.lineWidth = 1;
            ctx.beginPath();
            ctx.ellipse(ex, ey, r1, r2, -ang, 0, TAU);
            ctx.fill();
            ctx.stroke();
          }
        }
        ctx.strokeStyle = 'rgba(210,168,255,0.9)';
        ctx.setLineDash([3, 3]);
        ctx.lineWidth = 1.5;
        ctx.beginPath();
        ctx.arc(ex, ey, Math.max(3, radius * this.scale), 0, TAU);
        ctx.stroke();
        ctx.setLineDash([]);
        ctx.beginPath();
        ctx.moveTo(ex, ey);
        const hl = Math.max(8, radius * this.scale * 1.3);
        ctx.lineTo(ex + Math.cos(e[2]) * hl, ey - Math.sin(e[2]) * hl);
        ctx.stroke();
      }
    }
  }

  _drawLaser(ctx, p, sp, scan, selected) {
    const n = scan.ranges.length;
    const a0 = scan.angle_min ?? -Math.PI / 2;
    const inc = scan.angle_increment ?? (n > 1 ? ((scan.angle_max ?? Math.PI / 2) - a0) / (n - 1) : 0);
    const rmax = scan.range_max ?? Infinity;
    const origin = MapView._apply(p, sp[0], sp[1]);
    const th = p[2] + sp[2];
    const [ox, oy] = this.worldToScreen(origin[0], origin[1]);
    const c = Math.cos(th);
    const s = Math.sin(th);
    const pts = new Array(n);
    for (let i = 0; i < n; i++) {
      const r = scan.ranges[i];
      const a = a0 + i * inc;
      const rr = typeof r === 'number' && Number.isFinite(r) ? Math.min(r, rmax) : rmax;
      const lx = rr * Math.cos(a);
      const ly = rr * Math.sin(a);
      const wx = origin[0] + c * lx - s * ly;
      const wy = origin[1] + s * lx + c * ly;
      pts[i] = [...this.worldToScreen(wx, wy), typeof r === 'number' && r < rmax];
    }
    // the swept area (the selected robot's only: large fills cost), then the hits
    if (selected) {
      ctx.beginPath();
      ctx.moveTo(ox, oy);
      for (const q of pts) ctx.lineTo(q[0], q[1]);
      ctx.closePath();
      ctx.fillStyle = 'rgba(255,82,82,0.06)';
      ctx.fill();
    }
    ctx.fillStyle = '#ff5252';
    const size = this.scale > 60 ? 3 : 2;
    for (const q of pts) if (q[2]) ctx.fillRect(q[0] - size / 2, q[1] - size / 2, size, size);
  }

  _drawSonar(ctx, p, sensor, reading, radius, selected) {
    const n = reading.ranges.length;
    const fov = typeof sensor.fov === 'number' ? sensor.fov : 0.26;
    const range = pt(sensor.range);
    const rmax = reading.range_max ?? (range ? range[1] : 5);
    const headings = Array.isArray(reading.headings) && reading.headings.length === n
      ? reading.headings
      : Array.from({ length: n }, (_, i) => (i * TAU) / n);
    for (let i = 0; i < n; i++) {
      const r = reading.ranges[i];
      if (typeof r !== 'number') continue;
      const h = headings[i];
      const origin = MapView._apply(p, radius * 0.9 * Math.cos(h), radius * 0.9 * Math.sin(h));
      const [ox, oy] = this.worldToScreen(origin[0], origin[1]);
      const echo = r < rmax;
      const rr = Math.min(r, rmax) * this.scale;
      const a = p[2] + h;
      // a faint cone (the selected robot's only), and the echo as an arc at the range read
      const near = Math.max(0, Math.min(1, 1 - r / 1.5));
      const rgb = `${Math.round(100 + 155 * near)},${Math.round(200 - 120 * near)},255`;
      if (selected) {
        ctx.beginPath();
        ctx.moveTo(ox, oy);
        // canvas angles run clockwise (y down): negate
        ctx.arc(ox, oy, rr, -(a + fov / 2), -(a - fov / 2));
        ctx.closePath();
        ctx.fillStyle = `rgba(${rgb},${echo ? 0.05 + 0.1 * near : 0.015})`;
        ctx.fill();
      }
      if (echo) {
        ctx.beginPath();
        ctx.arc(ox, oy, rr, -(a + fov / 2), -(a - fov / 2));
        ctx.strokeStyle = `rgba(${rgb},0.7)`;
        ctx.lineWidth = 2;
        ctx.stroke();
      }
    }
  }

  _drawFlag(ctx, g, color) {
    const [sx, sy] = this.worldToScreen(g[0], g[1]);
    ctx.strokeStyle = color;
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.moveTo(sx, sy);
    ctx.lineTo(sx, sy - 18);
    ctx.stroke();
    ctx.fillStyle = color;
    ctx.beginPath();
    ctx.moveTo(sx, sy - 18);
    ctx.lineTo(sx + 11, sy - 14);
    ctx.lineTo(sx, sy - 10);
    ctx.closePath();
    ctx.fill();
    ctx.beginPath();
    ctx.arc(sx, sy, 3, 0, TAU);
    ctx.fill();
  }

  _drawRobot(ctx, id, p) {
    const s = this.store;
    const color = this.robotColor(id);
    const selected = id === s.selected;
    const robot = s.get(`robot/${id}`);
    const fp = robot && obj(robot.footprint);
    const [sx, sy] = this.worldToScreen(p[0], p[1]);
    const rpx = Math.max(5, this._radius(id) * this.scale);
    const mode = s.get(`control/${id}`)?.mode;

    // the halo: who drives it
    if (mode === 'estop' || mode === 'teleop') {
      ctx.beginPath();
      ctx.arc(sx, sy, rpx + 6, 0, TAU);
      ctx.strokeStyle = mode === 'estop' ? 'rgba(248,81,73,0.9)' : 'rgba(227,179,65,0.9)';
      ctx.lineWidth = 3;
      ctx.stroke();
    }
    if (selected) {
      ctx.beginPath();
      ctx.arc(sx, sy, rpx + 3, 0, TAU);
      ctx.strokeStyle = 'rgba(255,255,255,0.55)';
      ctx.lineWidth = 1;
      ctx.stroke();
    }

    ctx.fillStyle = color;
    ctx.strokeStyle = '#0d1117';
    ctx.lineWidth = 1.5;
    const polygon = fp && Array.isArray(fp.polygon) && fp.polygon.length > 2 ? fp.polygon.map(pt) : null;
    if (polygon) {
      ctx.beginPath();
      polygon.forEach((q, i) => {
        const [wx, wy] = MapView._apply(p, q[0], q[1]);
        const [qx, qy] = this.worldToScreen(wx, wy);
        if (i === 0) ctx.moveTo(qx, qy);
        else ctx.lineTo(qx, qy);
      });
      ctx.closePath();
    } else {
      ctx.beginPath();
      ctx.arc(sx, sy, rpx, 0, TAU);
    }
    ctx.globalAlpha = 0.9;
    ctx.fill();
    ctx.globalAlpha = 1;
    ctx.stroke();

    // the heading
    const hl = rpx * 1.35;
    ctx.strokeStyle = '#0d1117';
    ctx.lineWidth = 2.5;
    ctx.beginPath();
    ctx.moveTo(sx, sy);
    ctx.lineTo(sx + Math.cos(p[2]) * hl, sy - Math.sin(p[2]) * hl);
    ctx.stroke();
    ctx.strokeStyle = '#f0f6fc';
    ctx.lineWidth = 1.5;
    ctx.stroke();

    if (s.get(`bumper/${id}`)?.pressed) {
      ctx.strokeStyle = '#f85149';
      ctx.lineWidth = 3;
      ctx.beginPath();
      ctx.arc(sx, sy, rpx, p[2] * -1 - 1, p[2] * -1 + 1);
      ctx.stroke();
    }

    if (this.layers.labels && (selected || s.robots.length <= LABELLED_ROBOTS)) {
      ctx.font = '600 11px ui-monospace, monospace';
      ctx.textAlign = 'center';
      ctx.textBaseline = 'top';
      ctx.fillStyle = 'rgba(13,17,23,0.75)';
      const label = String(id);
      const tw = ctx.measureText(label).width;
      ctx.fillRect(sx - tw / 2 - 3, sy + rpx + 4, tw + 6, 14);
      ctx.fillStyle = color;
      ctx.fillText(label, sx, sy + rpx + 5);
    }
    return [sx, sy, rpx];
  }

  _drawGoalMarker(ctx, now) {
    const g = this.goalMarker;
    if (!g) return;
    const age = now - g.t;
    if (age > 1500) {
      this.goalMarker = null;
      return;
    }
    const [sx, sy] = this.worldToScreen(g.at[0], g.at[1]);
    const k = age / 1500;
    ctx.strokeStyle = `rgba(88,166,255,${1 - k})`;
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.arc(sx, sy, 6 + 24 * k, 0, TAU);
    ctx.stroke();
    this.invalidate();
  }

  _drawScaleBar(ctx) {
    const target = 120 / this.scale;
    const pow = 10 ** Math.floor(Math.log10(target));
    const len = [1, 2, 5, 10].map((m) => m * pow).filter((l) => l <= target).pop() || pow;
    const px = len * this.scale;
    const x = 16;
    const y = this.height - 18;
    ctx.strokeStyle = '#c9d1d9';
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.moveTo(x, y - 5);
    ctx.lineTo(x, y);
    ctx.lineTo(x + px, y);
    ctx.lineTo(x + px, y - 5);
    ctx.stroke();
    ctx.font = '11px ui-monospace, monospace';
    ctx.fillStyle = '#c9d1d9';
    ctx.textAlign = 'left';
    ctx.textBaseline = 'bottom';
    ctx.fillText(len >= 1 ? `${len} m` : `${Math.round(len * 100)} cm`, x + 4, y - 4);
  }
}
