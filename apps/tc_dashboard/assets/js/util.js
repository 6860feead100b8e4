// Small helpers shared by the page's modules: DOM building, number
// formatting, and reading blackboard payloads whatever shape the server's
// JSON encoding gave them (Elixir keyword lists arrive as [[key, value], ...]).

/** Creates an element: el('div.card#id', {title: 'x'}, child, 'text', ...). */
export function el(spec, attrs, ...children) {
  const [tagAndClasses, id] = spec.split('#');
  const [tag, ...classes] = tagAndClasses.split('.');
  const node = document.createElement(tag || 'div');
  if (id) node.id = id;
  if (classes.length) node.className = classes.join(' ');
  if (attrs) {
    for (const [k, v] of Object.entries(attrs)) {
      if (v === undefined || v === null || v === false) continue;
      if (k.startsWith('on') && typeof v === 'function') node.addEventListener(k.slice(2), v);
      else if (k === 'dataset') Object.assign(node.dataset, v);
      else if (k === 'text') node.textContent = v;
      else node.setAttribute(k, v === true ? '' : v);
    }
  }
  for (const c of children.flat()) {
    if (c === null || c === undefined || c === false) continue;
    node.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return node;
}

export const $ = (sel, root = document) => root.querySelector(sel);

/** Replaces a node's children. */
export function setChildren(node, ...children) {
  node.replaceChildren(...children.flat().filter((c) => c !== null && c !== undefined));
}

/** A plain object from an object or a keyword list ([[k, v], ...]); else null. */
export function obj(v) {
  if (v && typeof v === 'object' && !Array.isArray(v)) return v;
  if (Array.isArray(v) && v.every((p) => Array.isArray(p) && p.length === 2 && typeof p[0] === 'string')) {
    return Object.fromEntries(v);
  }
  return null;
}

/** A 2D point [x, y] from [x, y], [x, y, th] or {x, y}. */
export function pt(v) {
  if (Array.isArray(v) && v.length >= 2 && typeof v[0] === 'number') return [v[0], v[1]];
  if (v && typeof v.x === 'number') return [v.x, v.y];
  return null;
}

/** A pose [x, y, th] from [x, y, th] or {x, y, theta}. */
export function pose3(v) {
  if (Array.isArray(v) && v.length >= 2 && typeof v[0] === 'number') return [v[0], v[1], v[2] || 0];
  if (v && typeof v.x === 'number') return [v.x, v.y, v.theta ?? v.th ?? 0];
  return null;
}

export function fmt(x, digits = 2) {
  if (x === null || x === undefined || Number.isNaN(x)) return '–';
  if (typeof x !== 'number') return String(x);
  return x.toFixed(digits);
}

/** Microseconds, readable: 850 µs, 3.2 ms, 1.20 s. */
export function fmtUs(us) {
  if (us === null || us === undefined || Number.isNaN(us)) return '–';
  const a = Math.abs(us);
  if (a < 1000) return `${us.toFixed(a < 10 ? 1 : 0)} µs`;
  if (a < 1e6) return `${(us / 1000).toFixed(a < 1e4 ? 2 : 1)} ms`;
  return `${(us / 1e6).toFixed(2)} s`;
}

export const clamp = (x, lo, hi) => Math.min(hi, Math.max(lo, x));

/** Epoch milliseconds with sub-millisecond precision. */
export const epochMs = () => performance.timeOrigin + performance.now();

/** A short, readable form of a drive command (["velocity", v, w], "stop", ...). */
export function fmtCommand(c) {
  if (c === null || c === undefined) return '–';
  if (typeof c === 'string') return c;
  if (Array.isArray(c)) {
    const [kind, ...args] = c;
    if (kind === 'velocity') return `v ${fmt(args[0])} m/s · ω ${fmt(args[1])} rad/s`;
    return `${kind} ${args.map((a) => (typeof a === 'number' ? fmt(a) : JSON.stringify(a))).join(' ')}`;
  }
  return JSON.stringify(c);
}

/** Robot colours, by index. */
export const PALETTE = ['#4fc3f7', '#ffb74d', '#81c784', '#ba68c8', '#f06292', '#4dd0e1', '#dce775', '#ff8a65', '#9575cd', '#a1887f'];
