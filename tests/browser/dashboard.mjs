// Browser test of the station dashboard: headless Chromium (Debian's, through
// playwright-core) loads the page served by gyrothermd, waits until the live
// values move (station time changes twice, both plots hold points, some of
// them from the stream), and saves a full-page screenshot.
//
//   node tests/browser/dashboard.mjs --url http://127.0.0.1:PORT/ --screenshot OUT.png
//       [--timeout-s 60] [--chromium /usr/bin/chromium]
//
// Fails on any console error, uncaught page error, failed request, or request
// to a host other than the page's own. Exit 0 when all held, 1 with the
// reasons on stderr, 2 on a bad command line.
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { chromium } from 'playwright-core';

function parseArgs(argv) {
  const args = { url: null, screenshot: null, timeoutS: 60, chromium: '/usr/bin/chromium' };
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
      default: usage(`unknown argument ${argv[i]}`);
    }
  }
  if (!args.url || !args.screenshot) usage('--url and --screenshot are required');
  if (!(args.timeoutS > 0)) usage('--timeout-s must be a positive number');
  return args;
}

function usage(problem) {
  console.error(`dashboard.mjs: ${problem}\n` +
    'usage: node tests/browser/dashboard.mjs --url URL --screenshot OUT.png [--timeout-s S] [--chromium PATH]');
  process.exit(2);
}

const args = parseArgs(process.argv.slice(2));
const origin = new URL(args.url).origin;
const failures = [];
let closing = false;  // the stream is cut when the page closes: not a fault

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
    if (msg.type() === 'error' && !closing) failures.push(`console error: ${msg.text()}`);
  });
  page.on('pageerror', (err) => failures.push(`page error: ${err.message}`));
  page.on('request', (req) => {
    const u = new URL(req.url());
    if (u.protocol === 'data:' || u.protocol === 'blob:') return;
    if (u.origin !== origin) failures.push(`request to another host: ${req.url()}`);
  });
  page.on('requestfailed', (req) => {
    if (!closing) failures.push(`request failed: ${req.url()}: ${req.failure()?.errorText}`);
  });
  page.on('response', (res) => {
    if (res.status() >= 400) failures.push(`HTTP ${res.status()} for ${res.url()}`);
  });

  const deadline = Date.now() + args.timeoutS * 1000;
  const response = await page.goto(args.url, { waitUntil: 'load', timeout: args.timeoutS * 1000 });
  if (!response || !response.ok()) {
    failures.push(`page load: HTTP ${response ? response.status() : 'no response'}`);
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
