// The Modules panel: what runs on which node (`modules/all`), its
// activity, status and restarts (a module whose layer gave up: "gave up",
// with its reason, and those stopped with it: "stopped"), with a restart button for those who have
// control; then the selected robot's behaviours and their activation
// degrees (`activation/<robot>`) and its plan (`plan/<robot>`).

import { el, fmt, obj, setChildren } from './util.js';

function activityText(a) {
  if (a === null || a === undefined) return '–';
  if (typeof a === 'string') return a;
  const o = obj(a);
  if (o) {
    const kind = o.kind || o.type || o.activity || '';
    const period = typeof o.period === 'number' ? ` ${fmt(o.period * 1000, o.period < 0.01 ? 1 : 0)} ms` : '';
    return `${kind}${period}` || JSON.stringify(a);
  }
  if (Array.isArray(a)) return a.map((x) => (typeof x === 'object' ? JSON.stringify(x) : String(x))).join(' ');
  return String(a);
}

function statusClass(status) {
  const s = String(status || '').toLowerCase();
  if (['running', 'ok', 'up', 'alive'].includes(s)) return 'ok';
  if (['restarting', 'starting', 'waiting', 'degraded'].includes(s)) return 'warn';
  return s ? 'bad' : '';
}

export class ModulesPanel {
  constructor(root, store, conn, toast) {
    this.root = root;
    this.store = store;
    this.conn = conn;
    this.toast = toast;
    this.table = el('table.modules');
    this.modulesEmpty = el('p.empty', null, 'Waiting for the runtime\u2019s module list…');
    this.behaviours = el('div.behaviours');
    this.plan = el('dl.plan');
    setChildren(root,
      el('h2', null, 'Modules'), this.modulesEmpty, el('div.scroll-x', null, this.table),
      el('h2#behaviours-title', null, 'Behaviours'), this.behaviours,
      el('h2', null, 'Plan'), this.plan);
    this._renderModules();
    this._renderBehaviours();
    this._renderPlan();
    // telemetry marks what changed; it is drawn once, in the next animation frame
    this.stale = new Set();
    store.on('telemetry', (keys) => {
      const sel = store.selected;
      if (keys.includes('modules/all')) this._later('modules');
      if (keys.includes(`activation/${sel}`)) this._later('behaviours');
      if (keys.includes(`plan/${sel}`)) this._later('plan');
    });
    store.on('select', () => {
      this._renderBehaviours();
      this._renderPlan();
    });
    store.on('status', () => this._renderModules());
  }

  _later(part) {
    if (this.stale.size === 0) {
      requestAnimationFrame(() => {
        if (this.stale.has('modules')) this._renderModules();
        if (this.stale.has('behaviours')) this._renderBehaviours();
        if (this.stale.has('plan')) this._renderPlan();
        this.stale.clear();
      });
    }
    this.stale.add(part);
  }

  _renderModules() {
    const all = this.store.get('modules/all');
    const mods = (all && Array.isArray(all.modules) ? all.modules : []).map(obj).filter(Boolean);
    this.modulesEmpty.hidden = mods.length > 0;
    const canRestart = this.store.canControl && this.store.connected;
    setChildren(this.table,
      el('thead', null, el('tr', null, ...['module · node', 'activity', 'status', 'restarts', ''].map((h) => el('th', null, h)))),
      el('tbody', null, mods.map((m) => el('tr', { dataset: { module: String(m.name) } },
        el('td', { title: `${m.module || ''} on ${m.node || '?'}${m.robot ? `, robot ${m.robot}` : ''}${m.layer ? `, layer ${m.layer}` : ''}` }, el('b', null, String(m.name)),
          el('small', null, String(m.module || '').replace(/^Elixir\./, '').replace(/^ThinkingCap\./, '')),
          el('small.node', null, String(m.node || '–'))),
        el('td', null, activityText(m.activity)),
        el('td', m.reason ? { title: String(m.reason) } : null,
          el(`span.pill.${statusClass(m.status)}`, null, String(m.status || '–').replace(/_/g, ' ')),
          m.reason ? el('small.reason', null, String(m.reason)) : null),
        el(`td.num${(m.restarts || 0) > 0 ? '.warn-text' : ''}`, null, String(m.restarts ?? 0)),
        el('td', null, el('button.small', {
          type: 'button',
          disabled: !canRestart || (m.status != null && m.status !== 'running'),
          title: canRestart ? `Restart ${m.name}` : 'Needs control (the token)',
          onclick: () => this._restart(String(m.name), m.robot == null ? null : String(m.robot)),
        }, '↻'))))));
  }

  async _restart(name, robot) {
    try {
      await this.conn.request(robot ? { op: 'restart', module: name, robot } : { op: 'restart', module: name });
      this.toast(`Restarted ${name}`);
    } catch (e) {
      this.toast(`Restart of ${name} refused: ${e.message}`, 'error');
    }
  }

  _renderBehaviours() {
    const sel = this.store.selected;
    const act = this.store.get(`activation/${sel}`);
    const o = obj(act) || {};
    const entries = Object.entries(o).filter(([, v]) => typeof v === 'number');
    if (!entries.length) {
      setChildren(this.behaviours, el('p.empty', null, sel ? `No behaviour activations from ${sel} yet.` : 'No robot.'));
      return;
    }
    entries.sort((a, b) => a[0].localeCompare(b[0]));
    setChildren(this.behaviours, entries.map(([name, degree]) => {
      const d = Math.max(0, Math.min(1, degree));
      return el('div.bar-row', { dataset: { behaviour: name } },
        el('span.bar-label', null, name.replace(/_/g, ' ')),
        el('span.bar', null, el('span.fill', { style: `width:${(d * 100).toFixed(1)}%;opacity:${0.35 + 0.65 * d}` })),
        el('span.bar-value', null, d.toFixed(2)));
    }));
  }

  _renderPlan() {
    const sel = this.store.selected;
    const p = obj(this.store.get(`plan/${sel}`));
    if (!p) {
      setChildren(this.plan, el('p.empty', null, 'No plan.'));
      return;
    }
    const show = (v) => {
      if (v === null || v === undefined) return '–';
      if (Array.isArray(v) && v.every((x) => typeof x === 'number')) return `(${v.map((x) => fmt(x)).join(', ')})`;
      if (typeof v === 'object') return JSON.stringify(v);
      return String(v);
    };
    // a task as the planner writes it: ["patrol", ["a", "b"]], ["go_to", [x, y]], ...
    const task = (t) => {
      if (!Array.isArray(t) || typeof t[0] !== 'string') return show(t);
      const [kind, arg] = t;
      if (Array.isArray(arg) && arg.every((x) => typeof x === 'string')) return `${kind}: ${arg.join(' → ')}`;
      return arg === undefined ? kind : `${kind} ${show(arg)}`;
    };
    const rows = [
      ['task', task(p.task)],
      ['state', show(p.state)],
      ['waypoint', show(p.waypoint)],
      ['goal', show(p.goal)],
      ['path', Array.isArray(p.path) ? `${p.path.length} points` : '–'],
      ['door', show(p.door)],
      ['closed doors', Array.isArray(p.closed_doors) && p.closed_doors.length ? p.closed_doors.join(', ') : '–'],
      ['replans', show(p.replans)],
      ['reached', Array.isArray(p.reached) ? p.reached.join(', ') || '–' : show(p.reached)],
      ['given up', Array.isArray(p.given_up) ? p.given_up.map(show).join(', ') || '–' : show(p.given_up)],
    ];
    setChildren(this.plan, rows.flatMap(([k, v]) => [el('dt', null, k), el('dd', null, v)]));
  }
}
