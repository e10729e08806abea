// Browser test of the dashboard's devices under test and progress: headless
// Chromium (Debian's, through playwright-core) loads the page's own files
// (web/ and uPlot from node_modules/) and is fed a station with three DUTs
// through request routing, no daemon: the page is the unit under test.
//   1. GET /api/v1/status (a run settling, three DUTs, two queued entries):
//      one card per DUT in order with serial, model, the rate per axis, the
//      internal temperature, samples/s and link health; only the first DUT's
//      primary axis is highlighted; the channel chooser holds every channel
//      of GET /api/v1/runs/5 "duts", the first DUT's primary axis chosen, and
//      the first samples request asks for it (?dut=17-0042&channel=gyro_z);
//      the stability gate's bar shows instead of a step fraction, the run
//      has no ETA ("≥ … + 2 settles"), the queue its fixed time and settles;
//   2. choosing the third DUT's rate channel asks the samples route for
//      ?dut=21-0007&channel=rate and plots what it answered;
//   3. the stream (held until 2 was checked) brings the run acquiring: the
//      step's bar at 42.5 %, no gate bar, the run's ETA, the chosen
//      channel's live value on the plot; the adaptive soak's judgement: a
//      U95(T) curve per axis with a model, the target and the text line
//      (a second screenshot, OUT-acquiring.png).
//
//   node tests/browser/dashboard_duts.mjs --screenshot OUT.png
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
  console.error(`dashboard_duts.mjs: ${problem}\n` +
    'usage: node tests/browser/dashboard_duts.mjs --screenshot OUT.png [--timeout-s S] ' +
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

const device = { connected: true, last_success_utc: '2026-11-24T10:00:00Z', requests: 1200,
  errors: 0, reconnects: 0, last_error: '', last_latency_ms: 2.5 };
const gyroHealth = (connected, lastError, crc) => ({ connected, samples: 1000, frames_ok: 1000,
  crc_failures: crc, bytes_skipped: 0, sequence_gaps: 0, frames_missed: 0, invalid_samples: 0,
  reopens: 0, read_errors: 0, last_error: lastError });

// Three DUTs: a KVH 1750 with every axis, a second one silent (nulls), a
// one-axis gyro printing text whose primary axis is x.
function duts(thirdRateDph) {
  return [
    { serial: '17-0042', model: 'KVH 1750', primary_axis: 'z',
      rates_dph: { x: 1.5, y: -2.25, z: 7.95 }, temp_c: 41.23, samples_per_s: 1000,
      health: gyroHealth(true, '', 0) },
    { serial: '17-0043', model: 'KVH 1750', primary_axis: 'z',
      rates_dph: { x: null, y: null, z: null }, temp_c: null, samples_per_s: 0,
      health: gyroHealth(false, '/dev/ttyUSB1: no frames for 5 s', 3) },
    { serial: '21-0007', model: 'FOG-A', primary_axis: 'x', rates_dph: { x: thirdRateDph },
      temp_c: 30.5, samples_per_s: 200, health: gyroHealth(true, '', 0) },
  ];
}

const SETTLING = {
  phase: 'settling', step_elapsed_s: 420, step_planned_s: 6000, step_fraction: null,
  gate_held_s: 240, gate_needed_s: 600, run_remaining_fixed_s: 7800, run_settles_remaining: 2,
  run_eta_s: null, run_eta_p10_s: null, run_eta_p90_s: null, run_eta_basis: null,
  prior_settles: 0, queue_fixed_s: 43200, queue_settles: 8,
  queue_eta_s: null, queue_eta_p10_s: null, queue_eta_p90_s: null,
  settle: { verdict: 'predicted', note: 'first-order fit', p10_s: 1200, p50_s: 1800, p90_s: 3000,
    age_s: 20 },
};
// An axis's projection as the station gives it: [T, U95(T)] at 41 lengths
// from 60 s to the cap (9000 s), here of white noise and a flicker floor.
function projection(qN, qB, k) {
  return Array.from({ length: 41 }, (_, i) => {
    const t = 60 * Math.pow(9000 / 60, i / 40);
    return [t, k * Math.sqrt(qN / t + qB)];
  });
}
const ACQUIRING = {
  phase: 'acquiring', step_elapsed_s: 2550, step_planned_s: 6000, step_fraction: 0.425,
  gate_held_s: null, gate_needed_s: null, run_remaining_fixed_s: 3000, run_settles_remaining: 0,
  run_eta_s: 3000, run_eta_p10_s: null, run_eta_p90_s: null, run_eta_basis: 'fixed',
  prior_settles: 0, queue_fixed_s: 43200, queue_settles: 8, settle: null,
  queue_eta_s: 50400, queue_eta_p10_s: 46800, queue_eta_p90_s: 57600,
  // An adaptive soak judged: two axes with a model (white noise; white noise
  // and a flicker floor), one without yet.
  acquire: {
    target_u95_dph: 0.03, min_s: 600, max_s: 9000, acquired_s: 2550, planned_s: 6000, age_s: 40,
    axes: [
      { name: '17-0042 x', verdict: 'continue', u95_dph: 0.0389, reach_s: 4300, floor_dph: 0,
        model: { q_n: 1.0, q_b: 0, q_k: 0, q_g: 0, gm_tc_s: 0, k: 1.97 },
        projection: projection(1.0, 0, 1.97), note: 'U95 0.0389 °/h after 42 min' },
      { name: '17-0042 z', verdict: 'continue', u95_dph: 0.0443, reach_s: 6000, floor_dph: 0.005,
        model: { q_n: 1.2, q_b: 2.5e-5, q_k: 0, q_g: 0, gm_tc_s: 0, k: 1.98 },
        projection: projection(1.2, 2.5e-5, 1.98), note: 'U95 0.0443 °/h after 42 min' },
      { name: '21-0007 x', verdict: 'no_model', u95_dph: null, reach_s: null, floor_dph: null,
        model: null, projection: [], note: 'no noise model yet' },
    ],
  },
};

// A station snapshot as GET /api/v1/status gives it (docs/api.md), run 5.
function status(tRunS, progress, thirdRateDph) {
  return {
    station: 'IMU lab', state: progress.phase, run_id: 5, schedule: 'campaign',
    step: { index: 2, count: 9, label: 'step 3: soak 40 °C' },
    setpoint_c: 40.0, chamber_c: 40.01, top_c: 40.2, side_c: 40.1, gradient_c: 0.1,
    temp_rate_c_per_min: 0.0, gyro_rate_dph: 7.95, gyro_samples_per_s: 1000,
    t_station_s: tRunS + 50, t_run_s: tRunS, uptime_s: tRunS, time_scale: 1, last_event: '',
    paused: false, interlocks: [], queue_length: 2, queue_held: false, queue_hold_reason: '',
    table: null,
    devices: { chamber: device, probes: device, gyro: gyroHealth(true, '', 0), table: null },
    storage: { gyro_rows: 1000, temperature_rows: 10, commits: 10, commit_failures: 0, dropped: 0,
      pending: 0, last_commit_ms: 1.0, max_commit_ms: 3.0, last_error: '' },
    duts: duts(thirdRateDph),
    progress,
    run_metadata: { operator: 'ana', comment: '', tags: ['cold'] },
  };
}

const kvhChannels = ['x', 'y', 'z'].map((a) => ({ name: `gyro_${a}`, unit: 'deg/h', kind: 'rate',
  axis: a })).concat(['x', 'y', 'z'].map((a) => ({ name: `accel_${a}`, unit: 'g', kind: 'accel',
  axis: a })), [{ name: 'status', unit: '', kind: 'status', axis: '' },
  { name: 'temp_c', unit: 'degC', kind: 'temperature', axis: '' }]);
// GET /api/v1/runs/5 (the part the page reads).
const RUN = {
  id: 5, schedule_name: 'campaign', state: 'settling', segments: [],
  metadata: { operator: 'ana', comment: '', tags: ['cold'], duts: ['17-0042', '17-0043', '21-0007'] },
  duts: [
    { serial: '17-0042', model: 'KVH 1750', position: 0, primary_axis: 'z', axes: ['x', 'y', 'z'],
      rate_hz: 1000, channels: kvhChannels },
    { serial: '17-0043', model: 'KVH 1750', position: 1, primary_axis: 'z', axes: ['x', 'y', 'z'],
      rate_hz: 1000, channels: kvhChannels },
    { serial: '21-0007', model: 'FOG-A', position: 2, primary_axis: 'x', axes: ['x'], rate_hz: 200,
      channels: [{ name: 'rate', unit: 'deg/h', kind: 'rate', axis: 'x' },
        { name: 'temp_c', unit: 'degC', kind: 'temperature', axis: '' }] },
  ],
};
const CHANNEL_COUNT = 8 + 8 + 2;

// The samples route's answer for one DUT and channel: four buckets whose
// means tell which channel they are (21-0007 rate: −36 000.5 °/h, a table
// turning at −10 °/s, over three days: the axes' widest labels).
const THIRD_MEAN = -36000.5;
function samples(dut, channel) {
  const third = dut === '21-0007' && channel === 'rate';
  const mean = third ? THIRD_MEAN : 7.5;
  const t = third ? [100, 86400, 172800, 259300] : [100, 200, 300, 400];
  return {
    run_id: 5, dut, channel, unit: 'deg/h',
    temperature: { t_s: t, setpoint_c: t.map(() => 40), chamber_c: t.map(() => 40),
      top_c: t.map(() => 40.1), side_c: t.map(() => 40) },
    gyro: { t_s: t, mean_dph: t.map(() => mean), min_dph: t.map(() => mean - 1),
      max_dph: t.map(() => mean + 1) },
  };
}

// What the page shows of the DUTs, the chooser and the progress.
async function look(page) {
  return page.evaluate(() => {
    const el = (id) => document.getElementById(id);
    const text = (id) => el(id).textContent.trim();
    const cards = [...document.querySelectorAll('#duts .dut')].map((c) => ({
      serial: c.querySelector('.serial').textContent,
      model: c.querySelector('.model').textContent,
      rates: Object.fromEntries([...c.querySelectorAll('dd.rate')].map((d) =>
        [d.dataset.axis, d.textContent])),
      primary: [...c.querySelectorAll('dd.rate.primary')].map((d) => d.dataset.axis),
      temp: c.querySelector('[data-key="temp"]').textContent,
      sps: c.querySelector('[data-key="sps"]').textContent,
      link: c.querySelector('[data-key="link"]').textContent,
      linkBad: c.querySelector('[data-key="link"]').classList.contains('bad'),
      crcWarn: c.querySelector('[data-key="crc"]').classList.contains('warn'),
      error: c.querySelector('.err').textContent,
      dot: c.querySelector('.dot').dataset.ok,
    }));
    const select = el('gyro-channel');
    return {
      cards,
      options: select.options.length,
      selected: select.selectedIndex >= 0 ? select.options[select.selectedIndex].textContent : '',
      selectHidden: select.hidden,
      title: text('gyro-plot-title'),
      unit: text('gyro-plot-unit'),
      progressHidden: el('progress').hidden,
      stepBarHidden: el('step-bar').hidden,
      stepWidth: el('step-fill').style.width,
      stepText: text('step-progress'),
      gateHidden: el('gate-bar').hidden,
      gateWidth: el('gate-fill').style.width,
      gateText: text('gate-progress'),
      runEta: text('run-eta'),
      acquireHidden: el('acquire').hidden,
      acquireCurves: [...document.querySelectorAll('#acquire-plot path.curve')]
        .map((c) => c.dataset.axis),
      acquireText: text('acquire-text'),
      queueEta: text('queue-eta'),
      gyroMeans: window.dashboard ? [...window.dashboard.gyroPlot.data[1]] : [],
      station: text('t-station'),
    };
  });
}

// The gyro plot's axes as drawn: each tick label and where it stands,
// measured in the axes' font by the test itself.
async function gyroAxes(page) {
  return page.evaluate((font) => {
    const u = window.dashboard.gyroPlot;
    const ctx = document.createElement('canvas').getContext('2d');
    ctx.font = font;
    const ticks = (i, scale) => u.axes[i]._splits.map((v, k) => ({
      value: v, label: u.axes[i]._values[k], width: ctx.measureText(u.axes[i]._values[k]).width,
      pos: u.valToPos(v, scale) }));
    return { x: ticks(0, 'x'), y: ticks(1, 'y'), ySize: u.axes[1]._size,
      yTick: u.axes[1].ticks.size, yGap: u.axes[1].gap };
  }, '13px "DejaVu Sans", "Segoe UI", system-ui, sans-serif');
}

// Fails when a y label does not read as its tick's value, is wider than its
// axis (clipped at the page's edge) or lost a negative value's minus sign,
// or when two x labels overlap.
function checkAxes(failures, step, axes) {
  for (const t of axes.y) {
    const read = Number(t.label.replace('−', '-'));
    if (Math.abs(read - t.value) > 1e-9 * Math.max(1, Math.abs(t.value))) {
      failures.push(`${step}: the y tick at ${t.value} reads "${t.label}"`);
    }
    if (t.value < 0 && !t.label.startsWith('−')) {
      failures.push(`${step}: the y tick at ${t.value} reads "${t.label}", no minus sign`);
    }
    if (t.width + axes.yTick + axes.yGap > axes.ySize) {
      failures.push(`${step}: the y label "${t.label}" (${t.width.toFixed(1)} px) does not fit ` +
        `its ${axes.ySize} px axis`);
    }
  }
  if (axes.y.length < 2) failures.push(`${step}: ${axes.y.length} y ticks`);
  if (axes.x.length < 2) failures.push(`${step}: ${axes.x.length} x ticks`);
  for (let k = 1; k < axes.x.length; k++) {
    const a = axes.x[k - 1];
    const b = axes.x[k];
    if (b.pos - a.pos < (a.width + b.width) / 2 + 4) {
      failures.push(`${step}: the x labels "${a.label}" and "${b.label}" overlap ` +
        `(${(b.pos - a.pos).toFixed(1)} px apart)`);
    }
  }
}

async function waitFor(page, ok, deadline) {
  let last = null;
  while (Date.now() < deadline) {
    last = await look(page);
    if (ok(last)) return { ok: true, last };
    await page.waitForTimeout(50);
  }
  return { ok: false, last };
}

function expectEqual(failures, phase, key, got, want) {
  if (JSON.stringify(got) !== JSON.stringify(want)) {
    failures.push(`${phase}: ${key} is ${JSON.stringify(got)}, not ${JSON.stringify(want)}`);
  }
}

function expectFields(failures, phase, got, want) {
  for (const [key, value] of Object.entries(want)) expectEqual(failures, phase, key, got[key], value);
}

const failures = [];
let closing = false;
const samplesAsked = [];  // [dut, channel] of each samples request, in order
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

  let releaseStream = null;
  const streamGate = new Promise((resolve) => { releaseStream = resolve; });
  await context.route(`${ORIGIN}/**`, async (route) => {
    const url = new URL(route.request().url());
    const json = (body) => route.fulfill({ status: 200, contentType: 'application/json',
      body: JSON.stringify(body) });
    if (FILES[url.pathname]) {
      const [file, type] = FILES[url.pathname];
      await route.fulfill({ status: 200, contentType: type, body: fs.readFileSync(file) });
    } else if (url.pathname === '/api/v1/status') {
      await json(status(1000, SETTLING, 12.0));
    } else if (url.pathname === '/api/v1/runs/5') {
      await json(RUN);
    } else if (url.pathname === '/api/v1/runs/5/events') {
      await json([]);
    } else if (url.pathname === '/api/v1/runs/5/samples') {
      const dut = url.searchParams.get('dut');
      const channel = url.searchParams.get('channel');
      samplesAsked.push([dut, channel]);
      await json(samples(dut, channel));
    } else if (url.pathname === '/api/v1/stream') {
      await streamGate;
      // A long retry: the page must not come back for more while it is looked at.
      const body = `retry: 3600000\n\nevent: status\ndata: ${
        JSON.stringify(status(259400, ACQUIRING, 12.25))}\n\n`;
      await route.fulfill({ status: 200, contentType: 'text/event-stream', body });
    } else {
      failures.push(`request the test does not serve: ${url.pathname}${url.search}`);
      await route.fulfill({ status: 404, body: '' });
    }
  });

  const deadline = Date.now() + args.timeoutS * 1000;
  // 1. Three DUTs, settling.
  await page.goto(`${ORIGIN}/`, { waitUntil: 'load', timeout: args.timeoutS * 1000 });
  let seen = await waitFor(page, (s) => s.cards.length === 3 && s.options === CHANNEL_COUNT &&
    samplesAsked.length >= 1 && s.gyroMeans.includes(7.5), deadline);
  if (!seen.ok) failures.push(`1: the cards or the chooser did not show: ${JSON.stringify(seen.last)}`);
  const one = seen.last;
  expectEqual(failures, '1', 'serials', one.cards.map((c) => c.serial),
    ['17-0042', '17-0043', '21-0007']);
  expectEqual(failures, '1', 'models', one.cards.map((c) => c.model),
    ['KVH 1750', 'KVH 1750', 'FOG-A']);
  if (one.cards.length === 3) {
    expectFields(failures, '1 (card 17-0042)', one.cards[0], {
      rates: { x: '1.500', y: '−2.250', z: '7.950' }, primary: ['z'], temp: '41.2 °C',
      sps: '1000', link: 'connected', linkBad: false, crcWarn: false, error: '', dot: 'ok' });
    expectFields(failures, '1 (card 17-0043)', one.cards[1], {
      rates: { x: '—', y: '—', z: '—' }, primary: [], temp: '—', sps: '0',
      link: 'DISCONNECTED', linkBad: true, crcWarn: true,
      error: '/dev/ttyUSB1: no frames for 5 s', dot: 'bad' });
    // Its primary axis is x, but only the first DUT's is highlighted.
    expectFields(failures, '1 (card 21-0007)', one.cards[2], {
      rates: { x: '12.000' }, primary: [], temp: '30.5 °C', sps: '200', link: 'connected' });
  }
  expectFields(failures, '1 (chooser)', one, {
    selectHidden: false, selected: '17-0042 · gyro_z (°/h)', title: '17-0042 · gyro_z',
    unit: '°/h' });
  expectEqual(failures, '1', 'first samples request', samplesAsked[0], ['17-0042', 'gyro_z']);
  expectFields(failures, '1 (progress, settling)', one, {
    progressHidden: false, stepBarHidden: false, stepWidth: '0%',
    stepText: 'settling for 7 min, then 1 h 40 min', gateHidden: false, gateWidth: '40%',
    acquireHidden: true,
    gateText: 'stability gate 0:04:00 of 0:10:00 · gate in 30 min (P10 20 min – P90 50 min)',
    runEta: 'run ≥ 2 h 10 min + 2 settles',
    queueEta: 'queue ≥ 12 h + 8 settles' });

  // 2. The third DUT's rate channel.
  const asked = samplesAsked.length;
  const index = await page.evaluate(() => [...document.getElementById('gyro-channel').options]
    .findIndex((o) => o.textContent === '21-0007 · rate (°/h)'));
  if (index < 0) {
    failures.push('2: no option "21-0007 · rate (°/h)" in the chooser');
  } else {
    await page.selectOption('#gyro-channel', String(index));
    seen = await waitFor(page,
      (s) => samplesAsked.length > asked && s.gyroMeans.includes(THIRD_MEAN), deadline);
    if (!seen.ok) failures.push(`2: the chosen channel was not plotted: ${JSON.stringify(seen.last)}`);
    expectEqual(failures, '2', 'samples request', samplesAsked[samplesAsked.length - 1],
      ['21-0007', 'rate']);
    expectFields(failures, '2', seen.last, { title: '21-0007 · rate', unit: '°/h' });
    if (seen.last.gyroMeans.includes(7.5)) {
      failures.push('2: the first channel\'s history is still on the plot');
    }
    checkAxes(failures, '2 (axes)', await gyroAxes(page));
  }
  await page.screenshot({ path: args.screenshot, fullPage: true });

  // 3. The stream: acquiring, with an ETA; the live value of the chosen channel.
  releaseStream();
  seen = await waitFor(page, (s) => s.stepWidth === '42.5%' && s.gyroMeans.includes(12.25),
    deadline);
  if (!seen.ok) failures.push(`3: the stream's status did not show: ${JSON.stringify(seen.last)}`);
  expectFields(failures, '3 (progress, acquiring)', seen.last, {
    stepText: 'step 42% · 42 min 30 s of 1 h 40 min', gateHidden: true,
    acquireHidden: false,
    acquireText: 'U95 0.0443 → 0.03 °/h after 42 min 30 s, target in ~57 min 30 s · ' +
      '17-0042 x continue, 17-0042 z continue, 21-0007 x no model',
    runEta: 'run ends in 50 min',
    queueEta: 'queue ≥ 12 h + 8 settles, ~14 h with the chamber\'s past settles ' +
      '(P10 13 h – P90 16 h)' });
  expectEqual(failures, '3', 'U95 curves drawn', seen.last.acquireCurves,
    ['17-0042 x', '17-0042 z']);
  await page.screenshot({ path: args.screenshot.replace(/\.png$/, '') + '-acquiring.png',
    fullPage: true });
  closing = true;
  if (failures.length === 0) {
    console.log(`dashboard DUTs ok: three cards, first DUT's primary axis highlighted, ` +
      `${CHANNEL_COUNT} channels, samples asked ${JSON.stringify(samplesAsked)}, gate then ` +
      `step progress; screenshot ${args.screenshot}`);
  }
} catch (err) {
  failures.push(`browser: ${err.message}`);
} finally {
  if (context) await context.close().catch(() => {});
  fs.rmSync(userDataDir, { recursive: true, force: true });
}

if (failures.length) {
  console.error('dashboard DUT test FAILED:\n  ' + failures.join('\n  '));
  process.exit(1);
}
process.exit(0);
