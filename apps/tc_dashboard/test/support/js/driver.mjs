// A browser driven over stdin/stdout, for ExUnit tests and benchmarks:
// Debian's chromium through playwright-core. One JSON command a line in,
// one JSON answer a line out ({"id", "ok": true, "result"} or {"id",
// "ok": false, "error"}). Commands (`page` names a page, default "main"):
//
//   {"cmd":"open","url":U,"page":P}          a new page (its own browser context)
//   {"cmd":"eval","expr":JS}                 the value of a JS expression in the page
//   {"cmd":"wait","expr":JS,"timeout":MS}    until the expression is truthy; its value
//   {"cmd":"keydown","key":K} / "keyup"      hold / let go of a key (Playwright's names)
//   {"cmd":"press","key":K}                  press and release
//   {"cmd":"click","selector":S}             click an element
//   {"cmd":"mouse","x":X,"y":Y}              click at page coordinates
//   {"cmd":"mousedown","x":X,"y":Y} / "mousemove" (x, y, steps) / "mouseup"   drag
//   {"cmd":"screenshot","path":F}            a PNG of the page
//   {"cmd":"console"}                        console messages and page errors so far
//   {"cmd":"profile","ms":MS,"top":N}        the page's JavaScript CPU profile over MS:
//                                            {total_ms, by: [[function@file:line, self_ms]...]}
//                                            ("(idle)", "(program)": the renderer's own
//                                            work, "(garbage collector)" included)
//   {"cmd":"close","page":P}                 close one page
//   {"cmd":"quit"}                           close the browser and exit
//
// The browser is launched at start; the first line out is
// {"id":null,"ok":true,"result":"ready"}. When stdin closes the browser is
// closed too, so a test that dies never leaves a chromium behind.

import { createRequire } from 'node:module';
import { fileURLToPath } from 'node:url';
import path from 'node:path';
import readline from 'node:readline';

const here = path.dirname(fileURLToPath(import.meta.url));
const assets = process.env.TC_ASSETS || path.resolve(here, '../../../assets');
const require = createRequire(path.join(assets, 'package.json'));
const { chromium } = require('playwright-core');

const executablePath = process.env.CHROMIUM || '/usr/bin/chromium';
const pages = new Map();
const logs = new Map();
let browser;

function reply(id, ok, payload) {
  const msg = ok ? { id, ok: true, result: payload === undefined ? null : payload } : { id, ok: false, error: String(payload) };
  process.stdout.write(`${JSON.stringify(msg)}\n`);
}

function page(name = 'main') {
  const p = pages.get(name);
  if (!p) throw new Error(`no page ${name}`);
  return p;
}

async function run(c) {
  switch (c.cmd) {
    case 'open': {
      const name = c.page || 'main';
      if (pages.has(name)) await pages.get(name).context().close();
      const context = await browser.newContext({ viewport: { width: c.width || 1400, height: c.height || 860 } });
      const p = await context.newPage();
      const log = [];
      logs.set(name, log);
      p.on('console', (m) => log.push(`${m.type()}: ${m.text()}`));
      p.on('pageerror', (e) => log.push(`pageerror: ${e.message}`));
      pages.set(name, p);
      const res = await p.goto(c.url, { waitUntil: 'load', timeout: c.timeout || 15000 });
      return { status: res ? res.status() : null };
    }
    case 'eval':
      return await page(c.page).evaluate(c.expr);
    case 'wait': {
      const handle = await page(c.page).waitForFunction(c.expr, null, { timeout: c.timeout || 5000, polling: c.polling || 'raf' });
      return await handle.jsonValue();
    }
    case 'keydown':
      await page(c.page).keyboard.down(c.key);
      return null;
    case 'keyup':
      await page(c.page).keyboard.up(c.key);
      return null;
    case 'press':
      await page(c.page).keyboard.press(c.key);
      return null;
    case 'click':
      await page(c.page).click(c.selector, { timeout: c.timeout || 5000 });
      return null;
    case 'mouse':
      await page(c.page).mouse.click(c.x, c.y);
      return null;
    case 'mousedown': {
      const m = page(c.page).mouse;
      await m.move(c.x, c.y);
      await m.down();
      return null;
    }
    case 'mousemove':
      await page(c.page).mouse.move(c.x, c.y, { steps: c.steps || 1 });
      return null;
    case 'mouseup':
      await page(c.page).mouse.up();
      return null;
    case 'screenshot':
      await page(c.page).screenshot({ path: c.path, fullPage: false });
      return c.path;
    case 'console':
      return logs.get(c.page || 'main') || [];
    case 'profile':
      return await profile(page(c.page), c.ms || 3000, c.top || 15);
    case 'trace':
      return await trace(page(c.page), c.ms || 3000, c.top || 20);
    case 'close': {
      const p = pages.get(c.page || 'main');
      if (p) await p.context().close();
      pages.delete(c.page || 'main');
      return null;
    }
    case 'quit':
      await browser.close();
      reply(c.id, true, null);
      process.exit(0);
      return null;
    default:
      throw new Error(`unknown command ${c.cmd}`);
  }
}

