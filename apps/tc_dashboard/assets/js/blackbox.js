// The Black box panel, for the selected robot: its dumps (time, reason,
// size, a download link carrying the page's token), a "Dump now" button,
// and the timeline of its black box's last minute. Opening the timeline
// takes a snapshot on the server (it does not move under the slider);
// moving the slider asks for the instant under it, and the map draws that
// instant (a Replay) with its usual code until "Live" is pressed. Frames
// are asked for one at a time, the latest position winning, so a fast
// slider never queues requests; the map comes only when it changes.

import { Replay } from './replay.js';
import { el, setChildren } from './util.js';

function fmtBytes(n) {
  if (typeof n !== 'number') return '–';
  if (n < 1024) return `${n} B`;
  if (n < 1024 * 1024) return `${(n / 1024).toFixed(1)} KB`;
  return `${(n / 1024 / 1024).toFixed(1)} MB`;
}

function fmtTime(ms, withDate = true) {
  if (typeof ms !== 'number') return '–';
  const d = new Date(ms);
  const pad = (x, n = 2) => String(x).padStart(n, '0');
  const time = `${pad(d.getHours())}:${pad(d.getMinutes())}:${pad(d.getSeconds())}.${pad(d.getMilliseconds(), 3)}`;
  return withDate ? `${d.getFullYear()}-${pad(d.getMonth() + 1)}-${pad(d.getDate())} ${time}` : time;
}

export class BlackBoxPanel {
  constructor(root, store, conn, map, toast) {
    this.root = root;
    this.store = store;
    this.conn = conn;
    this.map = map;
    this.toast = toast;
    this.visible = false;
    this.loading = null;
    /** the open timeline: {robot, from, to, replay}, or null */
    this.timeline = null;
    this.frames = 0;
    this._wanted = null;
    this._inflight = false;

    this.dumpBtn = el('button.small', { type: 'button', title: 'Dump the robot\u2019s black box now (its last minute, and a few seconds more)' }, 'Dump now');
    this.dumpBtn.addEventListener('click', () => this.dumpNow());
    this.list = el('div.dumps');
    this.openBtn = el('button.small.timeline-open', { type: 'button', title: 'Scrub the black box\u2019s last minute on the map' }, 'Open the last minute');
    this.openBtn.addEventListener('click', () => this.openTimeline());
    this.liveBtn = el('button.small.timeline-live', { type: 'button', hidden: true, title: 'Back to the live view' }, 'Live');
    this.liveBtn.addEventListener('click', () => this.closeTimeline());
    this.slider = el('input.timeline-slider', { type: 'range', min: 0, max: 0, step: 1, value: 0, disabled: true, 'aria-label': 'Instant shown' });
    this.slider.addEventListener('input', () => this._want(this._sliderAt()));
    this.marks = el('div.timeline-marks', { 'aria-label': 'Incidents' });
    this.when = el('div.timeline-when.mono', null, '');
    this.badge = document.getElementById('replay-badge');

    setChildren(root,
      el('div.panel-head', null, el('h2', null, 'Black box'), el('span.spacer'), this.dumpBtn),
      this.list,
      el('h2', null, 'Timeline'),
      el('p.muted.timeline-help', null, 'A snapshot of the last minute: move the slider to see the map, the laser, the plan and the pose at that instant.'),
      el('div.timeline-buttons', null, this.openBtn, this.liveBtn),
      this.slider,
      this.marks,
      this.when);

    store.on('select', () => {
      if (this.timeline && this.timeline.robot !== store.selected) this.closeTimeline();
      this.refresh();
    });
    // a new session knows nothing of the old one's timeline
    store.on('welcome', () => {
      if (this.timeline) this._endTimeline();
      this.refresh();
    });
    store.on('status', () => this._renderButtons());
    store.on('telemetry', (keys) => {
      if (this.visible && keys.includes(`black_box_dump/${store.selected}`)) this.refresh();
    });
    this._renderButtons();
  }

  setVisible(visible) {
    this.visible = visible;
    if (visible) this.refresh();
  }

  _renderButtons() {
    this.dumpBtn.disabled = !this.store.canControl || !this.store.selected;
    this.dumpBtn.title = this.store.canControl ? 'Dump the robot\u2019s black box now (its last minute, and a few seconds more)' : 'Read-only: dumping needs the access token';
  }

  // ---- dumps -----------------------------------------------------------------------

  /** Asks the server for the selected robot's dumps and lists them. */
  async refresh() {
    const robot = this.store.selected;
    if (!this.visible || !robot || !this.store.connected) return;
    const asked = (this.loading = Symbol('load'));
    try {
      const reply = await this.conn.request({ op: 'dumps', robot });
      if (asked !== this.loading || robot !== this.store.selected) return;
      this._renderDumps(robot, reply);
    } catch (e) {
      if (asked === this.loading) setChildren(this.list, el('p.empty', null, `Dumps unavailable: ${e.message}`));
    }
  }

