// Browser test of the station dashboard: headless Chromium (Debian's, through
// playwright-core) loads the page served by gyrothermd, waits until the live
// values move (station time changes twice, both plots hold points, some of
// them from the stream), checks the rate-table card is shown exactly when the
// status has a table, and saves a full-page screenshot.
//
//   node tests/browser/dashboard.mjs --url http://127.0.0.1:PORT/ --screenshot OUT.png
//       [--timeout-s 60] [--chromium /usr/bin/chromium] [--token TOKEN]
//
// With --token (a daemon with [api] read_access = "token"): the page must
// first answer the 401 by showing its token form; the test types the token
// in, and then also checks that every request to the API carried it as
// "Authorization: Bearer", none carried it in its URL, and the page kept it
// in sessionStorage only (not in localStorage, not in the page's HTML).
//
// Fails on any console error, uncaught page error, failed request, or request
// to a host other than the page's own. Exit 0 when all held, 1 with the
// reasons on stderr, 2 on a bad command line.
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { chromium } from 'playwright-core';

function parseArgs(argv) {
  const args = { url: null, screenshot: null, timeoutS: 60, chromium: '/usr/bin/chromium', token: null };
  for (let i = 0; i < argv.length; i++) {
    const value = () => {
      if (i + 1 >= argv.length) usage(`${argv[i]} needs a value`);
      return argv[++i];
    };
    switch (argv[i]) {
      case '--url': args.url = value(); break;
      case '--screenshot': args.screenshot = value(); break;
      case '--timeout-s': args.timeoutS = Number(value()); break;
      case '--chromium': args.chromium = value(); break;
      case '--token': args.token = value(); break;
      default: usage(`unknown argument ${argv[i]}`);
    }
  }
  if (!args.url || !args.screenshot) usage('--url and --screenshot are required');
  if (!(args.timeoutS > 0)) usage('--timeout-s must be a positive number');
  return args;
}

function usage(problem) {
  console.error(`dashboard.mjs: ${problem}\n` +
    'usage: node tests/browser/dashboard.mjs --url URL --screenshot OUT.png [--timeout-s S] ' +
    '[--chromium PATH] [--token TOKEN]');
  process.exit(2);
}

const args = parseArgs(process.argv.slice(2));
const origin = new URL(args.url).origin;
const failures = [];
let closing = false;  // the stream is cut when the page closes: not a fault
// With --token: 401s are expected until the token is typed in.
let tokenGiven = !args.token;
const apiRequests = [];  // [url, Authorization header, after the token was given]

const userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), 'gyrotherm-chromium-'));
let context = null;
try {
  // A fresh profile (--user-data-dir) each run; a lab monitor, 1920 × 1080.
  context = await chromium.launchPersistentContext(userDataDir, {
    executablePath: args.chromium,
    headless: true,
    args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
      '--disable-background-networking', '--disable-component-update', '--disable-sync'],
    viewport: { width: 1920, height: 1080 },
  });
  const page = context.pages()[0] ?? await context.newPage();

  page.on('console', (msg) => {
    if (msg.type() !== 'error' || closing) return;
    // The browser logs the expected 401 itself (a 401 after the token is
    // caught by the response check).
    if (args.token && msg.text().includes('401')) return;
    failures.push(`console error: ${msg.text()}`);
  });
  page.on('pageerror', (err) => failures.push(`page error: ${err.message}`));
  page.on('request', (req) => {
    const u = new URL(req.url());
    if (u.protocol === 'data:' || u.protocol === 'blob:') return;
    if (u.origin !== origin) failures.push(`request to another host: ${req.url()}`);
    if (args.token && req.url().includes(args.token)) failures.push(`token in a URL: ${req.url()}`);
    if (u.pathname.startsWith('/api/') || u.pathname === '/metrics') {
      apiRequests.push([u.pathname, req.headers().authorization ?? '', tokenGiven]);
    }
  });
  page.on('requestfailed', (req) => {
    if (!closing) failures.push(`request failed: ${req.url()}: ${req.failure()?.errorText}`);
  });
  page.on('response', (res) => {
    if (res.status() === 401 && !tokenGiven) return;
    if (res.status() >= 400) failures.push(`HTTP ${res.status()} for ${res.url()}`);
  });

  const deadline = Date.now() + args.timeoutS * 1000;
  const response = await page.goto(args.url, { waitUntil: 'load', timeout: args.timeoutS * 1000 });
  if (!response || !response.ok()) {
    failures.push(`page load: HTTP ${response ? response.status() : 'no response'}`);
  }

  if (args.token && failures.length === 0) {
    // The page asks for the token after its first 401.
    const form = page.locator('#token-form');
    await form.waitFor({ state: 'visible', timeout: args.timeoutS * 1000 });
    tokenGiven = true;
    await page.fill('#token-input', args.token);
    await page.click('#token-form button[type="submit"]');
    await form.waitFor({ state: 'hidden', timeout: 5000 });
  }

  // Poll the page until the live values moved; no fixed sleeps.
  const seen = new Set();
  let last = null;
  let done = false;
  while (!done && failures.length === 0 && Date.now() < deadline) {
    last = await page.evaluate(() => ({
      station: document.getElementById('t-station').textContent,
      link: document.getElementById('link').dataset.state,
      temperaturePoints: window.dashboard ? window.dashboard.temperaturePlot.data[0].length : 0,
      gyroPoints: window.dashboard ? window.dashboard.gyroPlot.data[0].length : 0,
      livePoints: window.dashboard ? window.dashboard.livePoints() : 0,
      state: document.getElementById('state').textContent,
    }));
    if (last.station !== '—') seen.add(last.station);
    done = seen.size >= 3 && last.link === 'live' && last.temperaturePoints >= 2 &&
      last.gyroPoints >= 2 && last.livePoints >= 2;
    if (!done) await page.waitForTimeout(100);
  }
  if (!done && failures.length === 0) {
    failures.push(`live values did not move within ${args.timeoutS} s: ` +
      `station times seen ${JSON.stringify([...seen])}, last ${JSON.stringify(last)}`);
  }

  if (args.token) {
    const stored = await page.evaluate(() => ({
      session: sessionStorage.getItem('gyrotherm.token'),
      local: JSON.stringify(Object.assign({}, localStorage)),
      html: document.documentElement.outerHTML,
    }));
    if (stored.session !== args.token) failures.push('the token is not in sessionStorage');
    if (stored.local.includes(args.token)) failures.push('the token is in localStorage');
    if (stored.html.includes(args.token)) failures.push('the token is in the page\'s HTML');
    const after = apiRequests.filter(([, , given]) => given);
    if (!after.some(([p]) => p === '/api/v1/stream')) {
      failures.push('no request to /api/v1/stream after the token was given');
    }
    for (const [p, auth] of after) {
      if (auth !== `Bearer ${args.token}`) failures.push(`${p} without the token's header`);
    }
    if (!apiRequests.some(([, , given]) => !given)) failures.push('no 401 before the token');
  }

  // The rate-table card: shown exactly when the station has a table.
  if (done) {
    const table = await page.evaluate(async () => {
      const token = sessionStorage.getItem('gyrotherm.token');
      const r = await fetch('/api/v1/status', {
        cache: 'no-store', headers: token ? { Authorization: `Bearer ${token}` } : {},
      });
      const s = await r.json();
      return { hasTable: s.table != null, hidden: document.getElementById('health-table').hidden };
    });
    if (table.hasTable === table.hidden) {
      failures.push(`the rate-table card is ${table.hidden ? 'hidden' : 'shown'} on a station ` +
        `${table.hasTable ? 'with' : 'without'} a table`);
    }
  }

  // Let the plots settle on the last data before the picture.
  await page.evaluate(() => new Promise((r) => requestAnimationFrame(() => r())));
  await page.screenshot({ path: args.screenshot, fullPage: true });
  closing = true;
  if (done) {
    console.log(`dashboard live: state ${last.state}, station times ${[...seen].join(', ')}; ` +
      `plots ${last.temperaturePoints} temperature / ${last.gyroPoints} gyro points ` +
      `(${last.livePoints} live); screenshot ${args.screenshot}`);
  }
} catch (err) {
  failures.push(`browser: ${err.message}`);
} finally {
  if (context) await context.close().catch(() => {});
  fs.rmSync(userDataDir, { recursive: true, force: true });
}

if (failures.length) {
  console.error('dashboard test FAILED:\n  ' + failures.join('\n  '));
  process.exit(1);
}
process.exit(0);
