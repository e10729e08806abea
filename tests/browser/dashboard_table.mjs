// Browser test of the dashboard's rate-table card: headless Chromium (Debian's,
// through playwright-core) loads the page's own files (web/ and uPlot from
// node_modules/) and is fed statuses through request routing, no daemon: the
// page is the unit under test. In turn:
//   1. GET /api/v1/status with a table turning at rate: the card shows the
//      mode, the closed interlock (not highlighted), the measured rate and
//      position, the demand, the errors, and no STOPPING;
//   2. the stream (held until 1 was checked) brings a status with an
//      interlock fault while the table is safing: the interlock reads FAULT,
//      highlighted, the fault text shows, and STOPPING is on;
//   3. the page reloaded on a station without a table (table null): the card
//      is hidden.
//
//   node tests/browser/dashboard_table.mjs --screenshot OUT.png
//       [--timeout-s 30] [--chromium /usr/bin/chromium]
//
// Fails on any console error, uncaught page error, or request the test does
// not serve. Exit 0 when all held, 1 with the reasons on stderr, 2 on a bad
// command line.
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

function parseArgs(argv) {
  const args = { screenshot: null, timeoutS: 30, chromium: '/usr/bin/chromium' };
  for (let i = 0; i < argv.length; i++) {
    const value = () => {
      if (i + 1 >= argv.length) usage(`${argv[i]} needs a value`);
      return argv[++i];
    };
    switch (argv[i]) {
      case '--screenshot': args.screenshot = value(); break;
      case '--timeout-s': args.timeoutS = Number(value()); break;
      case '--chromium': args.chromium = value(); break;
      default: usage(`unknown argument ${argv[i]}`);
    }
  }
  if (!args.screenshot) usage('--screenshot is required');
  if (!(args.timeoutS > 0)) usage('--timeout-s must be a positive number');
  return args;
}

function usage(problem) {
  console.error(`dashboard_table.mjs: ${problem}\n` +
    'usage: node tests/browser/dashboard_table.mjs --screenshot OUT.png [--timeout-s S] ' +
    '[--chromium PATH]');
  process.exit(2);
}

const args = parseArgs(process.argv.slice(2));
const here = path.dirname(fileURLToPath(import.meta.url));
const source = path.resolve(here, '../..');
const ORIGIN = 'http://dashboard.test';
// What the daemon serves: the page at /, its files and uPlot under /web/.
const FILES = {
  '/': [path.join(source, 'web/index.html'), 'text/html; charset=utf-8'],
  '/web/app.js': [path.join(source, 'web/app.js'), 'text/javascript; charset=utf-8'],
  '/web/style.css': [path.join(source, 'web/style.css'), 'text/css; charset=utf-8'],
  '/web/uPlot.iife.min.js': [path.join(source, 'node_modules/uplot/dist/uPlot.iife.min.js'),
    'text/javascript; charset=utf-8'],
  '/web/uPlot.min.css': [path.join(source, 'node_modules/uplot/dist/uPlot.min.css'),
    'text/css; charset=utf-8'],
};

// A station snapshot as GET /api/v1/status gives it (docs/api.md), idle,
// with `table` as given.
function status(tStationS, table, tableHealth) {
  const device = { connected: true, last_success_utc: '2026-11-24T10:00:00Z', requests: 1200,
    errors: 0, reconnects: 0, last_error: '', last_latency_ms: 2.5 };
  return {
    station: 'Rate lab', state: 'idle', run_id: null, schedule: '',
    step: { index: null, count: 0, label: '' },
    setpoint_c: 25.0, chamber_c: 25.01, top_c: 25.2, side_c: 25.1, gradient_c: 0.1,
    temp_rate_c_per_min: 0.0, gyro_rate_dph: 8.123, gyro_samples_per_s: 100,
    t_station_s: tStationS, t_run_s: 0, uptime_s: tStationS, time_scale: 1, last_event: '',
    paused: false, interlocks: [], queue_length: 0, queue_held: false, queue_hold_reason: '',
    table,
    devices: {
      chamber: device, probes: device,
      gyro: { connected: true, samples: 1000, frames_ok: 1000, crc_failures: 0, bytes_skipped: 0,
        sequence_gaps: 0, frames_missed: 0, invalid_samples: 0, reopens: 0, read_errors: 0,
        last_error: '' },
      table: table == null ? null : Object.assign({}, device, tableHealth),
    },
    storage: { gyro_rows: 1000, temperature_rows: 10, commits: 10, commit_failures: 0, dropped: 0,
      pending: 0, last_commit_ms: 1.0, max_commit_ms: 3.0, last_error: '' },
  };
}

const AT_RATE = {
  connected: true, mode: 'rate', interlock: 'closed', rate_dps: 99.99874, position_deg: 123.456,
  fault: '', demand: { mode: 'rate', rate_dps: 100.0, position_deg: null }, safing: false,
};
const FAULTED = {
  connected: true, mode: 'rate', interlock: 'fault', rate_dps: 42.5, position_deg: 301.25,
  fault: 'interlock loop opened at rate', demand: { mode: 'static', rate_dps: 0, position_deg: 0 },
  safing: true,
};