  _renderDumps(robot, reply) {
    const dumps = Array.isArray(reply.dumps) ? reply.dumps : [];
    const note = reply.keeping ? null : el('p.muted', null, `No black box keeps ${robot} on this node.`);
    if (!dumps.length) {
      setChildren(this.list, note, el('p.empty', null, `No dump of ${robot} yet.`));
      return;
    }
    const token = this.conn.token ? `?token=${encodeURIComponent(this.conn.token)}` : '';
    const more = reply.total > dumps.length ? el('p.muted', null, `The ${dumps.length} newest of ${reply.total}.`) : null;
    setChildren(this.list, note, more, el('table.dumps-table', null,
      el('thead', null, el('tr', null, el('th', null, 'time'), el('th', null, 'reason'), el('th', null, 'size'), el('th'))),
      el('tbody', null, dumps.map((d) => el('tr', { dataset: { name: String(d.name) } },
        el('td.mono', { title: String(d.name) }, fmtTime(d.time)),
        el('td', null, String(d.reason)),
        el('td.mono', null, fmtBytes(d.bytes)),
        el('td', null, el('a.download', { href: `${d.url}${token}`, download: String(d.name), title: `Download ${d.name} (MCAP: opens in Foxglove)` }, 'download')))))));
  }

  async dumpNow() {
    const robot = this.store.selected;
    if (!robot) return;
    try {
      await this.conn.request({ op: 'dump', robot });
      this.toast(`Dump of ${robot} asked for: listed once written`);
    } catch (e) {
      this.toast(`Dump refused: ${e.message}`, 'error');
    }
  }

  // ---- the timeline ------------------------------------------------------------------

  async openTimeline() {
    const robot = this.store.selected;
    if (!robot) return;
    this.openBtn.disabled = true;
    try {
      const summary = await this.conn.request({ op: 'timeline', robot }, { timeout: 30000 });
      if (robot !== this.store.selected) return;
      const replay = new Replay(this.store, robot);
      const incidents = summary.incidents || [];
      this.timeline = { robot, from: summary.from, to: summary.to, streams: summary.streams || {}, incidents, replay };
      this._renderMarks();
      this.frames = 0;
      this.slider.max = String(Math.max(0, summary.to - summary.from));
      this.slider.value = this.slider.max;
      this.slider.disabled = false;
      this.liveBtn.hidden = false;
      this.openBtn.textContent = 'Take a new snapshot';
      this.map.setSource(replay);
      this._want(summary.to);
    } catch (e) {
      this.toast(`Timeline unavailable: ${e.message}`, 'error');
    } finally {
      this.openBtn.disabled = false;
    }
  }

  /** Back to the live view; the server lets the snapshot go. */
  closeTimeline() {
    if (!this.timeline) return;
    this.conn.request({ op: 'timeline_close' }).catch(() => {});
    this._endTimeline();
  }

  _endTimeline() {
    this.timeline = null;
    this._wanted = null;
    this.slider.disabled = true;
    this.liveBtn.hidden = true;
    this.openBtn.textContent = 'Open the last minute';
    this.when.textContent = '';
    setChildren(this.marks);
    if (this.badge) this.badge.hidden = true;
    this.map.setSource(null);
  }

  // a mark under the slider for each incident of the span (what made the
  // black box dump); a click shows its instant
  _renderMarks() {
    const t = this.timeline;
    const span = Math.max(1, t.to - t.from);
    const marks = t.incidents
      .filter((i) => i.at >= t.from && i.at <= t.to + 1)
      .map((i) => {
        const mark = el('button.timeline-mark', {
          type: 'button',
          title: `${i.reason} at ${fmtTime(i.at, false)}`,
          'data-reason': i.reason,
        });
        mark.style.left = `${((100 * (i.at - t.from)) / span).toFixed(2)}%`;
        mark.addEventListener('click', () => {
          this.slider.value = String(i.at - t.from);
          this._want(i.at);
        });
        return mark;
      });
    setChildren(this.marks, ...marks);
  }

  _sliderAt() {
    return this.timeline.from + Number(this.slider.value);
  }

  // the latest position wins; one request at a time
  _want(at) {
    if (!this.timeline) return;
    this._wanted = at;
    if (!this._inflight) this._fetch();
  }

  async _fetch() {
    const t = this.timeline;
    if (!t || this._wanted === null) return;
    const at = this._wanted;
    this._wanted = null;
    this._inflight = true;
    try {
      const frame = await this.conn.request({ op: 'timeline_frame', at, map: t.replay.mapId });
      if (t !== this.timeline) return;
      t.replay.apply(frame);
      this.frames += 1;
      this._renderWhen(frame.at);
      this.map.invalidate();
    } catch (e) {
      if (t === this.timeline) {
        this.toast(`Timeline: ${e.message}`, 'error');
        this._endTimeline();
      }
    } finally {
      this._inflight = false;
      if (this._wanted !== null && this.timeline) this._fetch();
    }
  }

  _renderWhen(at) {
    const t = this.timeline;
    const ago = ((t.to - at) / 1000).toFixed(1);
    this.when.textContent = `${fmtTime(at, false)}  (${ago} s before the snapshot)`;
    if (this.badge) {
      this.badge.textContent = `BLACK BOX · ${t.robot} · ${fmtTime(at, false)} · −${ago} s`;
      this.badge.hidden = false;
    }
  }

  /** What the page's tests read (window.tc.timeline). */
  get state() {
    const t = this.timeline;
    if (!t) return { open: false, frames: this.frames };
    return {
      open: true,
      robot: t.robot,
      from: t.from,
      to: t.to,
      at: t.replay.at,
      map: t.replay.mapId,
      frames: this.frames,
      streams: { ...t.streams },
      incidents: t.incidents.map((i) => ({ ...i })),
      keys: [...t.replay.items.keys()],
    };
  }
}
