// The Timing panel: per periodic activity, the figures the timing worker
// publishes once a second (`timing/<activity>`): cycles, deadline misses
// (late results) and fallbacks, and mean / std / min / max of release
// jitter, response time, cycle time and CPU time, as in the paper's
// tables. Live plots show each second's mean cycle and response time (from
// the difference of two cumulative summaries); histograms show the whole
// run's distribution in the worker's log2 buckets.

import { el, fmtUs, setChildren } from './util.js';

const HISTORY = 60;
const SERIES = {
  response_us: { label: 'Response', color: '#e3b341' },
  cycle_us: { label: 'Cycle', color: '#58a6ff' },
  jitter_us: { label: 'Jitter', color: '#3fb950' },
  cpu_us: { label: 'CPU', color: '#d2a8ff' },
};

export class TimingPanel {
  constructor(root, store) {
    this.root = root;
    this.store = store;
    this.activities = new Map();
    this.dirty = new Set();
    this.frame = null;
    // canvas sizes as laid out, kept by a ResizeObserver: reading
    // clientWidth while drawing would force a layout per canvas
    this.resizes = new ResizeObserver((entries) => {
      for (const e of entries) {
        sizes.set(e.target, { w: e.contentRect.width, h: e.contentRect.height });
        const a = this.activities.get(e.target.closest('article')?.dataset.activity);
        if (a && this.visible) this._schedule(a);
      }
    });
    // an activity scrolled out of view is drawn when it comes back
    this.views = new IntersectionObserver((entries) => {
      for (const e of entries) {
        const a = this.activities.get(e.target.dataset.activity);
        if (!a) continue;
        a.inView = e.isIntersecting;
        if (a.inView && this.visible) this._schedule(a);
      }
    });
    this.histKind = 'response_us';
    this.visible = true;
    this.empty = el('p.empty', null, 'No periodic activity has reported its timing yet (the worker publishes once a second).');
    this.list = el('div.timing-list');
    const picker = el('div.seg', null, ...Object.entries(SERIES).map(([k, s]) => {
      const b = el('button', { type: 'button', dataset: { kind: k }, class: k === this.histKind ? 'on' : null }, s.label);
      b.addEventListener('click', () => {
        this.histKind = k;
        picker.querySelectorAll('button').forEach((x) => x.classList.toggle('on', x.dataset.kind === k));
        for (const a of this.activities.values()) this._render(a);
      });
      return b;
    }));
    setChildren(root, el('div.panel-head', null, el('span.hint', null, 'Histogram of'), picker), this.empty, this.list);
    store.on('telemetry', (keys) => {
      for (const k of keys) if (k.startsWith('timing/')) this._update(k.slice(7), store.get(k));
    });
    store.on('welcome', () => {
      for (const a of this.activities.values()) this._forget(a);
      this.activities.clear();
      this.list.replaceChildren();
      this.empty.hidden = false;
    });
  }

  _update(name, summary) {
    if (!summary) {
      const a = this.activities.get(name);
      if (a) this._forget(a);
      this.activities.delete(name);
      this.empty.hidden = this.activities.size > 0;
      return;
    }
    let a = this.activities.get(name);
    if (!a) {
      a = this._create(name);
      this.activities.set(name, a);
      const sorted = [...this.activities.keys()].sort();
      this.list.replaceChildren(...sorted.map((n) => this.activities.get(n).node));
      this.empty.hidden = true;
    }
    const prev = a.summary;
    a.summary = summary;
    // this interval's means, from two cumulative summaries
    const point = { t: performance.now() };
    for (const k of ['response_us', 'cycle_us']) {
      const now = summary[k] || {};
      const before = (prev && prev[k]) || { n: 0, mean: 0 };
      const dn = (now.n || 0) - (before.n || 0);
      point[k] = dn > 0 ? ((now.n * now.mean) - (before.n * (before.mean || 0))) / dn : null;
    }
    const missesBefore = prev ? (prev.late || 0) + (prev.fallbacks || 0) : 0;
    const misses = (summary.late || 0) + (summary.fallbacks || 0);
    if (prev && misses > missesBefore) a.lastMiss = performance.now();
    point.misses = prev ? misses - missesBefore : 0;
    a.history.push(point);
    if (a.history.length > HISTORY) a.history.shift();
    if (this.visible) this._schedule(a);
  }

