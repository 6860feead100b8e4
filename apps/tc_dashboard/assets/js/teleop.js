// Teleoperation: the arrow keys or WASD, an on-screen joystick, or a
// gamepad (Gamepad API) drive the selected robot. While any of them is
// held the page sends `teleop` every 100 ms (the server lets a command
// expire 300 ms after its last refresh: the deadman rule), and on letting
// go it sends `teleop_release` at once, so autonomy resumes (or the robot
// stops). Full scale is the robot's RDF limits (`robot/<id>`.limits)
// times the speed slider; Shift gives full scale. Space (or the gamepad's
// B button) is the E-stop.

import { clamp, el, epochMs, fmt, obj, setChildren } from './util.js';

export const REFRESH_MS = 100;
const DEADZONE = 0.15;

const KEYS = {
  ArrowUp: 'up', KeyW: 'up',
  ArrowDown: 'down', KeyS: 'down',
  ArrowLeft: 'left', KeyA: 'left',
  ArrowRight: 'right', KeyD: 'right',
};

function keyDirection(e) {
  return KEYS[e.code] || KEYS[e.key] || null;
}

function typingIn(target) {
  if (!target || !(target instanceof Element)) return false;
  if (target.isContentEditable) return true;
  if (target.tagName === 'TEXTAREA' || target.tagName === 'SELECT') return true;
  return target.tagName === 'INPUT' && !['range', 'checkbox', 'radio', 'button'].includes(target.type);
}

export class Teleop {
  constructor(root, store, conn, toast) {
    this.root = root;
    this.store = store;
    this.conn = conn;
    this.toast = toast;
    /** held directions (up/down/left/right) by the key code holding them */
    this.held = new Map();
    this.shift = false;
    this.joy = { x: 0, y: 0, active: false };
    this.pad = { x: 0, y: 0, active: false, index: null, estopWas: false };
    this.scale = 0.5;
    this.timer = null;
    /** the robot being driven, while a command is held */
    this.robot = null;
    /** the command being sent: {v, w, source} or null */
    this.command = null;
    this.sent = 0;
    this._build();
    this._bindKeys();
    this._bindGamepad();
    store.on('telemetry', (keys) => {
      if (keys.includes(`robot/${store.selected}`)) this._renderLimits();
      if (keys.includes(`control/${store.selected}`)) this._renderAccess();
    });
    store.on('select', () => {
      this.releaseAll();
      this._renderLimits();
      this._renderAccess();
    });
    store.on('status', () => this._renderAccess());
    this._renderLimits();
    this._renderAccess();
  }

  // ---- the panel -------------------------------------------------------------

  _build() {
    this.knob = el('div.knob');
    this.stick = el('div.joystick#joystick', { title: 'Drag to drive: up is forward, left turns left' }, el('div.cross'), this.knob);
    this.slider = el('input#speed', { type: 'range', min: '10', max: '100', step: '5', value: String(this.scale * 100), 'aria-label': 'Speed limit (% of the RDF limits)' });
    this.sliderValue = el('output', null, `${Math.round(this.scale * 100)}%`);
    this.slider.addEventListener('input', () => {
      this.scale = Number(this.slider.value) / 100;
      this.sliderValue.textContent = `${this.slider.value}%`;
      this._update();
    });
    this.slider.addEventListener('change', () => this.slider.blur());
    this.vBar = el('span.fill');
    this.wBar = el('span.fill');
    this.vText = el('span.mono');
    this.wText = el('span.mono');
    this.source = el('span.source#teleop-source', null, 'released');
    this.limits = el('div.limits');
    this.access = el('div.access');
    this.padText = el('span.pad-status', null, 'no gamepad');
    this.releaseBtn = el('button.release#estop-release', { type: 'button', title: 'Release the E-stop of the selected robot (needs control)' }, 'Release E-stop');
    this.releaseBtn.addEventListener('click', () => this.estopRelease());
    setChildren(this.root,
      el('div.teleop-grid', null,
        this.stick,
        el('div.teleop-readout', null,
          el('div.row', null, el('span.k', null, 'input'), this.source),
          el('div.row', null, el('span.k', null, 'v'), el('span.gauge', null, this.vBar), this.vText),
          el('div.row', null, el('span.k', null, 'ω'), el('span.gauge', null, this.wBar), this.wText),
          el('label.row.speed', null, el('span.k', null, 'speed'), this.slider, this.sliderValue),
          this.limits)),
      el('div.teleop-foot', null,
        el('span.keys', { title: 'Hold the arrow keys or WASD to drive; Shift for full scale; Space is the E-stop' },
          el('kbd', null, '↑↓←→'), '/', el('kbd', null, 'WASD'), ' drive · ', el('kbd', null, '⇧'), ' full · ', el('kbd', null, 'Space'), ' E-stop'),
        this.padText),
      this.access,
      this.releaseBtn);
    this._bindJoystick();
    this._renderCommand();
  }

