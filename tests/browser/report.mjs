// Browser test of a calibration report page: headless Chromium (Debian's,
// through playwright-core) opens the self-contained HTML file from disk,
// waits until every <div class="chart"> holds a drawn uPlot canvas (with
// coloured pixels, i.e. data, not only axes) or its "no data" text, and
// saves a full-page screenshot.
//
//   node tests/browser/report.mjs --html FILE.html --screenshot OUT.png
//       [--timeout-s 30] [--chromium /usr/bin/chromium] [--expect-charts N]
//
// --expect-charts N: exactly N charts must be drawn as plots (charts showing
// "no data" are counted apart). Fails on any console error or warning, any
// uncaught page error, any request other than the file itself (requests to
// anything but file: or data: are also aborted), a visible report error, and
// an empty screenshot. Exit 0 when all held, 1 with the reasons on stderr,
// 2 on a bad command line.
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { pathToFileURL } from 'node:url';
import { chromium } from 'playwright-core';

function parseArgs(argv) {
  const args = { html: null, screenshot: null, timeoutS: 30, chromium: '/usr/bin/chromium',
    expectCharts: null };
  for (let i = 0; i < argv.length; i++) {
    const value = () => {
      if (i + 1 >= argv.length) usage(`${argv[i]} needs a value`);
      return argv[++i];
    };
    switch (argv[i]) {
      case '--html': args.html = value(); break;
      case '--screenshot': args.screenshot = value(); break;
      case '--timeout-s': args.timeoutS = Number(value()); break;
      case '--chromium': args.chromium = value(); break;
      case '--expect-charts': args.expectCharts = Number(value()); break;
      default: usage(`unknown argument ${argv[i]}`);
    }
  }
  if (!args.html || !args.screenshot) usage('--html and --screenshot are required');
  if (!(args.timeoutS > 0)) usage('--timeout-s must be a positive number');
  const n = args.expectCharts;
  if (n !== null && !(Number.isInteger(n) && n >= 0)) {
    usage('--expect-charts must be a whole number');
  }
  if (!fs.existsSync(args.html)) usage(`no such file: ${args.html}`);
  return args;
}

function usage(problem) {
  console.error(`report.mjs: ${problem}\n` +
    'usage: node tests/browser/report.mjs --html FILE.html --screenshot OUT.png ' +
    '[--timeout-s S] [--chromium PATH] [--expect-charts N]');
  process.exit(2);
}

// In the page: the state of every div.chart. A canvas counts as drawn when
// it has pixels of some colour (axes, grid and text are grey; the palette
// is not), so an empty frame with axes does not pass.
function inspectCharts() {
  const charts = [...document.querySelectorAll('div.chart')];
  return charts.map((el) => {
    const id = el.id || '(no id)';
    const error = el.querySelector('.report-error');
    if (error) return { id, state: 'error', detail: error.textContent };
    const canvas = el.querySelector('.uplot canvas');
    if (canvas) {
      if (!canvas.width || !canvas.height) {
        return { id, state: 'pending', detail: 'canvas has no size' };
      }
      // Read a copy: one readback per fresh context, so polling does not make
      // Chromium warn about repeated getImageData on the plot's own canvas.
      const copy = document.createElement('canvas');
      copy.width = canvas.width;
      copy.height = canvas.height;
      const ctx = copy.getContext('2d', { willReadFrequently: true });
      ctx.drawImage(canvas, 0, 0);
      const px = ctx.getImageData(0, 0, copy.width, copy.height).data;
      let inked = 0;
      let coloured = 0;
      for (let i = 0; i < px.length; i += 4) {
        if (px[i + 3] < 16) continue;
        inked++;
        const r = px[i], g = px[i + 1], b = px[i + 2];
        if (Math.max(r, g, b) - Math.min(r, g, b) > 48) coloured++;
      }
      const detail =
        `${canvas.width}×${canvas.height} px canvas, ${inked} inked, ${coloured} coloured`;
      return { id, state: coloured > 0 ? 'drawn' : 'pending', detail };
    }
    if (/no data/i.test(el.textContent)) {
      return { id, state: 'empty', detail: el.textContent.trim() };
    }
    return { id, state: 'pending', detail: 'neither a plot nor "no data"' };
  });
}

// PNG signature, then the IHDR chunk's width and height.
function checkPng(file) {
  const buf = fs.readFileSync(file);
  const signature = Buffer.from([0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a]);
  if (buf.length < 33 || !buf.subarray(0, 8).equals(signature) ||
      buf.toString('latin1', 12, 16) !== 'IHDR') {
    return `screenshot ${file} is not a PNG (${buf.length} bytes)`;
  }
  const width = buf.readUInt32BE(16);
  const height = buf.readUInt32BE(20);
  if (!width || !height || buf.length < 1000) {
    return `screenshot ${file} is empty: ${width}×${height}, ${buf.length} bytes`;
  }
  return null;
}

