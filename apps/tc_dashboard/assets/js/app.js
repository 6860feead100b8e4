// ThinkingCap's dashboard page: wires the connection, the store, the map
// and the panels, keeps the header and status bar current, and exposes
// `window.tc`, a read-only view of the page's state for tests and
// benchmarks.

import { Store } from './store.js';
import { Connection } from './socket.js';
import { MapView, LAYERS } from './map.js';
import { TimingPanel } from './timing.js';
import { ModulesPanel } from './modules.js';
import { BlackboardPanel } from './blackboard.js';
import { ParamsPanel } from './params.js';
import { BlackBoxPanel } from './blackbox.js';
import { Teleop } from './teleop.js';
import { $, el, fmt, fmtCommand, pose3, setChildren } from './util.js';

const store = new Store();
const conn = new Connection(store);

// ---- toasts --------------------------------------------------------------------

const toasts = $('#toasts');
function toast(text, kind = 'info') {
  const t = el(`div.toast.${kind}`, { role: 'status' }, text);
  toasts.append(t);
  setTimeout(() => t.classList.add('gone'), 3500);
  setTimeout(() => t.remove(), 4000);
  while (toasts.childElementCount > 4) toasts.firstElementChild.remove();
}

// ---- the map -----------------------------------------------------------------

const cursor = $('#cursor');
const map = new MapView($('#map'), store, {
  onGoal: async (goal, at) => {
    const robot = store.selected;
    if (!robot) return;
    if (!store.canControl) {
      toast('Read-only: sending goals needs the access token', 'error');
      return;
    }
    const what = goal.waypoint ? goal.waypoint : `(${fmt(at[0])}, ${fmt(at[1])})`;
    try {
      await conn.request({ op: 'goal', robot, ...goal });
      toast(`Goal for ${robot}: ${what}`);
    } catch (e) {
      toast(`Goal refused: ${e.message}`, 'error');
    }
  },
  onSelect: (id) => store.select(id),
  onCursor: (x, y) => {
    cursor.textContent = `x ${fmt(x)}  y ${fmt(y)} m`;
  },
});

$('#fit').addEventListener('click', () => map.fit());
$('#zoom-in').addEventListener('click', () => map.zoomAt(1.25));
$('#zoom-out').addEventListener('click', () => map.zoomAt(0.8));
const followBtn = $('#follow');
followBtn.addEventListener('click', () => {
  map.follow = !map.follow;
  followBtn.classList.toggle('on', map.follow);
  map.invalidate();
});
const goalBtn = $('#goal-mode');
goalBtn.classList.toggle('on', map.goalMode);
goalBtn.addEventListener('click', () => {
  map.goalMode = !map.goalMode;
  goalBtn.classList.toggle('on', map.goalMode);
});
setChildren($('#layers-menu'), Object.entries(LAYERS).map(([k, label]) => {
  const box = el('input', { type: 'checkbox', checked: map.layers[k] });
  box.addEventListener('change', () => {
    map.layers[k] = box.checked;
    map._staticKey = '';
    map.invalidate();
  });
  return el('label', null, box, label);
}));

// ---- panels --------------------------------------------------------------------

const teleop = new Teleop($('#teleop-body'), store, conn, toast);
const timing = new TimingPanel($('#tab-timing'), store);
new ModulesPanel($('#tab-modules'), store, conn, toast);
const bb = new BlackboardPanel($('#tab-blackboard'), store, conn);
const params = new ParamsPanel($('#tab-params'), store, conn, toast);
const blackbox = new BlackBoxPanel($('#tab-blackbox'), store, conn, map, toast);

const tabs = [...document.querySelectorAll('.tabs button')];
function showTab(name) {
  for (const b of tabs) b.classList.toggle('on', b.dataset.tab === name);
  for (const p of document.querySelectorAll('.tab-panel')) p.hidden = p.id !== `tab-${name}`;
  timing.setVisible(name === 'timing');
  params.setVisible(name === 'params');
  blackbox.setVisible(name === 'blackbox');
  try {
    localStorage.setItem('tc.tab', name);
  } catch (e) {
    // private mode
  }
}
for (const b of tabs) b.addEventListener('click', () => showTab(b.dataset.tab));
let initialTab = 'timing';
try {
  initialTab = localStorage.getItem('tc.tab') || 'timing';
} catch (e) {
  // private mode
}
showTab(tabs.some((b) => b.dataset.tab === initialTab) ? initialTab : 'timing');

$('#estop').addEventListener('click', () => teleop.estopAll());

store.on('server-error', (msg) => {
  bb.error(msg);
  if (!msg.id || !String(msg.id).startsWith('c')) toast(`Server: ${msg.message}`, 'error');
});

// ---- robot selector ----------------------------------------------------------

const select = $('#robot-select');
select.addEventListener('change', () => store.select(select.value));
store.on('robots', (robots) => {
  setChildren(select, robots.map((r) => el('option', { value: r, selected: r === store.selected }, r)));
  select.disabled = robots.length < 2;
  if (!map.fitted) map.fit();
});

// ---- header, banner, status bar ------------------------------------------------

const MODE_TEXT = { autonomy: 'AUTONOMY', teleop: 'TELEOP', estop: 'E-STOP', idle: 'IDLE' };
const banner = $('#banner');
const badge = $('#control-badge');