  _limits() {
    const r = this.store.get(`robot/${this.robot || this.store.selected}`);
    const l = obj(r && r.limits) || {};
    return {
      v: typeof l.max_speed === 'number' && l.max_speed > 0 ? l.max_speed : 0.5,
      w: typeof l.max_turn_rate === 'number' && l.max_turn_rate > 0 ? l.max_turn_rate : 1.0,
      fromRdf: typeof l.max_speed === 'number',
    };
  }

  _renderLimits() {
    const l = this._limits();
    setChildren(this.limits,
      `full scale ${fmt(l.v)} m/s · ${fmt(l.w)} rad/s`,
      el('small', null, l.fromRdf ? ' (RDF limits)' : ' (defaults: no RDF limits yet)'));
  }

  _renderAccess() {
    const s = this.store;
    const mode = s.control;
    this.releaseBtn.hidden = mode !== 'estop';
    this.releaseBtn.disabled = !s.canControl;
    if (!s.connected) this.access.textContent = 'Not connected.';
    else if (!s.canControl) this.access.textContent = 'Read-only: teleoperation needs the access token. The E-stop works for everyone.';
    else this.access.textContent = '';
    this.access.hidden = !this.access.textContent;
    this.root.classList.toggle('disabled', !s.canControl || !s.connected);
  }

  _renderCommand() {
    const c = this.command;
    const l = this._limits();
    const v = c ? c.v : 0;
    const w = c ? c.w : 0;
    const bar = (node, x, max) => {
      const f = clamp(max ? x / max : 0, -1, 1);
      node.style.left = f >= 0 ? '50%' : `${50 + f * 50}%`;
      node.style.width = `${Math.abs(f) * 50}%`;
    };
    bar(this.vBar, v, l.v);
    bar(this.wBar, w, l.w);
    this.vText.textContent = `${v >= 0 ? ' ' : ''}${fmt(v)} m/s`;
    this.wText.textContent = `${w >= 0 ? ' ' : ''}${fmt(w)} rad/s`;
    this.source.textContent = c ? `${c.source} · held` : 'released';
    this.source.classList.toggle('held', !!c);
    this.root.classList.toggle('holding', !!c);
  }

  // ---- inputs ------------------------------------------------------------------

  _bindKeys() {
    window.addEventListener('keydown', (e) => {
      if (typingIn(e.target) || e.ctrlKey || e.metaKey || e.altKey) return;
      if (e.code === 'Space' || e.key === ' ') {
        e.preventDefault();
        if (!e.repeat) this.estopAll();
        return;
      }
      if (e.key === 'Shift') {
        this.shift = true;
        this._update();
        return;
      }
      const dir = keyDirection(e);
      if (!dir) return;
      e.preventDefault();
      if (e.repeat && this.held.has(e.code || e.key)) return;
      this.held.set(e.code || e.key, dir);
      this._update();
    });
    window.addEventListener('keyup', (e) => {
      if (e.key === 'Shift') {
        this.shift = false;
        this._update();
        return;
      }
      const code = e.code || e.key;
      if (this.held.delete(code)) {
        e.preventDefault();
        this._update();
      }
    });
    // a page that loses the keyboard loses its keys: never leave one held
    window.addEventListener('blur', () => this.releaseAll());
    document.addEventListener('visibilitychange', () => {
      if (document.hidden) this.releaseAll();
    });
  }

  _bindJoystick() {
    const stick = this.stick;
    let pointer = null;
    const move = (e) => {
      const r = stick.getBoundingClientRect();
      const radius = r.width / 2;
      let x = (e.clientX - (r.left + radius)) / radius;
      let y = (e.clientY - (r.top + radius)) / radius;
      const m = Math.hypot(x, y);
      if (m > 1) {
        x /= m;
        y /= m;
      }
      this.joy = { x, y, active: true };
      this.knob.style.transform = `translate(${x * radius * 0.7}px, ${y * radius * 0.7}px)`;
      this._update();
    };
    stick.addEventListener('pointerdown', (e) => {
      pointer = e.pointerId;
      stick.setPointerCapture(e.pointerId);
      stick.classList.add('active');
      move(e);
    });
    stick.addEventListener('pointermove', (e) => {
      if (e.pointerId === pointer) move(e);
    });
    const end = (e) => {
      if (e.pointerId !== pointer) return;
      pointer = null;
      stick.classList.remove('active');
      this.joy = { x: 0, y: 0, active: false };
      this.knob.style.transform = '';
      this._update();
    };
    stick.addEventListener('pointerup', end);
    stick.addEventListener('pointercancel', end);
    stick.addEventListener('lostpointercapture', end);
  }