const args = parseArgs(process.argv.slice(2));
const pageUrl = pathToFileURL(path.resolve(args.html)).href;
const failures = [];
const requests = [];
let aborted = 0;

const userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), 'gyrotherm-chromium-'));
let context = null;
let summary = null;
try {
  // A fresh profile (--user-data-dir) each run; a desktop screen 1280 px wide.
  context = await chromium.launchPersistentContext(userDataDir, {
    executablePath: args.chromium,
    headless: true,
    args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
      '--disable-background-networking', '--disable-component-update', '--disable-sync'],
    viewport: { width: 1280, height: 900 },
  });
  const page = context.pages()[0] ?? await context.newPage();

  page.on('console', (msg) => {
    if (msg.type() === 'error' || msg.type() === 'warning') {
      const where = msg.location();
      const at = where && where.url ? ` (${path.basename(where.url)}:${where.lineNumber})` : '';
      failures.push(`console ${msg.type()}: ${msg.text()}${at}`);
    }
  });
  page.on('pageerror', (err) => failures.push(`page error: ${err.message}`));
  page.on('request', (req) => {
    requests.push(req.url());
    const u = req.url();
    if (u.split('#')[0] !== pageUrl) failures.push(`request other than the page: ${u}`);
  });
  page.on('requestfailed', (req) => {
    failures.push(`request failed: ${req.url()}: ${req.failure()?.errorText}`);
  });
  await context.route('**/*', (route) => {
    const protocol = new URL(route.request().url()).protocol;
    if (protocol === 'file:' || protocol === 'data:') return route.continue();
    aborted++;
    return route.abort('blockedbyclient');
  });

  const deadline = Date.now() + args.timeoutS * 1000;
  await page.goto(pageUrl, { waitUntil: 'load', timeout: args.timeoutS * 1000 });

  // Poll until no chart is pending; no fixed sleeps.
  let charts = [];
  for (;;) {
    charts = await page.evaluate(inspectCharts);
    const pending = charts.filter((c) => c.state === 'pending');
    if (!pending.length || failures.length) break;
    if (Date.now() > deadline) {
      failures.push(`charts not drawn within ${args.timeoutS} s: ` +
        pending.map((c) => `${c.id} (${c.detail})`).join('; '));
      break;
    }
    await page.waitForTimeout(100);
  }

  if (!charts.length) failures.push('the page has no <div class="chart">');
  for (const c of charts.filter((c) => c.state === 'error')) {
    failures.push(`chart ${c.id} shows an error: ${c.detail}`);
  }
  const pageErrors = await page.evaluate(() =>
    [...document.querySelectorAll('.report-error')].map((e) => e.textContent));
  for (const e of pageErrors) {
    if (!charts.some((c) => c.state === 'error' && c.detail === e)) {
      failures.push(`page shows: ${e}`);
    }
  }
  const drawn = charts.filter((c) => c.state === 'drawn');
  const empty = charts.filter((c) => c.state === 'empty');
  if (args.expectCharts !== null && drawn.length !== args.expectCharts) {
    failures.push(`${drawn.length} charts drawn, expected ${args.expectCharts} ` +
      `(drawn: ${drawn.map((c) => c.id).join(', ') || 'none'}; ` +
      `no data: ${empty.map((c) => c.id).join(', ') || 'none'})`);
  }

  await page.evaluate(() => new Promise((r) => requestAnimationFrame(() => r())));
  await page.screenshot({ path: args.screenshot, fullPage: true });
  const pngProblem = checkPng(args.screenshot);
  if (pngProblem) failures.push(pngProblem);
  const ids = (list) => (list.length ? ` (${list.map((c) => c.id).join(', ')})` : '');
  summary = `${drawn.length} charts drawn${ids(drawn)}, ` +
    `${empty.length} with no data${ids(empty)}; ` +
    `${requests.length} request(s); screenshot ${args.screenshot}`;
} catch (err) {
  failures.push(`browser: ${err.message}`);
} finally {
  if (context) await context.close().catch(() => {});
  fs.rmSync(userDataDir, { recursive: true, force: true });
}

if (aborted) failures.push(`${aborted} request(s) to the network aborted`);
if (failures.length) {
  console.error('report test FAILED:\n  ' + [...new Set(failures)].join('\n  '));
  process.exit(1);
}
console.log(`report page ok: ${summary}`);
process.exit(0);
