// The Blackboard inspector: read every tuple matching a template
// (`query`), or follow a template live (`tail`, at most 20 tuples a second
// per tail, as the server sends them).
//
// A template is written as the tuple's positions separated by commas
// (`pose, r1, _`) or as a JSON array (`["pose", "_", "_"]`): `_` matches
// anything; numbers are numbers; true/false/null are JSON's.

import { el, setChildren } from './util.js';

const MAX_TAIL = 200;
const MAX_TEXT = 4000;

/** The JSON template a text asks for; throws on a malformed one. */
export function parseTemplate(text) {
  const t = text.trim();
  if (!t) throw new Error('empty template');
  if (t.startsWith('[')) {
    const v = JSON.parse(t);
    if (!Array.isArray(v) || !v.length) throw new Error('a template is a non-empty array');
    return v;
  }
  const body = t.replace(/^\{/, '').replace(/\}$/, '');
  return body.split(',').map((s) => s.trim()).map((s) => {
    if (s === '_' || s === ':_') return '_';
    if (/^-?\d+(\.\d+)?(e-?\d+)?$/i.test(s)) return Number(s);
    if (s === 'true' || s === 'false' || s === 'null') return JSON.parse(s);
    return s.replace(/^:/, '').replace(/^"(.*)"$/, '$1');
  });
}

function tupleView(tuple, stamp) {
  const parts = Array.isArray(tuple) ? tuple : [tuple];
  const [tag, id, ...rest] = parts;
  let text = JSON.stringify(rest.length === 1 ? rest[0] : rest, null, 2);
  if (text && text.length > MAX_TEXT) text = `${text.slice(0, MAX_TEXT)}\n… (${text.length - MAX_TEXT} more characters)`;
  const summary = el('summary', null,
    stamp ? el('span.time', null, stamp) : null,
    el('span.tag', null, String(tag)),
    id !== undefined ? el('span.id', null, typeof id === 'object' ? JSON.stringify(id) : String(id)) : null,
    el('span.preview', null, (JSON.stringify(rest.length === 1 ? rest[0] : rest) || '').slice(0, 120)));
  return el('details.tuple', null, summary, el('pre', null, text));
}

export class BlackboardPanel {
  constructor(root, store, conn) {
    this.root = root;
    this.store = store;
    this.conn = conn;
    this.tailId = null;
    this.tailCount = 0;
    this.paused = false;
    this.input = el('input.template#bb-template', {
      type: 'text', spellcheck: 'false', autocomplete: 'off', value: 'pose, _, _',
      placeholder: 'tag, id, _   or   ["tag","_","_"]',
      'aria-label': 'Template',
    });
    this.queryBtn = el('button#bb-query', { type: 'button' }, 'Query');
    this.tailBtn = el('button#bb-tail', { type: 'button' }, 'Tail');
    this.pauseBtn = el('button#bb-pause', { type: 'button', disabled: true }, 'Pause');
    this.status = el('div.bb-status');
    this.suggest = el('div.chips');
    this.results = el('div.bb-results#bb-results');
    this.input.addEventListener('keydown', (e) => {
      if (e.key === 'Enter') {
        e.preventDefault();
        this.query();
      }
    });
    this.queryBtn.addEventListener('click', () => this.query());
    this.tailBtn.addEventListener('click', () => (this.tailId ? this.untail() : this.tail()));
    this.pauseBtn.addEventListener('click', () => {
      this.paused = !this.paused;
      this.pauseBtn.textContent = this.paused ? 'Resume' : 'Pause';
    });
    setChildren(root,
      el('h2', null, 'Blackboard'),
      el('form.bb-form', { onsubmit: (e) => e.preventDefault() }, this.input, this.queryBtn, this.tailBtn, this.pauseBtn),
      this.suggest, this.status, this.results);
    conn.onOp('tuple', (msg) => this._tuple(msg));
    store.on('status', () => {
      if (!store.connected && this.tailId) this._tailEnded('disconnected');
    });
    store.on('telemetry', () => this._suggestions());
  }

  _suggestions() {
    const tags = new Set();
    for (const k of this.store.items.keys()) tags.add(k.split('/')[0]);
    const key = [...tags].sort().join(',');
    if (key === this._tagsKey) return;
    this._tagsKey = key;
    setChildren(this.suggest, [...tags].sort().map((t) => el('button.chip', {
      type: 'button',
      onclick: () => {
        this.input.value = `${t}, _, _`;
        this.query();
      },
    }, t)));
  }

  _setStatus(text, kind = '') {
    this.status.className = `bb-status ${kind}`;
    this.status.textContent = text;
  }

  async query() {
    let template;
    try {
      template = parseTemplate(this.input.value);
    } catch (e) {
      this._setStatus(`Template: ${e.message}`, 'error');
      return;
    }
    if (this.tailId) this.untail();
    this._setStatus('Querying…');
    const t0 = performance.now();
    try {
      const reply = await this.conn.request({ op: 'query', template });
      const tuples = reply.tuples || [];
      this._setStatus(`${tuples.length} tuple${tuples.length === 1 ? '' : 's'} match ${JSON.stringify(template)} (${(performance.now() - t0).toFixed(0)} ms)`);
      setChildren(this.results, tuples.map((tp) => tupleView(tp)));
    } catch (e) {
      this._setStatus(`Query refused: ${e.message}`, 'error');
    }
  }

  async tail() {
    let template;
    try {
      template = parseTemplate(this.input.value);
    } catch (e) {
      this._setStatus(`Template: ${e.message}`, 'error');
      return;
    }
    const id = `tail${Date.now()}`;
    this.tailId = id;
    this.tailCount = 0;
    this.paused = false;
    this.results.replaceChildren();
    this.tailBtn.textContent = 'Stop';
    this.tailBtn.classList.add('on');
    this.pauseBtn.disabled = false;
    this.pauseBtn.textContent = 'Pause';
    this._setStatus(`Tailing ${JSON.stringify(template)}…`, 'live');
    if (!this.conn.send({ op: 'tail', id, template })) this._tailEnded('not connected');
  }

  untail() {
    if (this.tailId) this.conn.send({ op: 'untail', id: this.tailId });
    this._tailEnded(`${this.tailCount} tuples received`);
  }

  _tailEnded(why) {
    this.tailId = null;
    this.tailBtn.textContent = 'Tail';
    this.tailBtn.classList.remove('on');
    this.pauseBtn.disabled = true;
    this._setStatus(`Tail stopped: ${why}`);
  }

  _tuple(msg) {
    if (msg.id !== this.tailId) return;
    this.tailCount += 1;
    if (this.paused) return;
    const d = new Date();
    const stamp = `${d.toTimeString().slice(0, 8)}.${String(d.getMilliseconds()).padStart(3, '0')}`;
    this.results.prepend(tupleView(msg.tuple, stamp));
    while (this.results.childElementCount > MAX_TAIL) this.results.lastElementChild.remove();
    this._setStatus(`Tailing: ${this.tailCount} tuples`, 'live');
  }

  /** A server error about our tail ends it. */
  error(msg) {
    if (msg.id && msg.id === this.tailId) this._tailEnded(msg.message);
  }
}