  _bindGamepad() {
    if (!navigator.getGamepads) return;
    let polling = false;
    const poll = () => {
      const pads = [...navigator.getGamepads()].filter(Boolean);
      const gp = pads.find((p) => p.index === this.pad.index) || pads[0];
      if (!gp) {
        polling = false;
        this.pad = { x: 0, y: 0, active: false, index: null, estopWas: false };
        this.padText.textContent = 'no gamepad';
        this._update();
        return;
      }
      const dz = (a) => (Math.abs(a) < DEADZONE ? 0 : (a - Math.sign(a) * DEADZONE) / (1 - DEADZONE));
      const x = dz(gp.axes[0] || 0);
      const y = dz(gp.axes[1] || 0);
      const estop = !!(gp.buttons[1] && gp.buttons[1].pressed);
      if (estop && !this.pad.estopWas) this.estopAll();
      const active = x !== 0 || y !== 0;
      const changed = active !== this.pad.active || x !== this.pad.x || y !== this.pad.y;
      this.pad = { x, y, active, index: gp.index, estopWas: estop };
      this.padText.textContent = `🎮 ${gp.id.slice(0, 28)}${active ? ' · driving' : ''}`;
      if (changed) this._update();
      requestAnimationFrame(poll);
    };
    window.addEventListener('gamepadconnected', (e) => {
      this.pad.index = e.gamepad.index;
      this.toast(`Gamepad connected: ${e.gamepad.id}`);
      if (!polling) {
        polling = true;
        requestAnimationFrame(poll);
      }
    });
    window.addEventListener('gamepaddisconnected', () => {
      this.toast('Gamepad disconnected');
    });
  }

  // What the inputs ask for: the keyboard first, then the joystick, then the gamepad.
  _compute() {
    const l = this._limits();
    const k = this.shift ? 1 : this.scale;
    if (this.held.size) {
      const dirs = new Set(this.held.values());
      const f = (dirs.has('up') ? 1 : 0) - (dirs.has('down') ? 1 : 0);
      const t = (dirs.has('left') ? 1 : 0) - (dirs.has('right') ? 1 : 0);
      return { v: f * l.v * k, w: t * l.w * k, source: 'keyboard' };
    }
    if (this.joy.active) return { v: -this.joy.y * l.v * k, w: -this.joy.x * l.w * k, source: 'joystick' };
    if (this.pad.active) return { v: -this.pad.y * l.v * k, w: -this.pad.x * l.w * k, source: 'gamepad' };
    return null;
  }

  _update() {
    const cmd = this._compute();
    const robot = this.store.selected;
    if (cmd && robot && this.store.canControl && this.store.connected) {
      const changed = !this.command || this.robot !== robot
        || Math.abs(cmd.v - this.command.v) > 1e-6 || Math.abs(cmd.w - this.command.w) > 1e-6;
      if (this.robot && this.robot !== robot) this._release();
      this.command = cmd;
      this.robot = robot;
      if (changed || !this.timer) {
        // a new command goes out now, and is refreshed every 100 ms from now
        clearInterval(this.timer);
        this._send();
        this.timer = setInterval(() => this._send(), REFRESH_MS);
      }
    } else {
      if (cmd && !this.store.canControl && !this._warned) {
        this._warned = true;
        this.toast('Read-only: teleoperation needs the access token', 'error');
      }
      if (this.command) this._release();
    }
    this._renderCommand();
  }

  _send() {
    if (!this.command || !this.robot) return;
    const ok = this.conn.send({
      op: 'teleop',
      robot: this.robot,
      v: this.command.v,
      w: this.command.w,
      sent_at: epochMs(),
    });
    if (ok) this.sent += 1;
  }

  _release() {
    clearInterval(this.timer);
    this.timer = null;
    if (this.robot) this.conn.send({ op: 'teleop_release', robot: this.robot });
    this.command = null;
    this.robot = null;
  }

  /** Lets go of every input (and the robot) now. */
  releaseAll() {
    this.held.clear();
    this.shift = false;
    this.joy = { x: 0, y: 0, active: false };
    this.knob.style.transform = '';
    if (this.command) this._release();
    this._renderCommand();
  }

  /** The E-stop: every robot this page knows of. */
  estopAll() {
    this.releaseAll();
    const robots = this.store.robots.length ? this.store.robots : [this.store.selected].filter(Boolean);
    if (!robots.length) {
      this.toast('E-stop: no robot known', 'error');
      return;
    }
    let sent = 0;
    for (const r of robots) if (this.conn.send({ op: 'estop', robot: r })) sent += 1;
    if (sent) this.toast(`E-STOP sent to ${robots.join(', ')}`, 'error');
    else this.toast('E-stop NOT sent: not connected', 'error');
  }

  async estopRelease() {
    const r = this.store.selected;
    if (!r) return;
    try {
      await this.conn.request({ op: 'estop_release', robot: r });
      this.toast(`E-stop of ${r} released`);
    } catch (e) {
      this.toast(`E-stop release refused: ${e.message}`, 'error');
    }
  }
}