// The card as the page shows it.
async function card(page) {
  return page.evaluate(() => {
    const text = (id) => document.getElementById(id).textContent.trim();
    const el = (id) => document.getElementById(id);
    return {
      hidden: el('health-table').hidden,
      visible: el('health-table').offsetParent !== null,
      withTable: el('health-table').parentElement.classList.contains('with-table'),
      link: text('table-link'),
      mode: text('table-mode'),
      interlock: text('table-interlock'),
      interlockBad: el('table-interlock').classList.contains('bad'),
      rate: text('table-rate'),
      position: text('table-position'),
      demand: text('table-demand'),
      errors: text('table-errors'),
      errorsWarn: el('table-errors').classList.contains('warn'),
      stopping: !el('table-stopping').hidden,
      fault: text('table-fault'),
      faultVisible: el('table-fault').offsetParent !== null,
      dot: el('table-conn').dataset.ok,
      station: text('t-station'),
    };
  });
}

// Polls the card until `ok(card)` holds; the last card seen otherwise.
async function waitForCard(page, ok, deadline) {
  let last = null;
  while (Date.now() < deadline) {
    last = await card(page);
    if (ok(last)) return { ok: true, last };
    await page.waitForTimeout(50);
  }
  return { ok: false, last };
}

function expectFields(failures, phase, got, want) {
  for (const [key, value] of Object.entries(want)) {
    if (got[key] !== value) {
      failures.push(`${phase}: ${key} is ${JSON.stringify(got[key])}, not ${JSON.stringify(value)}`);
    }
  }
}

const failures = [];
let closing = false;
const userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), 'gyrotherm-chromium-'));
let context = null;
try {
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

  // What the routes answer: the status, and the stream's one message once
  // `releaseStream` is called (null: the stream is answered at once).
  let current = status(100, AT_RATE, { errors: 0 });
  let streamMessage = null;
  let releaseStream = null;
  let streamGate = new Promise((resolve) => { releaseStream = resolve; });
  await context.route(`${ORIGIN}/**`, async (route) => {
    const url = new URL(route.request().url());
    if (FILES[url.pathname]) {
      const [file, type] = FILES[url.pathname];
      await route.fulfill({ status: 200, contentType: type, body: fs.readFileSync(file) });
    } else if (url.pathname === '/api/v1/status') {
      await route.fulfill({ status: 200, contentType: 'application/json',
        body: JSON.stringify(current) });
    } else if (url.pathname === '/api/v1/stream') {
      await streamGate;
      // A long retry: the page must not come back for more while it is looked at.
      const body = `retry: 3600000\n\nevent: status\ndata: ${JSON.stringify(streamMessage)}\n\n`;
      await route.fulfill({ status: 200, contentType: 'text/event-stream', body });
    } else {
      failures.push(`request the test does not serve: ${url.pathname}`);
      await route.fulfill({ status: 404, body: '' });
    }
  });

  const deadline = Date.now() + args.timeoutS * 1000;
  // 1. At rate, from GET /api/v1/status.
  streamMessage = status(101, FAULTED, { errors: 3, last_error: 'timeout' });
  await page.goto(`${ORIGIN}/`, { waitUntil: 'load', timeout: args.timeoutS * 1000 });
  let seen = await waitForCard(page, (c) => c.visible && c.mode === 'rate', deadline);
  if (!seen.ok) failures.push(`1: the card did not show: ${JSON.stringify(seen.last)}`);
  expectFields(failures, '1 (at rate)', seen.last, {
    hidden: false, withTable: true, link: 'connected', mode: 'rate', interlock: 'closed',
    interlockBad: false, rate: '99.999 °/s', position: '123.46°', demand: '100.000 °/s',
    errors: '0', errorsWarn: false, stopping: false, faultVisible: false, dot: 'ok',
  });

  // 2. The stream's status: an interlock fault while safing.
  releaseStream();
  seen = await waitForCard(page, (c) => c.interlock === 'FAULT', deadline);
  if (!seen.ok) failures.push(`2: the fault did not show: ${JSON.stringify(seen.last)}`);
  expectFields(failures, '2 (fault, safing)', seen.last, {
    hidden: false, interlock: 'FAULT', interlockBad: true, rate: '42.500 °/s',
    position: '301.25°', demand: 'static at 0.00°', errors: '3', errorsWarn: true,
    stopping: true, fault: 'interlock loop opened at rate', faultVisible: true, dot: 'bad',
  });
  await page.screenshot({ path: args.screenshot, fullPage: true });

  // 3. A station without a table.
  current = status(200, null, {});
  streamMessage = status(201, null, {});
  streamGate = Promise.resolve();
  closing = true;  // the reload cuts the first page's stream
  await page.goto(`${ORIGIN}/`, { waitUntil: 'load', timeout: args.timeoutS * 1000 });
  closing = false;
  seen = await waitForCard(page, (c) => c.station === '0:03:21', deadline);
  if (!seen.ok) failures.push(`3: the stream's status did not arrive: ${JSON.stringify(seen.last)}`);
  expectFields(failures, '3 (no table)', seen.last, { hidden: true, visible: false,
    withTable: false });
  closing = true;
  if (failures.length === 0) {
    console.log(`dashboard table card ok: at rate, fault while safing, hidden without a table; ` +
      `screenshot ${args.screenshot}`);
  }
} catch (err) {
  failures.push(`browser: ${err.message}`);
} finally {
  if (context) await context.close().catch(() => {});
  fs.rmSync(userDataDir, { recursive: true, force: true });
}

if (failures.length) {
  console.error('dashboard table test FAILED:\n  ' + failures.join('\n  '));
  process.exit(1);
}
process.exit(0);
