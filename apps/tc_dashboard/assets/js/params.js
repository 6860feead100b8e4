// The Params panel: the live parameters of the selected robot's modules
// (ThinkingCap.Module), as their schemas describe them: a number input
// with its bounds, a checkbox, a select of the choices, a text field;
// read-only ones (and those of modules that take no live changes) shown
// disabled. Setting one sends `set_param`; the server checks it against
// the schema and a refusal is shown beside the field, with its reason.

import { el, setChildren } from './util.js';

function bounds(f) {
  const has = (x) => typeof x === 'number';
  if (has(f.min) && has(f.max)) return `${f.min} … ${f.max}`;
  if (has(f.min)) return f.exclusive_min ? `> ${f.min}` : `≥ ${f.min}`;
  if (has(f.max)) return `≤ ${f.max}`;
  return '';
}

function show(v) {
  if (v === null || v === undefined) return '–';
  return typeof v === 'object' ? JSON.stringify(v) : String(v);
}

export class ParamsPanel {
  constructor(root, store, conn, toast) {
    this.root = root;
    this.store = store;
    this.conn = conn;
    this.toast = toast;
    this.visible = false;
    this.loading = null;
    this.body = el('div.params');
    setChildren(root, el('h2', null, 'Parameters'), this.body);
    this._empty('Open to load the selected robot\u2019s parameters.');
    store.on('select', () => this.refresh());
    store.on('welcome', () => this.refresh());
  }

  setVisible(visible) {
    this.visible = visible;
    if (visible) this.refresh();
  }

  _empty(text) {
    setChildren(this.body, el('p.empty', null, text));
  }

  /** Asks the server for the selected robot's params and draws them. */
  async refresh() {
    const robot = this.store.selected;
    if (!this.visible || !robot || !this.store.connected) return;
    const asked = (this.loading = Symbol('load'));
    try {
      const reply = await this.conn.request({ op: 'params', robot });
      if (asked !== this.loading || robot !== this.store.selected) return;
      this._render(robot, Array.isArray(reply.modules) ? reply.modules : []);
    } catch (e) {
      if (asked === this.loading) this._empty(`Parameters unavailable: ${e.message}`);
    }
  }

  _render(robot, modules) {
    if (!modules.length) {
      this._empty(`No module of ${robot} declares parameters.`);
      return;
    }
    const canSet = this.store.canControl;
    setChildren(this.body, modules.map((m) => el('fieldset.param-module', { dataset: { module: String(m.name) } },
      el('legend', null, el('b', null, String(m.name)),
        el('small', null, ` ${String(m.module || '').replace(/^Elixir\./, '').replace(/^ThinkingCap\./, '')}`),
        m.live ? null : el('small.muted', null, ' · takes no live changes')),
      (m.fields || []).map((f) => this._row(robot, m, f, canSet)))));
  }

  _row(robot, m, f, canSet) {
    const editable = canSet && !f.read_only && f.input !== 'other';
    let input;
    switch (f.input) {
      case 'number':
      case 'integer':
        input = el('input', {
          type: 'number',
          step: f.input === 'integer' ? '1' : 'any',
          min: typeof f.min === 'number' ? String(f.min) : null,
          max: typeof f.max === 'number' ? String(f.max) : null,
        });
        input.value = typeof f.value === 'number' ? String(f.value) : '';
        break;
      case 'boolean':
        input = el('input', { type: 'checkbox' });
        input.checked = f.value === true;
        break;
      case 'choice':
        input = el('select', null, (f.choices || []).map((c) => el('option', { value: String(c), selected: String(c) === String(f.value) }, String(c))));
        break;
      case 'string':
        input = el('input', { type: 'text', maxlength: '256' });
        input.value = typeof f.value === 'string' ? f.value : '';
        break;
      default:
        input = el('input', { type: 'text' });
        input.value = show(f.value);
    }
    input.disabled = !editable;
    input.classList.add('param-input');
    const error = el('div.param-error', { role: 'alert' });
    const why = f.read_only ? 'read-only: set in the ADF, read at start' : f.input === 'other' ? 'not settable from the page' : canSet ? '' : 'needs control (the token)';
    const button = el('button.small.set', {
      type: 'button',
      disabled: !editable,
      title: why || `Set ${f.key} of ${m.name}`,
      onclick: () => this._set(robot, String(m.name), f, input, error),
    }, 'Set');
    input.addEventListener('keydown', (ev) => {
      if (ev.key === 'Enter' && editable) this._set(robot, String(m.name), f, input, error);
    });
    return el(`div.param-row${f.read_only ? '.read-only' : ''}`, { dataset: { key: String(f.key) } },
      el('label', { title: f.doc || '' }, el('span.param-key', null, String(f.key)), el('small', null, f.type ? ` ${String(f.type).replace(/`/g, '')}` : '')),
      el('span.param-field', null, input, button),
      el('small.param-hint', null, [bounds(f), f.doc, why].filter(Boolean).join(' · ')),
      error);
  }

  _value(f, input) {
    switch (f.input) {
      case 'number':
      case 'integer':
        return input.value.trim() === '' ? null : Number(input.value);
      case 'boolean':
        return input.checked;
      default:
        return input.value;
    }
  }

  async _set(robot, module, f, input, error) {
    const value = this._value(f, input);
    error.textContent = '';
    if (value === null || (typeof value === 'number' && !Number.isFinite(value))) {
      error.textContent = `${f.key}: a number, please`;
      return;
    }
    try {
      await this.conn.request({ op: 'set_param', robot, module, key: String(f.key), value });
      this.toast(`${module}.${f.key} = ${show(value)}`);
      this.refresh();
    } catch (e) {
      error.textContent = e.message;
      this.toast(`${module}.${f.key} refused: ${e.message}`, 'error');
    }
  }
}
