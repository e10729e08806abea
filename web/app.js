// gyrotherm station dashboard. On load: GET /api/v1/status, and for an active
// run the last hour of samples (GET /api/v1/runs/{id}/samples, decimated);
// then live from the SSE stream GET /api/v1/stream (a `status` message each
// wall second, `state` and `event` messages as they happen). Plots keep only
// the last hour of station time, so memory stays bounded however long the
// page stays open. Plain JS, no build step; uPlot is the global `uPlot`.
//
// Devices under test: one card per entry of status.duts. The gyro plot shows
// one DUT's channel, chosen in a select filled from GET /api/v1/runs/{id}
// ("duts" → channels; default: the first DUT's primary axis); its history
// comes from the samples route with ?dut=SN&channel=C, its live points from
// the status (the DUT's rate of that axis, or its internal temperature).
//
// A station with [api] read_access = "token" answers 401: the page then asks
// for a token, keeps it in sessionStorage (this tab only), sends it as
// "Authorization: Bearer" on every request, and reads the stream with
// fetch() (EventSource cannot send headers). The token never goes in a URL.
'use strict';

(() => {
  const WINDOW_S = 3600;          // plotted span, station seconds
  const HISTORY_POINTS = 1200;    // max_points asked of the samples route
  const MAX_LIVE_POINTS = 7200;   // cap besides the time window (1 status / s)
  const MAX_EVENTS = 40;
  const STALE_MS = 5000;          // no status for this long: the stream is stale
  const RECONNECT_MS = 3000;      // when the browser gave up on the stream
  const TOKEN_KEY = 'gyrotherm.token';  // sessionStorage

  const $ = (id) => document.getElementById(id);

  // ---------------------------------------------------------------- format
  const pad2 = (n) => String(n).padStart(2, '0');

  // Seconds as [-][d ]h:mm:ss.
  function fmtClock(s) {
    if (s == null || !Number.isFinite(s)) return '—';
    const sign = s < 0 ? '−' : '';
    let t = Math.floor(Math.abs(s));
    const d = Math.floor(t / 86400);
    t -= d * 86400;
    const h = Math.floor(t / 3600);
    const m = Math.floor((t % 3600) / 60);
    const sec = t % 60;
    return `${sign}${d ? d + ' d ' : ''}${h}:${pad2(m)}:${pad2(sec)}`;
  }

  function fmtNum(v, digits) {
    if (v == null || !Number.isFinite(v)) return '—';
    const s = v.toFixed(digits);
    return s.startsWith('-') ? '−' + s.slice(1) : s;
  }

  function fmtCount(v) {
    return v == null || !Number.isFinite(v) ? '—' : Math.round(v).toLocaleString('en-US');
  }

  // Seconds as the two largest units, rounded to the smaller (as the CLI and
  // `schedule check` print them): "5 h 20 min", "2 d 3 h", "12 min 30 s".
  function fmtDuration(s) {
    if (s == null || !Number.isFinite(s) || s < 0) s = 0;
    if (s >= 86400) {
      const hours = Math.round(s / 3600);
      const d = Math.floor(hours / 24);
      const h = hours % 24;
      return h ? `${d} d ${h} h` : `${d} d`;
    }
    if (s >= 3600) {
      const mins = Math.round(s / 60);
      const h = Math.floor(mins / 60);
      const m = mins % 60;
      if (h >= 24) return '1 d';
      return m ? `${h} h ${m} min` : `${h} h`;
    }
    if (s >= 60) {
      const secs = Math.round(s);
      const m = Math.floor(secs / 60);
      const sec = secs % 60;
      if (m >= 60) return '1 h';
      return sec ? `${m} min ${sec} s` : `${m} min`;
    }
    const secs = Math.round(s);
    return secs >= 60 ? '1 min' : `${secs} s`;
  }

  // "2 h 10 min + 2 settles": fixed time plus settles of unknown length.
  // A settling soak's forecast of its stability gate (progress.settle):
  // "gate in 42 min (P10 30 min – P90 1 h 5 min)"; '' without one.
  function fmtSettle(f) {
    if (!f) return '';
    if (f.verdict === 'predicted' && f.p10_s != null) {
      const hi = f.p90_s != null ? fmtDuration(f.p90_s) : 'beyond 48 h';
      return f.p50_s != null
        ? `gate in ${fmtDuration(f.p50_s)} (P10 ${fmtDuration(f.p10_s)} – P90 ${hi})`
        : `gate forecast too uncertain yet (P10 ${fmtDuration(f.p10_s)}, median beyond 48 h)`;
    }
    if (f.verdict === 'holds_now') return 'gate holds on the shell now';
    if (f.verdict === 'not_enough_curvature') return 'gate forecast: not enough curvature yet';
    if (f.verdict === 'never_within_tolerance') {
      return 'gate forecast: the shell settles outside the tolerance';
    }
    return '';
  }

  function fmtFixed(fixedS, settles) {
    const n = settles || 0;
    return fmtDuration(fixedS) + (n > 0 ? ` + ${n} settle${n === 1 ? '' : 's'}` : '');
  }

  // The unit of a channel as the page shows it.
  const UNITS = { 'deg/h': '°/h', degC: '°C', 'deg/s': '°/s' };
  const fmtUnit = (u) => (u in UNITS ? UNITS[u] : u || '');

  function setText(id, text) {
    const el = $(id);
    if (el.textContent !== text) el.textContent = text;
  }

  // Marks a figure as worth a look (nonzero error counters, lost links).
  function setLevel(id, level) {
    const el = $(id);
    el.classList.toggle('warn', level === 'warn');
    el.classList.toggle('bad', level === 'bad');
  }

  // ----------------------------------------------------------------- traces
  // One plot's columns: t (station s) then one column per series. History
  // (decimated, from the samples route) and live points (from the stream)
  // are kept apart and merged for drawing; both are trimmed to the window.
  class Trace {
    constructor(columns) {
      this.columns = columns;
      this.reset();
    }
    reset() {
      this.hist = this.empty();
      this.live = this.empty();
    }
    empty() {
      return Array.from({ length: this.columns }, () => []);
    }
    setHistory(cols) {
      this.hist = cols;
    }
    push(row) {
      const t = this.live[0];
      if (t.length && row[0] <= t[t.length - 1]) return;  // repeated snapshot
      row.forEach((v, i) => this.live[i].push(v));
      const cutoff = row[0] - WINDOW_S;
      let drop = 0;
      while (drop < t.length && t[drop] < cutoff) drop++;
      drop = Math.max(drop, t.length - MAX_LIVE_POINTS);
      if (drop > 0) this.live.forEach((c) => c.splice(0, drop));
    }
    livePoints() {
      return this.live[0].length;
    }
    data() {
      const lt = this.live[0];
      const ht = this.hist[0];
      const latest = lt.length ? lt[lt.length - 1] : ht.length ? ht[ht.length - 1] : 0;
      const cutoff = latest - WINDOW_S;
      const liveStart = lt.length ? lt[0] : Infinity;
      let a = 0;
      while (a < ht.length && ht[a] < cutoff) a++;
      let b = a;
      while (b < ht.length && ht[b] < liveStart) b++;
      let c = 0;
      while (c < lt.length && lt[c] < cutoff) c++;
      return this.hist.map((col, i) => col.slice(a, b).concat(this.live[i].slice(c)));
    }
  }

  const temperature = new Trace(5);  // t, setpoint, chamber, top, side
  const gyro = new Trace(4);         // t, mean, min, max

  // ------------------------------------------------------------------ plots
  const FONT = '13px "DejaVu Sans", "Segoe UI", system-ui, sans-serif';
  const AXIS = {
    stroke: '#9aa7b8',
    font: FONT,
    grid: { stroke: 'rgba(148, 163, 184, 0.13)', width: 1 },
    ticks: { stroke: 'rgba(148, 163, 184, 0.3)', width: 1, size: 5 },
  };
  const X_INCRS = [1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 900, 1200, 1800, 3600,
    7200, 10800, 21600, 43200, 86400, 172800, 345600, 604800];

  function valueFmt(digits) {
    return (u, v) => fmtNum(v, digits);
  }

  // Away from the cursor the legend shows the newest values, not dashes.
  function showLatestInLegend(u) {
    const n = u.data[0].length;
    if (n && u.cursor.idx == null) u.setLegend({ idx: n - 1 }, false);
  }

  // Axis labels are measured in the axes' own font, so the y axis is as wide
  // as its widest label (a minus sign is never clipped) and the x ticks stand
  // at least a label's width apart however long the span.
  const measure = document.createElement('canvas').getContext('2d');
  measure.font = FONT;
  function textWidth(s) {
    return measure.measureText(s).width;
  }

  // The decimals the tick step itself has (0.25 needs two, 5 none), at most
  // six: every tick then reads as its value.
  function tickValues(u, splits, axisIdx, space, incr) {
    let digits = 0;
    while (digits < 6) {
      const x = incr * 10 ** digits;
      if (!(incr > 0) || (Math.round(x) >= 1 && Math.abs(x - Math.round(x)) < 1e-9 * x)) break;
      digits++;
    }
    return splits.map((v) => fmtNum(v, digits));
  }

  function ySize(u, values) {
    const widest = values && values.length ? Math.max(...values.map(textWidth)) : 40;
    return Math.ceil(widest + AXIS.ticks.size + 12);
  }

  function xSpace(u, axisIdx, min, max) {
    const widest = Math.max(textWidth(fmtClock(min)), textWidth(fmtClock(max)));
    return Math.ceil(widest + 24);
  }

  function makePlot(el, series, extra) {
    const opts = Object.assign({
      width: Math.max(300, el.clientWidth),
      height: 280,
      pxAlign: 0,
      cursor: { drag: { x: false, y: false } },
      legend: { live: true },
      scales: { x: { time: false } },
      axes: [
        Object.assign({}, AXIS, {
          incrs: X_INCRS,
          values: (u, splits) => splits.map(fmtClock),
          space: xSpace,
          size: 40,
        }),
        Object.assign({}, AXIS, { values: tickValues, size: ySize }),
      ],
      series: [{ label: 'time', value: (u, v) => fmtClock(v) }].concat(series),
      hooks: { setCursor: [showLatestInLegend] },
    }, extra);
    const plot = new uPlot(opts, series.length ? [[]].concat(series.map(() => [])) : [[]], el);
    new ResizeObserver(() => {
      const w = Math.max(300, el.clientWidth);
      if (w !== plot.width) plot.setSize({ width: w, height: plot.height });
    }).observe(el);
    return plot;
  }

  const temperaturePlot = makePlot($('plot-temperature'), [
    { label: 'set point', stroke: '#e2e8f0', width: 1.5, dash: [8, 5], value: valueFmt(2) },
    { label: 'chamber', stroke: '#f59e0b', width: 2, value: valueFmt(2) },
    { label: 'top', stroke: '#f43f5e', width: 2, value: valueFmt(2) },
    { label: 'side', stroke: '#38bdf8', width: 2, value: valueFmt(2) },
  ]);

  const gyroPlot = makePlot($('plot-gyro'), [
    { label: 'mean', stroke: '#34d399', width: 2, value: valueFmt(3) },
    { label: 'bucket min', stroke: 'rgba(52, 211, 153, 0.35)', width: 1, value: valueFmt(3) },
    { label: 'bucket max', stroke: 'rgba(52, 211, 153, 0.35)', width: 1, value: valueFmt(3) },
  ], { bands: [{ series: [3, 2], fill: 'rgba(52, 211, 153, 0.14)' }] });

  function redraw() {
    for (const [plot, trace] of [[temperaturePlot, temperature], [gyroPlot, gyro]]) {
      plot.setData(trace.data());
      showLatestInLegend(plot);
    }
  }

  // ---------------------------------------------------------------- history
  // The plots follow one run (or the station clock when idle); key says which.
  let plotKey = undefined;
  let historyRequest = 0;

  // ------------------------------------------------------------------ token
  let token = sessionStorage.getItem(TOKEN_KEY) || '';

  function authHeaders() {
    return token ? { Authorization: `Bearer ${token}` } : {};
  }

  class Unauthorized extends Error {}

  // The daemon wants a token (or refused ours): ask for one.
  function askForToken(refused) {
    if (refused) {
      token = '';
      sessionStorage.removeItem(TOKEN_KEY);
    }
    stopStream();
    setText('token-note', refused ? 'The station refused that token.' : '');
    const form = $('token-form');
    if (form.hidden) {
      form.hidden = false;
      $('token-input').focus();
    }
    setLink('down', 'Token needed');
  }

  $('token-form').addEventListener('submit', (e) => {
    e.preventDefault();
    const input = $('token-input');
    token = input.value.trim();
    input.value = '';
    if (!token) return;
    sessionStorage.setItem(TOKEN_KEY, token);
    $('token-form').hidden = true;
    plotKey = undefined;
    start();
  });

  async function getJson(path) {
    const r = await fetch(path, { cache: 'no-store', headers: authHeaders() });
    if (r.status === 401) {
      askForToken(!!token);
      throw new Unauthorized(`${path}: HTTP 401`);
    }
    if (!r.ok) throw new Error(`${path}: HTTP ${r.status}`);
    return r.json();
  }

  async function loadHistory(runId, tRunS) {
    const request = ++historyRequest;
    const from = Math.max(0, tRunS - WINDOW_S);
    const to = Math.max(from, tRunS);
    try {
      const ch = chosenChannel();
      // The unnamed gyro (serial "") is the run's first DUT: the default.
      const which = ch ? (ch.serial ? `&dut=${encodeURIComponent(ch.serial)}` : '') +
        `&channel=${encodeURIComponent(ch.name)}` : '';
      const s = await getJson(`/api/v1/runs/${runId}/samples?from=${from.toFixed(3)}` +
        `&to=${to.toFixed(3)}&max_points=${HISTORY_POINTS}${which}`);
      if (request !== historyRequest || plotKey !== runId) return;  // superseded
      if (ch !== chosenChannel()) return;  // another channel was chosen meanwhile
      const tp = s.temperature || {};
      temperature.setHistory([tp.t_s || [], tp.setpoint_c || [], tp.chamber_c || [],
        tp.top_c || [], tp.side_c || []]);
      // The chosen channel's buckets (in its unit, under the route's "gyro").
      const g = s.gyro || {};
      gyro.setHistory([g.t_s || [], g.mean_dph || g.mean || [], g.min_dph || g.min || [],
        g.max_dph || g.max || []]);
      redraw();
    } catch (err) {
      if (!(err instanceof Unauthorized)) {
        console.error('history of run', runId, 'not loaded:', err.message);
      }
    }
  }

  // --------------------------------------------------------------- channels
  // The channels the gyro plot can show: every channel of every DUT of the
  // plotted run, from GET /api/v1/runs/{id}; chosen = index into it.
  let channels = [];
  let chosen = -1;
  let channelsRequest = 0;

  function chosenChannel() {
    return chosen >= 0 && chosen < channels.length ? channels[chosen] : null;
  }

  function showChannel() {
    const ch = chosenChannel();
    const dut = ch ? (ch.serial || 'gyro') : '';
    setText('gyro-plot-title', ch ? `${dut} · ${ch.name}` : 'Gyro rate');
    setText('gyro-plot-unit', ch ? fmtUnit(ch.unit) : '°/h');
  }

  // Fills the chooser from the run's DUTs; keeps the choice when the run's
  // channels still hold it (same serial and channel), else takes the first
  // DUT's primary axis.
  function setChannels(duts) {
    const previous = chosenChannel();
    channels = [];
    (duts || []).forEach((d, di) => {
      for (const c of d.channels || []) {
        channels.push({ serial: d.serial || '', model: d.model || '', name: c.name,
          unit: c.unit || '', kind: c.kind || '', axis: c.axis || '',
          primary: di === 0 && c.kind === 'rate' && c.axis === d.primary_axis });
      }
    });
    chosen = previous ? channels.findIndex((c) => c.serial === previous.serial &&
      c.name === previous.name) : -1;
    if (chosen < 0) chosen = channels.findIndex((c) => c.primary);
    if (chosen < 0) chosen = channels.findIndex((c) => c.kind === 'rate');
    const select = $('gyro-channel');
    select.replaceChildren(...channels.map((c, i) => {
      const o = document.createElement('option');
      o.value = String(i);
      o.textContent = `${c.serial || 'gyro'} · ${c.name}${c.unit ? ` (${fmtUnit(c.unit)})` : ''}`;
      return o;
    }));
    select.hidden = channels.length === 0;
    if (chosen >= 0) select.value = String(chosen);
    showChannel();
  }

  $('gyro-channel').addEventListener('change', (e) => {
    chosen = Number(e.target.value);
    showChannel();
    gyro.reset();
    redraw();
    if (plotKey != null && lastStatus) loadHistory(plotKey, lastStatus.t_run_s);
  });

  // The run's DUTs and channels, then its history on the chosen channel.
  async function loadRun(runId, tRunS) {
    const request = ++channelsRequest;
    try {
      const run = await getJson(`/api/v1/runs/${runId}`);
      if (request !== channelsRequest || plotKey !== runId) return;  // superseded
      setChannels(run.duts);
    } catch (err) {
      if (err instanceof Unauthorized) return;
      console.error('run', runId, 'not loaded:', err.message);
      setChannels([]);
    }
    loadHistory(runId, tRunS);
  }

  // The chosen channel's live value in a status: the DUT's rate of that axis
  // or its internal temperature; the station's gyro rate without a choice.
  function liveValue(s) {
    const ch = chosenChannel();
    if (!ch) return s.gyro_rate_dph;
    const d = (s.duts || []).find((x) => (x.serial || '') === ch.serial);
    if (!d) return null;
    if (ch.kind === 'rate' && d.rates_dph && ch.axis in d.rates_dph) return d.rates_dph[ch.axis];
    if (ch.kind === 'temperature') return d.temp_c;
    return null;
  }

  // ----------------------------------------------------------------- events
  const events = new Map();  // "run:id" -> record

  function addEvents(records) {
    for (const e of records) {
      if (e && e.id != null) events.set(`${e.run_id}:${e.id}`, e);
    }
    const newest = [...events.values()].sort((a, b) =>
      (b.run_id - a.run_id) || (b.id - a.id)).slice(0, MAX_EVENTS);
    events.clear();
    newest.forEach((e) => events.set(`${e.run_id}:${e.id}`, e));
    renderEvents(newest);
  }

  function renderEvents(list) {
    const ol = $('events');
    const items = list.map((e) => {
      const li = document.createElement('li');
      li.dataset.kind = e.kind || '';
      const t = document.createElement('span');
      t.className = 'when mono';
      t.textContent = `#${e.run_id} ${fmtClock(e.t_s)}`;
      const kind = document.createElement('span');
      kind.className = 'kind';
      kind.textContent = e.kind || '';
      const msg = document.createElement('span');
      msg.className = 'msg';
      msg.textContent = e.message || '';
      li.append(t, kind, msg);
      return li;
    });
    if (!items.length) {
      const li = document.createElement('li');
      li.className = 'muted empty';
      li.textContent = 'No events yet.';
      items.push(li);
    }
    ol.replaceChildren(...items);
  }

  async function loadEvents(runId) {
    try {
      const list = await getJson(`/api/v1/runs/${runId}/events`);
      addEvents(list.slice(-MAX_EVENTS).map((e) => Object.assign({ run_id: runId }, e)));
    } catch (err) {
      if (!(err instanceof Unauthorized)) {
        console.error('events of run', runId, 'not loaded:', err.message);
      }
    }
  }

  // ----------------------------------------------------------------- status
  function renderDevice(prefix, d) {
    d = d || {};
    const up = !!d.connected;
    $(`${prefix}-conn`).dataset.ok = up ? 'ok' : 'bad';
    setText(`${prefix}-link`, up ? 'connected' : 'DISCONNECTED');
    setLevel(`${prefix}-link`, up ? '' : 'bad');
    setText(`${prefix}-requests`, fmtCount(d.requests));
    setText(`${prefix}-errors`, fmtCount(d.errors));
    setLevel(`${prefix}-errors`, d.errors > 0 ? 'warn' : '');
    setText(`${prefix}-reconnects`, fmtCount(d.reconnects));
    setLevel(`${prefix}-reconnects`, d.reconnects > 0 ? 'warn' : '');
    setText(`${prefix}-latency`, d.last_latency_ms == null ? '—' : `${fmtNum(d.last_latency_ms, 2)} ms`);
    setText(`${prefix}-error`, d.last_error || '');
  }

  // The rate table's card: shown only when the station has a table
  // (status.table not null). mode off/rate/position, interlock
  // open/closed/fault; null figures while the controller has not answered.
  const TABLE_DEMAND = {
    none: () => 'none',
    static: (d) => (d.position_deg == null ? 'static' : `static at ${fmtNum(d.position_deg, 2)}°`),
    rate: (d) => `${fmtNum(d.rate_dps, 3)} °/s`,
  };

  function renderTable(t, health) {
    const card = $('health-table');
    card.hidden = t == null;
    card.parentElement.classList.toggle('with-table', t != null);
    if (t == null) return;
    const up = !!t.connected;
    const fault = t.interlock === 'fault' || !!t.fault;
    $('table-conn').dataset.ok = !up || fault ? 'bad' : t.safing ? 'warn' : 'ok';
    setText('table-link', up ? 'connected' : 'DISCONNECTED');
    setLevel('table-link', up ? '' : 'bad');
    setText('table-mode', t.mode || '—');
    setText('table-interlock', t.interlock === 'fault' ? 'FAULT' : (t.interlock || '—'));
    setLevel('table-interlock', t.interlock === 'fault' ? 'bad' : '');
    setText('table-rate', t.rate_dps == null ? '—' : `${fmtNum(t.rate_dps, 3)} °/s`);
    setText('table-position', t.position_deg == null ? '—' : `${fmtNum(t.position_deg, 2)}°`);
    const d = t.demand || {};
    const demand = TABLE_DEMAND[d.mode];
    setText('table-demand', demand ? demand(d) : (d.mode || '—'));
    $('table-stopping').hidden = !t.safing;
    const h = health || {};
    setText('table-errors', fmtCount(h.errors));
    setLevel('table-errors', h.errors > 0 ? 'warn' : '');
    setText('table-fault', t.fault || (up ? '' : h.last_error || ''));
  }

  // An adaptive soak's judgement (progress.acquire, docs/api.md): each gated
  // axis's projected U95(T) of its mean (the station's points, `projection`)
  // on log-log axes up to the soak's cap, the target dashed, the acquisition
  // judged dotted with each axis's U95 there; and a line of text.
  const ACQUIRE_COLOURS = ['#38bdf8', '#a3e635', '#f472b6', '#fbbf24', '#c084fc', '#2dd4bf'];
  const SVG_NS = 'http://www.w3.org/2000/svg';
  function svgEl(name, attrs, text) {
    const e = document.createElementNS(SVG_NS, name);
    for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
    if (text != null) e.textContent = text;
    return e;
  }
  function fmtU(v) {
    return v == null || !Number.isFinite(v) ? '—' : Number(v.toPrecision(3)).toString();
  }
  function renderAcquire(a, running) {
    const show = running && a != null && Array.isArray(a.axes) && a.axes.length > 0;
    $('acquire').hidden = !show;
    if (!show) return;
    const curves = a.axes.map((axis) => {
      const pts = Array.isArray(axis.projection) ? axis.projection.filter(
        (p) => Array.isArray(p) && p[0] > 0 && p[1] > 0 && Number.isFinite(p[1])) : [];
      return pts.length > 1 ? pts : null;
    });
    let t0 = 60, t1 = Math.max(a.max_s || 0, 120);
    for (const c of curves) if (c) { t0 = Math.min(t0, c[0][0]); t1 = Math.max(t1, c[c.length - 1][0]); }
    let lo = a.target_u95_dph, hi = a.target_u95_dph;
    for (const c of curves) {
      if (!c) continue;
      for (const [, v] of c) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
    }
    lo /= 1.5;
    hi *= 1.5;
    const W = 420, H = 150, L = 44, R = 8, T = 8, B = 22;
    const x = (t) => L + (W - L - R) * Math.log(t / t0) / Math.log(t1 / t0);
    const y = (v) => T + (H - T - B) * (1 - Math.log(v / lo) / Math.log(hi / lo));
    const svg = $('acquire-plot');
    svg.replaceChildren();
    svg.appendChild(svgEl('rect', { class: 'frame', x: L, y: T, width: W - L - R, height: H - T - B }));
    const yt = y(a.target_u95_dph);
    svg.appendChild(svgEl('line', { class: 'target', x1: L, x2: W - R, y1: yt, y2: yt }));
    svg.appendChild(svgEl('text', { x: L + 4, y: yt - 3 }, `target ${fmtU(a.target_u95_dph)} °/h`));
    if (a.acquired_s > 0) {
      const xn = x(Math.min(Math.max(a.acquired_s, t0), t1));
      svg.appendChild(svgEl('line', { class: 'now', x1: xn, x2: xn, y1: T, y2: H - B }));
    }
    svg.appendChild(svgEl('text', { x: L, y: H - 6 }, fmtDuration(t0)));
    svg.appendChild(svgEl('text', { x: W - R, y: H - 6, 'text-anchor': 'end' }, fmtDuration(t1)));
    svg.appendChild(svgEl('text', { x: L - 4, y: T + 9, 'text-anchor': 'end' }, fmtU(hi)));
    svg.appendChild(svgEl('text', { x: L - 4, y: T + 20, 'text-anchor': 'end' }, '°/h'));
    svg.appendChild(svgEl('text', { x: L - 4, y: H - B, 'text-anchor': 'end' }, fmtU(lo)));
    curves.forEach((c, i) => {
      if (!c) return;
      const colour = ACQUIRE_COLOURS[i % ACQUIRE_COLOURS.length];
      const d = c.map(([t, v], j) => `${j ? 'L' : 'M'}${x(t).toFixed(1)},${y(v).toFixed(1)}`).join('');
      const path = svgEl('path', { class: 'curve', d, stroke: colour });
      path.dataset.axis = a.axes[i].name;
      path.appendChild(svgEl('title', {}, `${a.axes[i].name}: ${a.axes[i].note}`));
      svg.appendChild(path);
      svg.appendChild(svgEl('text', { x: W - R - 4, y: T + 11 + 11 * i, 'text-anchor': 'end',
        fill: colour, style: `fill: ${colour}` }, `— ${a.axes[i].name}`));
      if (a.axes[i].u95_dph > 0 && a.acquired_s > 0) {
        svg.appendChild(svgEl('circle', { cx: x(Math.min(Math.max(a.acquired_s, t0), t1)),
          cy: y(a.axes[i].u95_dph), r: 3, fill: colour }));
      }
    });
    const widest = a.axes.reduce((w, axis) =>
      (axis.u95_dph != null && (!w || axis.u95_dph > w.u95_dph) ? axis : w), null);
    const verdicts = a.axes.map((axis) => `${axis.name} ${axis.verdict.replace(/_/g, ' ')}`);
    const when = a.planned_s != null
      ? `target in ~${fmtDuration(Math.max(0, a.planned_s - a.acquired_s))}`
      : 'target not projected within the cap';
    setText('acquire-text', `U95 ${widest ? fmtU(widest.u95_dph) : '—'} → ` +
      `${fmtU(a.target_u95_dph)} °/h after ${fmtDuration(a.acquired_s)}, ${when} · ` +
      verdicts.join(', '));
  }

  // The step's progress bar, or the stability gate's while a soak settles
  // (no fraction then: settling has no fixed length), and the run's and the
  // queue's time left.
  function renderProgress(p, running, queueLength) {
    $('progress').hidden = !p || (!running && !(queueLength > 0));
    if (!p) return;
    setText('progress-phase', running ? (p.phase || '').replace('_', ' ') : 'queue');
    const fraction = p.step_fraction;
    const hasFraction = running && fraction != null && Number.isFinite(fraction);
    $('step-bar').hidden = !running;
    $('step-fill').style.width = hasFraction ? `${(100 * fraction).toFixed(1)}%` : '0%';
    $('step-bar').setAttribute('aria-valuenow', hasFraction ? Math.floor(100 * fraction) : 0);
    setText('step-progress', !running ? '—' : hasFraction
      ? `step ${Math.floor(100 * fraction)}% · ${fmtDuration(p.step_elapsed_s)} of ` +
        `${fmtDuration(p.step_planned_s)}`
      : `settling for ${fmtDuration(p.step_elapsed_s)}, then ${fmtDuration(p.step_planned_s)}`);
    const gate = running && p.gate_held_s != null && p.gate_needed_s > 0;
    $('gate-bar').hidden = !gate;
    if (gate) {
      const g = Math.min(1, p.gate_held_s / p.gate_needed_s);
      $('gate-fill').style.width = `${(100 * g).toFixed(1)}%`;
      $('gate-bar').setAttribute('aria-valuenow', Math.floor(100 * g));
      const forecast = fmtSettle(p.settle);
      setText('gate-progress', `${p.phase === 'spinning_up' ? 'at rate' : 'stability gate'} ` +
        `${fmtClock(p.gate_held_s)} of ${fmtClock(p.gate_needed_s)}` +
        (forecast ? ` · ${forecast}` : ''));
      $('gate-progress').title = p.settle ? p.settle.note || '' : '';
    }
    renderAcquire(p.acquire, running);
    const etaBand = p.run_eta_p10_s != null
      ? ` (P10 ${fmtDuration(p.run_eta_p10_s)} – P90 ` +
        `${p.run_eta_p90_s != null ? fmtDuration(p.run_eta_p90_s) : 'beyond 48 h'}` +
        `${p.prior_settles > 0 ? `; settles from the chamber's last ${p.prior_settles}` : ''})`
      : '';
    setText('run-eta', !running ? 'no run'
      : p.run_eta_s != null ? `run ends in ${fmtDuration(p.run_eta_s)}${etaBand}`
        : `run ≥ ${fmtFixed(p.run_remaining_fixed_s, p.run_settles_remaining)}`);
    const queuePrior = p.queue_settles > 0 && p.queue_eta_s != null
      ? `, ~${fmtDuration(p.queue_eta_s)} with the chamber's past settles ` +
        `(P10 ${fmtDuration(p.queue_eta_p10_s)} – P90 ${fmtDuration(p.queue_eta_p90_s)})`
      : '';
    setText('queue-eta', queueLength > 0
      ? `queue ≥ ${fmtFixed(p.queue_fixed_s, p.queue_settles)}${queuePrior}` : 'queue empty');
  }

  // One card per DUT: serial, model, live rate per axis, internal
  // temperature, samples/s, link health. The first DUT's primary axis is
  // highlighted (it is the station's gyro rate).
  function dutCard(d, first) {
    const card = document.createElement('div');
    card.className = 'panel card dut' + (first ? ' first' : '');
    card.dataset.serial = d.serial || '';
    const h = d.health || {};
    const h3 = document.createElement('h3');
    const dot = document.createElement('span');
    dot.className = 'dot';
    const bad = h.crc_failures > 0 || h.sequence_gaps > 0 || h.frames_missed > 0;
    dot.dataset.ok = !h.connected ? 'bad' : bad ? 'warn' : 'ok';
    const serial = document.createElement('span');
    serial.className = 'serial';
    serial.textContent = d.serial || '(no serial)';
    const model = document.createElement('span');
    model.className = 'muted model';
    model.textContent = d.model || '';
    h3.append(dot, serial, model);
    const rates = document.createElement('dl');
    rates.className = 'rates';
    for (const [axis, v] of Object.entries(d.rates_dph || {})) {
      const dt = document.createElement('dt');
      dt.textContent = axis;
      const dd = document.createElement('dd');
      dd.className = 'mono rate';
      dd.dataset.axis = axis;
      dd.textContent = fmtNum(v, 3);
      const u = document.createElement('span');
      u.className = 'u';
      u.textContent = '°/h';
      if (first && axis === d.primary_axis) {
        dt.classList.add('primary');
        dd.classList.add('primary');
      }
      rates.append(dt, dd, u);
    }
    const kv = document.createElement('dl');
    kv.className = 'kv';
    const rows = [
      ['Internal temp', d.temp_c == null ? '—' : `${fmtNum(d.temp_c, 1)} °C`, 'temp', ''],
      ['Samples/s', fmtNum(d.samples_per_s, 0), 'sps', ''],
      ['Link', h.connected ? 'connected' : 'DISCONNECTED', 'link', h.connected ? '' : 'bad'],
      ['CRC failures', fmtCount(h.crc_failures), 'crc', h.crc_failures > 0 ? 'warn' : ''],
      ['Sequence gaps', fmtCount(h.sequence_gaps), 'gaps', h.sequence_gaps > 0 ? 'warn' : ''],
    ];
    for (const [label, value, key, level] of rows) {
      const dt = document.createElement('dt');
      dt.textContent = label;
      const dd = document.createElement('dd');
      dd.className = 'mono';
      dd.dataset.key = key;
      if (level) dd.classList.add(level);
      dd.textContent = value;
      kv.append(dt, dd);
    }
    const err = document.createElement('p');
    err.className = 'err';
    err.textContent = h.last_error || '';
    card.append(h3, rates, kv, err);
    return card;
  }

  function renderDuts(duts) {
    const section = $('duts');
    const list = Array.isArray(duts) ? duts : [];
    section.hidden = list.length === 0;
    section.replaceChildren(...list.map((d, i) => dutCard(d, i === 0)));
  }

  function renderStatus(s) {
    const dev = s.devices || {};
    const running = s.run_id != null;

    setText('station', s.station || '—');
    document.title = `${s.state || '—'} · ${s.station || 'station'} · gyrotherm`;
    setText('t-station', fmtClock(s.t_station_s));
    setText('t-run', running ? fmtClock(s.t_run_s) : '—');
    setText('time-scale', s.time_scale == null ? '—'
      : s.time_scale === 1 ? 'real time' : `×${fmtNum(s.time_scale, s.time_scale % 1 ? 1 : 0)}`);
    setText('uptime', fmtClock(s.uptime_s));

    const state = $('state');
    setText('state', (s.state || '—').toUpperCase());
    state.dataset.state = s.state || '';
    $('flag-paused').hidden = !s.paused;
    setText('paused', s.paused ? 'YES' : 'no');
    setLevel('paused', s.paused ? 'warn' : '');

    setText('run', running ? `#${s.run_id}` : '—');
    setText('schedule', s.schedule || '—');
    const step = s.step || {};
    setText('step-label', step.label || '—');
    setText('step-index', step.index != null && step.count ? `(${step.index + 1} of ${step.count})` : '');
    setText('queue', `${fmtCount(s.queue_length)} waiting`);
    $('queue-held').hidden = !s.queue_held;
    setText('hold-reason', s.queue_held ? (s.queue_hold_reason || 'held') : '—');
    setText('last-event', s.last_event || '—');
    renderProgress(s.progress, running, s.queue_length);
    renderDuts(s.duts);

    const interlocks = s.interlocks || [];
    setText('interlocks', interlocks.length
      ? interlocks.map((i) => i.kind).join(', ') : 'none tripped');
    setLevel('interlocks', interlocks.length ? 'bad' : '');
    const banner = $('banner-interlocks');
    banner.hidden = interlocks.length === 0;
    setText('banner-interlocks', interlocks.length
      ? 'INTERLOCK TRIPPED — ' + interlocks.map((i) => `${i.kind}: ${i.message}`).join(' · ') : '');

    setText('setpoint', fmtNum(s.setpoint_c, 2));
    setText('chamber', fmtNum(s.chamber_c, 2));
    setText('top', fmtNum(s.top_c, 2));
    setText('side', fmtNum(s.side_c, 2));
    setText('gradient', fmtNum(s.gradient_c, 3));
    setText('temp-rate', fmtNum(s.temp_rate_c_per_min, 2));
    setText('gyro-rate', fmtNum(s.gyro_rate_dph, 3));

    renderDevice('chamber', dev.chamber);
    renderDevice('probes', dev.probes);
    renderTable(s.table, dev.table);

    const g = dev.gyro || {};
    $('gyro-conn').dataset.ok = g.connected ? 'ok' : 'bad';
    setText('gyro-link', g.connected ? 'connected' : 'DISCONNECTED');
    setLevel('gyro-link', g.connected ? '' : 'bad');
    setText('gyro-sps', fmtNum(s.gyro_samples_per_s, 1));
    for (const [id, v] of [['gyro-crc', g.crc_failures], ['gyro-gaps', g.sequence_gaps],
      ['gyro-missed', g.frames_missed], ['gyro-reopens', g.reopens]]) {
      setText(id, fmtCount(v));
      setLevel(id, v > 0 ? 'warn' : '');
    }
    setText('gyro-error', g.last_error || '');

    const st = s.storage || {};
    const storageOk = !st.commit_failures && !st.dropped && !st.last_error;
    $('storage-conn').dataset.ok = storageOk ? 'ok' : 'warn';
    setText('storage-pending', fmtCount(st.pending));
    setText('storage-dropped', fmtCount(st.dropped));
    setLevel('storage-dropped', st.dropped > 0 ? 'bad' : '');
    setText('storage-commits', fmtCount(st.commits));
    setText('storage-failures', fmtCount(st.commit_failures));
    setLevel('storage-failures', st.commit_failures > 0 ? 'bad' : '');
    setText('storage-last', st.last_commit_ms == null ? '—' : `${fmtNum(st.last_commit_ms, 2)} ms`);
    setText('storage-max', st.max_commit_ms == null ? '—' : `${fmtNum(st.max_commit_ms, 2)} ms`);
    setText('storage-error', st.last_error || '');

    const note = running ? 'x: run time (station), h:mm:ss · last hour'
      : 'x: station time since daemon start, h:mm:ss · last hour';
    setText('axis-note-t', note);
    setText('axis-note-g', note);
  }

  // Appends the snapshot to the plots; switches the plots when the run changed.
  function plotStatus(s) {
    const running = s.run_id != null;
    const key = running ? s.run_id : null;
    if (key !== plotKey) {
      plotKey = key;
      temperature.reset();
      gyro.reset();
      if (running) {
        loadRun(s.run_id, s.t_run_s);
        loadEvents(s.run_id);
      } else {
        setChannels([]);
      }
    }
    const t = running ? s.t_run_s : s.t_station_s;
    if (t == null || !Number.isFinite(t)) return;
    temperature.push([t, s.setpoint_c, s.chamber_c, s.top_c, s.side_c]);
    gyro.push([t, liveValue(s), null, null]);
    redraw();
  }

  let lastStatus = null;

  function applyStatus(s) {
    lastStatus = s;
    lastStatusAt = Date.now();
    renderStatus(s);
    plotStatus(s);
  }

  // ----------------------------------------------------------------- stream
  let source = null;       // EventSource (no token)
  let reader = null;       // AbortController of the fetch() stream (token)
  let reconnectTimer = 0;
  let lastStatusAt = 0;
  let linkUp = false;
  let streamLost = false;

  function setLink(state, text) {
    const link = $('link');
    link.dataset.state = state;
    setText('link-text', text);
    const down = state !== 'live';
    $('banner-disconnected').hidden = !down || state === 'connecting' ||
      !$('token-form').hidden;
    document.body.classList.toggle('stale', down);
  }

  function parse(type, data) {
    try {
      return JSON.parse(data);
    } catch (err) {
      console.error(`stream: bad ${type} message:`, err.message);
      return null;
    }
  }

  // One stream message, from either reader.
  function onMessage(type, data) {
    if (type === 'status') {
      const s = parse(type, data);
      if (!s) return;
      linkUp = true;
      setLink('live', 'Live');
      applyStatus(s);
    } else if (type === 'state') {
      const st = parse(type, data);
      if (!st || !st.to) return;
      setText('state', st.to.toUpperCase());
      $('state').dataset.state = st.to;
    } else if (type === 'event') {
      const ev = parse(type, data);
      if (ev) addEvents([ev]);
    }
  }

  function onOpen() {
    // After a gap the plots are refilled from the samples route.
    if (streamLost) plotKey = undefined;
    streamLost = false;
  }

  function onLost() {
    linkUp = false;
    streamLost = true;
    setLink('down', 'Disconnected — reconnecting');
  }

  function stopStream() {
    clearTimeout(reconnectTimer);
    if (source) source.close();
    source = null;
    if (reader) reader.abort();
    reader = null;
  }

  function reconnectLater() {
    clearTimeout(reconnectTimer);
    reconnectTimer = setTimeout(openStream, RECONNECT_MS);
  }

  function openStream() {
    stopStream();
    if (token) {
      readStream();
      return;
    }
    source = new EventSource('/api/v1/stream');
    source.addEventListener('open', onOpen);
    for (const type of ['status', 'state', 'event']) {
      source.addEventListener(type, (e) => onMessage(type, e.data));
    }
    source.addEventListener('error', () => {
      onLost();
      if (source && source.readyState === EventSource.CLOSED) {
        // The browser retries by itself unless the answer was not a stream
        // (e.g. 503: too many clients, 401: a token is needed); then retry
        // here, or ask for the token.
        source.close();
        source = null;
        fetch('/api/v1/status', { cache: 'no-store' }).then((r) => {
          if (r.status === 401) askForToken(false);
          else reconnectLater();
        }, reconnectLater);
      }
    });
  }

  // The stream through fetch(), so the token goes in a header: splits the
  // text/event-stream body into messages ("event:" and "data:" lines, a
  // blank line ends one) as EventSource would.
  async function readStream() {
    const controller = new AbortController();
    reader = controller;
    try {
      const r = await fetch('/api/v1/stream', {
        cache: 'no-store', headers: authHeaders(), signal: controller.signal,
      });
      if (r.status === 401) {
        askForToken(true);
        return;
      }
      if (!r.ok || !r.body) throw new Error(`HTTP ${r.status}`);
      onOpen();
      const body = r.body.getReader();
      const decoder = new TextDecoder();
      let buffer = '';
      for (;;) {
        const { value, done } = await body.read();
        if (done) break;
        buffer += decoder.decode(value, { stream: true });  // the daemon ends lines with \n
        let end;
        while ((end = buffer.indexOf('\n\n')) >= 0) {
          const block = buffer.slice(0, end);
          buffer = buffer.slice(end + 2);
          let type = 'message';
          const data = [];
          for (const line of block.split('\n')) {
            const colon = line.indexOf(':');
            const field = colon < 0 ? line : line.slice(0, colon);
            let v = colon < 0 ? '' : line.slice(colon + 1);
            if (v.startsWith(' ')) v = v.slice(1);
            if (field === 'event') type = v;
            else if (field === 'data') data.push(v);
          }
          if (data.length) onMessage(type, data.join('\n'));
        }
      }
      throw new Error('the stream ended');
    } catch (err) {
      if (controller.signal.aborted) return;  // closed on purpose
      onLost();
      reconnectLater();
    } finally {
      if (reader === controller) reader = null;
    }
  }

  setInterval(() => {
    if (linkUp && Date.now() - lastStatusAt > STALE_MS) {
      setLink('down', 'No data — stream stalled');
    }
  }, 1000);

  async function start() {
    try {
      applyStatus(await getJson('/api/v1/status'));
    } catch (err) {
      if (err instanceof Unauthorized) return;  // the token form is up
      setLink('down', 'Daemon not answering');
    }
    openStream();
  }

  // For the browser test and for a look from the developer console.
  window.dashboard = {
    temperaturePlot,
    gyroPlot,
    channel: () => chosenChannel(),
    livePoints: () => Math.min(temperature.livePoints(), gyro.livePoints()),
  };

  start();
})();
