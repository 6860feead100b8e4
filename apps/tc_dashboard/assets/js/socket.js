// The WebSocket to the dashboard server (apps/tc_dashboard/PROTOCOL.md):
// connects with the page's own ?token=, reconnects with backoff, answers
// requests by id, and tells the store what happened.

export class Connection {
  /**
   * @param {import('./store.js').Store} store
   */
  constructor(store) {
    this.store = store;
    this.token = new URLSearchParams(location.search).get('token');
    this.ws = null;
    this.nextId = 1;
    this.pending = new Map();
    this.backoff = 500;
    this.opened = false;
    this.handlers = new Map();
    this._pingTimer = null;
  }

  get url() {
    const scheme = location.protocol === 'https:' ? 'wss' : 'ws';
    const q = this.token ? `?token=${encodeURIComponent(this.token)}` : '';
    return `${scheme}://${location.host}/ws${q}`;
  }

  /** Registers a handler for server messages of one op. */
  onOp(op, fn) {
    this.handlers.set(op, fn);
  }

  connect() {
    let ws;
    try {
      ws = new WebSocket(this.url);
    } catch (e) {
      this._retry();
      return;
    }
    this.ws = ws;
    this.opened = false;
    ws.onopen = () => {
      this.opened = true;
      this.backoff = 500;
      this.store.setConnected(true);
      this._pingTimer = setInterval(() => this.ping(), 2000);
    };
    ws.onmessage = (ev) => this._message(ev.data);
    ws.onclose = () => {
      clearInterval(this._pingTimer);
      const wasOpen = this.opened;
      this.ws = null;
      this.store.setConnected(false);
      for (const [, p] of this.pending) p.reject(new Error('disconnected'));
      this.pending.clear();
      if (!wasOpen) this._diagnose();
      this._retry();
    };
  }

  _retry() {
    const delay = this.backoff;
    this.backoff = Math.min(this.backoff * 2, 5000);
    setTimeout(() => this.connect(), delay);
  }

  // A socket that never opened was refused, or the server is down: a plain
  // GET of the same URL says which (401/403 carry the server's reason).
  async _diagnose() {
    try {
      const res = await fetch(this.url.replace(/^ws/, 'http'), { cache: 'no-store' });
      if (res.status === 401 || res.status === 403) {
        const text = (await res.text()).trim();
        this.store.setRefused(text || `refused (HTTP ${res.status})`);
      } else if (res.status >= 500) {
        this.store.setRefused(null);
      }
    } catch (e) {
      // the server is down: not a refusal
      this.store.setRefused(null);
    }
  }

  _message(data) {
    let msg;
    try {
      msg = JSON.parse(data);
    } catch (e) {
      console.warn('dashboard: a message that is not JSON', data);
      return;
    }
    switch (msg.op) {
      case 'welcome':
        this.store.welcome(msg);
        break;
      case 'telemetry':
        this.store.telemetry(msg);
        // the server holds further frames while five are unacknowledged, so
        // a busy page is sent fewer, fresher frames rather than a backlog
        if (Number.isInteger(msg.seq)) this.send({ op: 'ack', seq: msg.seq });
        break;
      case 'pong': {
        const p = this.pending.get(msg.id);
        if (p && p.sentAt) this.store.rtt = performance.now() - p.sentAt;
        break;
      }
      default:
        break;
    }
    if (msg.id !== undefined && msg.id !== null && this.pending.has(msg.id)) {
      const p = this.pending.get(msg.id);
      this.pending.delete(msg.id);
      if (msg.op === 'error') p.reject(new Error(msg.message || 'refused'));
      else p.resolve(msg);
    }
    const h = this.handlers.get(msg.op);
    if (h) h(msg);
    if (msg.op === 'error') this.store.emit('server-error', msg);
  }

  /** Sends a message; false when not connected. */
  send(msg) {
    if (!this.ws || this.ws.readyState !== WebSocket.OPEN) return false;
    this.ws.send(JSON.stringify(msg));
    return true;
  }

  /** Sends a message with a fresh id; resolves with the reply (ok/result/pong), rejects on error. */
  request(msg, { timeout = 5000 } = {}) {
    const id = `c${this.nextId++}`;
    return new Promise((resolve, reject) => {
      const entry = { resolve, reject, sentAt: performance.now() };
      if (!this.send({ ...msg, id })) {
        reject(new Error('not connected'));
        return;
      }
      this.pending.set(id, entry);
      setTimeout(() => {
        if (this.pending.get(id) === entry) {
          this.pending.delete(id);
          reject(new Error('no reply'));
        }
      }, timeout);
    });
  }

  ping() {
    this.request({ op: 'ping' }, { timeout: 4000 }).catch(() => {});
  }
}
