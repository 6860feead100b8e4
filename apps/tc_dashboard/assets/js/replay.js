// One past instant of one robot, read like the live store (get(key),
// robots, selected, world) so that the map draws it with its own code:
// the frames of the black box's timeline (PROTOCOL.md, timeline_frame).
// The robot's capabilities and the world come from the live store when
// the frame has none (they do not change while a robot runs).

export class Replay {
  /**
   * @param {import('./store.js').Store} live
   * @param {string} robot
   */
  constructor(live, robot) {
    this.live = live;
    this.robot = robot;
    /** key "tag/robot" → payload at the instant shown */
    this.items = new Map();
    /** the map the items hold (the server leaves it out of a frame while it is this one) */
    this.mapId = null;
    /** the instant shown, ms since the epoch */
    this.at = null;
  }

  get(key) {
    if (this.items.has(key)) return this.items.get(key);
    return key === `robot/${this.robot}` ? this.live.get(key) : undefined;
  }

  get robots() {
    return [this.robot];
  }

  get selected() {
    return this.robot;
  }

  get world() {
    return this.live.world;
  }

  /** Takes in a frame: its items (null: nothing yet at that instant), the map kept when left out. */
  apply(frame) {
    for (const [key, value] of Object.entries(frame.items || {})) {
      if (value === null) this.items.delete(key);
      else this.items.set(key, value);
    }
    this.mapId = frame.map ?? null;
    if (this.mapId === null) this.items.delete(`map/${this.robot}`);
    this.at = frame.at;
  }
}
