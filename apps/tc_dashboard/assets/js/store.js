// The page's state: the latest value of every telemetry stream, the robots,
// the world, the connection, and a tiny event bus the panels listen on.

const ROBOT_TAGS = new Set([
  'sim_pose', 'pose', 'odom', 'laser', 'sonar', 'lps', 'plan', 'activation', 'control',
  'robot', 'bumper', 'beacons', 'drive', 'teleop', 'estop',
]);

export class Store {
  constructor() {
    this.connected = false;
    /** null, or why the server refused the socket (a token missing or wrong, an origin not allowed). */
    this.refused = null;
    /** whether this client may teleoperate, send goals, release the E-stop, restart modules */
    this.canControl = false;
    this.welcomed = false;
    this.robots = [];
    this.selected = null;
    /** the robot named in the page's URL (?robot=), selected when it shows up */
    this.wanted = new URLSearchParams(location.search).get('robot');
    this.world = null;
    /** key "tag/id" → payload */
    this.items = new Map();
    this.frames = 0;
    this.fps = 0;
    this.lastTelemetry = null;
    this.lastTelemetryAt = null;
    this.rtt = null;
    this._frameTimes = [];
    this._handlers = new Map();
  }

  on(event, fn) {
    if (!this._handlers.has(event)) this._handlers.set(event, new Set());
    this._handlers.get(event).add(fn);
    return () => this._handlers.get(event).delete(fn);
  }

  emit(event, detail) {
    for (const fn of this._handlers.get(event) || []) {
      try {
        fn(detail);
      } catch (e) {
        console.error(`handler of ${event} failed`, e);
      }
    }
  }

  get(key) {
    return this.items.get(key);
  }

  /** The latest payload of tag for robot id (or the selected robot). */
  robotItem(tag, id = this.selected) {
    return id ? this.items.get(`${tag}/${id}`) : undefined;
  }

  welcome(msg) {
    this.welcomed = true;
    this.refused = null;
    this.canControl = !!msg.control;
    this.world = msg.world || null;
    this.items.clear();
    for (const r of msg.robots || []) this.addRobot(String(r));
    this.emit('welcome', msg);
    this.emit('world', this.world);
    this.emit('status');
  }

  addRobot(id) {
    if (this.robots.includes(id)) return;
    this.robots.push(id);
    this.robots.sort();
    // the robot the URL names (?robot=r2), else the first one known
    if (!this.selected || (id === this.wanted && this.selected !== id)) {
      this.selected = id;
      this.emit('select', id);
    }
    this.emit('robots', this.robots);
  }

  select(id) {
    if (!this.robots.includes(id) || this.selected === id) return;
    this.selected = id;
    this.wanted = id;
    this.emit('robots', this.robots);
    this.emit('select', id);
    this.emit('status');
  }

  telemetry(msg) {
    const changed = [];
    for (const [key, value] of Object.entries(msg.items || {})) {
      if (value === null) this.items.delete(key);
      else this.items.set(key, value);
      changed.push(key);
      const slash = key.indexOf('/');
      if (slash > 0 && ROBOT_TAGS.has(key.slice(0, slash))) this.addRobot(key.slice(slash + 1));
    }
    this.frames += 1;
    this.lastTelemetry = msg;
    this.lastTelemetryAt = performance.now();
    this._frameTimes.push(this.lastTelemetryAt);
    this.emit('telemetry', changed);
  }

  /** Telemetry frames received over the last second (called on a timer). */
  updateFps() {
    const now = performance.now();
    while (this._frameTimes.length && now - this._frameTimes[0] > 1000) this._frameTimes.shift();
    this.fps = this._frameTimes.length;
  }

  setConnected(connected) {
    this.connected = connected;
    if (!connected) {
      this._frameTimes = [];
      this.fps = 0;
    }
    this.emit('status');
  }

  setRefused(reason) {
    this.refused = reason;
    this.emit('status');
  }

  /** Who drives the selected robot: "autonomy", "teleop", "estop", "idle" (null when unknown). */
  get control() {
    const c = this.robotItem('control');
    return c && c.mode ? String(c.mode) : null;
  }
}