  // Activities report at different moments: their panels are redrawn
  // together in the next animation frame, so that the page lays out once
  // per frame however many reports a telemetry frame brings.
  _schedule(a) {
    this.dirty.add(a);
    if (!this.frame) {
      this.frame = requestAnimationFrame(() => {
        this.frame = null;
        const dirty = [...this.dirty];
        this.dirty.clear();
        for (const d of dirty) if (this.activities.get(d.name) === d && d.inView) this._render(d);
      });
    }
  }

  _create(name) {
    const a = { name, summary: null, history: [], lastMiss: null, inView: false };
    a.title = el('h3', null, name);
    a.badges = el('div.badges');
    a.table = el('table.figures');
    a.plot = el('canvas.plot', { width: 300, height: 90 });
    a.hist = el('canvas.hist', { width: 300, height: 70 });
    a.node = el('article.activity', { dataset: { activity: name } },
      el('header', null, a.title, a.badges), a.table, a.plot, a.hist);
    this.views.observe(a.node);
    this.resizes.observe(a.plot);
    this.resizes.observe(a.hist);
    return a;
  }

  _forget(a) {
    a.node.remove();
    this.views.unobserve(a.node);
    this.resizes.unobserve(a.plot);
    this.resizes.unobserve(a.hist);
  }

  setVisible(v) {
    this.visible = v;
    if (v) for (const a of this.activities.values()) this._schedule(a);
  }

  _render(a) {
    const s = a.summary;
    if (!s) return;
    const recent = a.lastMiss && performance.now() - a.lastMiss < 5000;
    setChildren(a.badges,
      el('span.badge', { title: 'period' }, fmtUs(s.period_us)),
      el('span.badge', { title: 'cycles released' }, `${s.cycles ?? 0} cycles`),
      el(`span.badge${(s.late || 0) > 0 ? '.warn' : ''}${recent ? '.alarm' : ''}`, { title: 'results that missed their deadline' }, `${s.late ?? 0} late`),
      el(`span.badge${(s.fallbacks || 0) > 0 ? '.warn' : ''}${recent ? '.alarm' : ''}`, { title: 'fallback commands applied' }, `${s.fallbacks ?? 0} fallbacks`),
      (s.skipped || 0) > 0 ? el('span.badge.warn', { title: 'releases skipped' }, `${s.skipped} skipped`) : null);
    const row = (k) => {
      const f = s[k] || {};
      return el('tr', null, el('th', null, el('i', { style: `background:${SERIES[k].color}` }), SERIES[k].label),
        el('td', null, fmtUs(f.mean)), el('td', null, fmtUs(f.std)), el('td', null, fmtUs(f.min)), el('td', null, fmtUs(f.max)));
    };
    setChildren(a.table,
      el('thead', null, el('tr', null, el('th'), el('th', null, 'mean'), el('th', null, 'std'), el('th', null, 'min'), el('th', null, 'max'))),
      el('tbody', null, Object.keys(SERIES).map(row)));
    drawPlot(a.plot, a.history, s.period_us);
    drawHistogram(a.hist, (s[this.histKind] || {}).hist, SERIES[this.histKind]);
  }
}

// laid-out sizes of the panel's canvases (see TimingPanel's ResizeObserver)
const sizes = new WeakMap();

function prepare(canvas) {
  const dpr = window.devicePixelRatio || 1;
  const size = sizes.get(canvas);
  const w = (size && size.w) || canvas.width / dpr;
  const h = (size && size.h) || canvas.height / dpr;
  if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) {
    canvas.width = Math.round(w * dpr);
    canvas.height = Math.round(h * dpr);
  }
  const ctx = canvas.getContext('2d');
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.clearRect(0, 0, w, h);
  return [ctx, w, h];
}