function renderStatus() {
  const s = store;
  // the banner: refused, read-only, or disconnected
  let text = '';
  let kind = '';
  if (s.refused) {
    const hint = /token/i.test(s.refused) ? '' : ' Open the dashboard with the URL printed at start (it carries ?token=…).';
    text = `Connection refused: ${s.refused.replace(/\.?$/, '.')}${hint}`;
    kind = 'error';
  } else if (!s.connected && s.welcomed) {
    text = 'Connection lost — reconnecting…';
    kind = 'warn';
  } else if (s.connected && s.welcomed && !s.canControl) {
    text = conn.token
      ? 'Read-only: the token was not accepted. You can watch, and press the E-stop, but not drive.'
      : 'Read-only: no access token in the URL. You can watch, and press the E-stop, but not drive.';
    kind = 'info';
  }
  banner.textContent = text;
  banner.className = `banner ${kind}`;
  banner.hidden = !text;
  document.body.classList.toggle('read-only', !s.canControl);

  const mode = s.control;
  badge.textContent = mode ? MODE_TEXT[mode] || mode.toUpperCase() : '—';
  badge.className = `mode mode-${mode || 'unknown'}`;
  const c = s.robotItem('control');
  badge.title = c ? `${s.selected}: ${mode}, applying ${fmtCommand(c.command)}` : 'who drives the selected robot';

  $('#conn').className = `conn ${s.connected ? 'up' : s.refused ? 'refused' : 'down'}`;
  $('#conn-text').textContent = s.connected ? (s.canControl ? 'connected · control' : 'connected · read-only') : s.refused ? 'refused' : 'disconnected';
  $('#st-control').textContent = mode ? `${s.selected}: ${MODE_TEXT[mode] || mode}` : '–';
  $('#st-control').className = `mode-text mode-${mode || 'unknown'}`;
  $('#st-command').textContent = c ? fmtCommand(c.command) : '–';
  const p = s.robotItem('sim_pose') || s.robotItem('pose') || s.robotItem('odom');
  const pose = p && pose3(p.pose);
  $('#st-pose').textContent = pose ? `(${fmt(pose[0])}, ${fmt(pose[1])}, ${fmt((pose[2] * 180) / Math.PI, 0)}°)` : '–';
  const odom = s.robotItem('odom');
  $('#st-twist').textContent = odom && Array.isArray(odom.twist) ? `${fmt(odom.twist[0])} m/s ${fmt(odom.twist[1])} rad/s` : '–';
  $('#st-fps').textContent = `${s.fps}`;
  $('#st-render').textContent = `${map.renderFps}`;
  $('#st-rtt').textContent = s.rtt !== null ? `${fmt(s.rtt, 1)} ms` : '–';
  $('#st-frames').textContent = String(s.frames);
  const world = s.world;
  $('#world-name').textContent = world ? `world: ${world.name || 'unnamed'}` : '';
}

store.on('status', renderStatus);
store.on('select', renderStatus);
let lastControl = null;
store.on('telemetry', (keys) => {
  if (keys.includes(`control/${store.selected}`)) {
    const mode = store.control;
    if (mode !== lastControl) {
      lastControl = mode;
      renderStatus();
      document.body.dataset.control = mode || '';
    }
  }
});
setInterval(() => {
  store.updateFps();
  renderStatus();
}, 250);

// ---- the test hook -------------------------------------------------------------

/** A read-only view of the page's state, for tests and benchmarks. */
window.tc = {
  get connected() { return store.connected; },
  get frames() { return store.frames; },
  get fps() { return store.fps; },
  /** who drives the selected robot: "autonomy" | "teleop" | "estop" | "idle" | null */
  get control() { return store.control; },
  get lastTelemetry() { return store.lastTelemetry; },
  get canControl() { return store.canControl; },
  get welcomed() { return store.welcomed; },
  get refused() { return store.refused; },
  get robots() { return [...store.robots]; },
  get selected() { return store.selected; },
  get world() { return store.world; },
  get renderFps() { return map.renderFps; },
  get renders() { return map.renders; },
  get rtt() { return store.rtt; },
  /** the latest value of one stream, e.g. tc.item("sim_pose/r1") */
  item(key) { return store.get(key); },
  keys() { return [...store.items.keys()]; },
  /** where each robot was drawn last: {id: [x, y, radius]} in CSS pixels of the map canvas */
  get drawn() { return JSON.parse(JSON.stringify(map.drawn)); },
  /** how many walkers (people of a simulated world) the map drew last */
  get walkersDrawn() { return map.walkersDrawn || 0; },
  worldToScreen(x, y) { return map.worldToScreen(x, y); },
  /** the colour a robot is drawn in (#rrggbb) */
  robotColor(id) { return map.robotColor(id); },
  get teleop() {
    return { command: teleop.command && { ...teleop.command }, robot: teleop.robot, sent: teleop.sent };
  },
  select(id) { store.select(id); },
  /**
   * the black box's timeline: {open, robot, from, to, at, map, frames, streams, keys}
   * (at: the instant the map shows, ms since the epoch; frames: frames received)
   */
  get timeline() { return blackbox.state; },
  /** whether the map shows a past instant (the timeline) rather than the live robots */
  get replaying() { return map.replaying; },
  /** shows a tab of the sidebar: "timing" | "modules" | "params" | "blackboard" | "blackbox" */
  showTab(name) { showTab(name); },
};

renderStatus();
conn.connect();