// Self time per function from a CDP CPU profile (samples x their time deltas).
async function profile(p, ms, top) {
  const cdp = await p.context().newCDPSession(p);
  await cdp.send('Profiler.enable');
  await cdp.send('Profiler.start');
  await new Promise((r) => setTimeout(r, ms));
  const { profile: prof } = await cdp.send('Profiler.stop');
  await cdp.detach();
  const nodes = new Map(prof.nodes.map((n) => [n.id, n]));
  const self = new Map();
  let total = 0;
  prof.samples.forEach((id, i) => {
    const dt = (prof.timeDeltas[i] || 0) / 1000;
    const f = nodes.get(id).callFrame;
    const file = f.url ? f.url.split('/').pop() : '';
    const name = file ? `${f.functionName || '(anonymous)'}@${file}:${f.lineNumber + 1}` : f.functionName;
    self.set(name, (self.get(name) || 0) + dt);
    total += dt;
  });
  const by = [...self.entries()].sort((a, b) => b[1] - a[1]).slice(0, top).map(([n, t]) => [n, Math.round(t * 10) / 10]);
  return { total_ms: Math.round(total), by };
}

// Time per trace event name (devtools timeline) over MS, all threads.
async function trace(p, ms, top) {
  const cdp = await p.context().newCDPSession(p);
  const events = [];
  cdp.on('Tracing.dataCollected', (d) => events.push(...d.value));
  const done = new Promise((r) => cdp.once('Tracing.tracingComplete', r));
  await cdp.send('Tracing.start', { categories: 'devtools.timeline,disabled-by-default-devtools.timeline,v8', transferMode: 'ReportEvents' });
  await new Promise((r) => setTimeout(r, ms));
  await cdp.send('Tracing.end');
  await done;
  await cdp.detach();
  const threads = new Map();
  for (const e of events) if (e.ph === 'M' && e.name === 'thread_name') threads.set(`${e.pid}:${e.tid}`, e.args.name);
  const by = new Map();
  for (const e of events) {
    if (e.ph !== 'X' || !e.dur) continue;
    const k = `${threads.get(`${e.pid}:${e.tid}`) || e.tid} ${e.name}`;
    by.set(k, (by.get(k) || 0) + e.dur / 1000);
  }
  return [...by.entries()].sort((a, b) => b[1] - a[1]).slice(0, top).map(([n, t]) => [n, Math.round(t)]);
}

async function main() {
  browser = await chromium.launch({
    executablePath,
    headless: true,
    args: ['--no-sandbox', '--disable-gpu', '--disable-dev-shm-usage', '--disable-background-timer-throttling', '--disable-renderer-backgrounding', '--disable-backgrounding-occluded-windows'],
  });
  reply(null, true, 'ready');
  const rl = readline.createInterface({ input: process.stdin });
  // commands run one after another, in the order they came
  let chain = Promise.resolve();
  rl.on('line', (line) => {
    if (!line.trim()) return;
    let c;
    try {
      c = JSON.parse(line);
    } catch (e) {
      reply(null, false, `bad JSON: ${e.message}`);
      return;
    }
    chain = chain.then(() => run(c).then((r) => reply(c.id ?? null, true, r), (e) => reply(c.id ?? null, false, e.message)));
  });
  rl.on('close', async () => {
    try {
      await browser.close();
    } finally {
      process.exit(0);
    }
  });
}

main().catch((e) => {
  reply(null, false, `launch failed: ${e.message}`);
  process.exit(1);
});