// each second's mean cycle time (left axis, with the period dashed) and
// mean response time (right axis); a red tick where a deadline was missed
function drawPlot(canvas, history, period) {
  const [ctx, w, h] = prepare(canvas);
  const pad = { l: 50, r: 50, t: 8, b: 12 };
  const pw = w - pad.l - pad.r;
  const ph = h - pad.t - pad.b;
  ctx.fillStyle = '#0d1117';
  ctx.fillRect(pad.l, pad.t, pw, ph);
  const x = (i) => pad.l + (pw * (i + HISTORY - history.length)) / (HISTORY - 1);
  const axis = (key, ref) => {
    const vals = history.map((p) => p[key]).filter((v) => v !== null && v !== undefined);
    if (ref) vals.push(ref);
    if (!vals.length) return null;
    let lo = Math.min(...vals);
    let hi = Math.max(...vals);
    if (hi - lo < Math.max(1, hi * 0.02)) {
      lo -= Math.max(1, hi * 0.01);
      hi += Math.max(1, hi * 0.01);
    }
    return { lo, hi, y: (v) => pad.t + ph - ((v - lo) / (hi - lo)) * ph };
  };
  const cyc = axis('cycle_us', period);
  const resp = axis('response_us');
  ctx.font = '10px ui-monospace, monospace';
  ctx.textBaseline = 'middle';
  if (cyc && period) {
    ctx.strokeStyle = 'rgba(88,166,255,0.45)';
    ctx.setLineDash([3, 3]);
    ctx.beginPath();
    ctx.moveTo(pad.l, cyc.y(period));
    ctx.lineTo(pad.l + pw, cyc.y(period));
    ctx.stroke();
    ctx.setLineDash([]);
  }
  const line = (ax, key, color) => {
    if (!ax) return;
    ctx.strokeStyle = color;
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    let started = false;
    history.forEach((p, i) => {
      const v = p[key];
      if (v === null || v === undefined) {
        started = false;
        return;
      }
      if (!started) ctx.moveTo(x(i), ax.y(v));
      else ctx.lineTo(x(i), ax.y(v));
      started = true;
    });
    ctx.stroke();
  };
  line(cyc, 'cycle_us', SERIES.cycle_us.color);
  line(resp, 'response_us', SERIES.response_us.color);
  ctx.fillStyle = '#f85149';
  history.forEach((p, i) => {
    if (p.misses > 0) ctx.fillRect(x(i) - 1, pad.t, 2, ph);
  });
  if (cyc) {
    ctx.fillStyle = SERIES.cycle_us.color;
    ctx.textAlign = 'right';
    ctx.fillText(fmtUs(cyc.hi), pad.l - 4, pad.t + 4);
    ctx.fillText(fmtUs(cyc.lo), pad.l - 4, pad.t + ph - 4);
  }
  if (resp) {
    ctx.fillStyle = SERIES.response_us.color;
    ctx.textAlign = 'left';
    ctx.fillText(fmtUs(resp.hi), pad.l + pw + 4, pad.t + 4);
    ctx.fillText(fmtUs(resp.lo), pad.l + pw + 4, pad.t + ph - 4);
  }
  ctx.fillStyle = '#8b949e';
  ctx.textAlign = 'center';
  ctx.textBaseline = 'top';
  ctx.fillText('cycle · response, per second', pad.l + pw / 2, pad.t + ph + 1);
}

// the worker's log2 buckets: bucket 0 is < 1 µs, bucket b is [2^(b-1), 2^b) µs
function drawHistogram(canvas, hist, series) {
  const [ctx, w, h] = prepare(canvas);
  const entries = Object.entries(hist || {}).map(([k, v]) => [Number(k), v]).filter(([k]) => Number.isFinite(k));
  ctx.font = '10px ui-monospace, monospace';
  if (!entries.length) {
    ctx.fillStyle = '#8b949e';
    ctx.textAlign = 'center';
    ctx.textBaseline = 'middle';
    ctx.fillText('no samples', w / 2, h / 2);
    return;
  }
  const lo = Math.min(...entries.map(([k]) => k));
  const hi = Math.max(...entries.map(([k]) => k));
  const counts = new Map(entries);
  const total = entries.reduce((s, [, v]) => s + v, 0);
  const max = Math.max(...entries.map(([, v]) => v));
  const pad = { l: 4, r: 4, t: 4, b: 14 };
  const nb = hi - lo + 1;
  const bw = (w - pad.l - pad.r) / nb;
  const ph = h - pad.t - pad.b;
  for (let b = lo; b <= hi; b++) {
    const c = counts.get(b) || 0;
    // a log scale of counts: rare outliers stay visible
    const frac = c > 0 ? Math.log1p(c) / Math.log1p(max) : 0;
    const bx = pad.l + (b - lo) * bw;
    ctx.fillStyle = series.color;
    ctx.globalAlpha = 0.85;
    ctx.fillRect(bx + 1, pad.t + ph * (1 - frac), Math.max(1, bw - 2), ph * frac);
    ctx.globalAlpha = 1;
    if (nb <= 16 || (b - lo) % 2 === 0) {
      ctx.fillStyle = '#8b949e';
      ctx.textAlign = 'center';
      ctx.textBaseline = 'top';
      ctx.fillText(b === 0 ? '<1µ' : fmtUs(2 ** b).replace(' ', ''), bx + bw / 2, pad.t + ph + 2);
    }
  }
  canvas.title = `${series.label}: ${total} samples, log2 buckets (upper bounds), log count scale`;
}
