// gyrotherm calibration report: draws the charts of a self-contained report
// page. The C++ renderer writes the tables and one <div class="chart" id=…>
// per figure, and the chart specs as JSON in <script id="report-data">
// (schema 1: charts[] of {id, title, height_px, x, y, y2, series[]}).
// Each series has its own x; series are sorted by x and joined onto one x
// with uPlot.join. "points" and "markers" series are drawn from their own
// arrays, so duplicate x values (common in a scatter) all show. A malformed
// document gets a visible error in the page and a console.error; a chart
// without data says "no data". Plain JS, no build step; uPlot is the global
// `uPlot`. For the browser test: window.report = {plots, errors, done}.
'use strict';

(() => {
  const DEFAULT_HEIGHT_PX = 340;
  const MIN_WIDTH_PX = 320;
  const EMPTY_HEIGHT_PX = 180;      // a chart with "no data" takes less room
  const LINE_POINTS_MAX = 40;       // a "line" series this short also shows its points
  const POINT_RADIUS_PX = 1.6;      // "points": a dense scatter
  const MARKER_RADIUS_PX = 5;       // "markers": a few emphasised values
  const BAND_ALPHA = 0.16;
  const POINTS_ALPHA = 0.55;
  const DASH = [7, 4];

  // Okabe & Ito's colour-blind-safe set (without its yellow, too pale on
  // white), then Tol's; taken in series order, the same on every page.
  const PALETTE = ['#0072B2', '#D55E00', '#009E73', '#CC79A7', '#E69F00', '#56B4E9',
    '#882255', '#117733', '#332288', '#999933'];

  const FONT_FAMILY = '"DejaVu Sans", "Segoe UI", system-ui, sans-serif';
  const TICK_FONT = `12px ${FONT_FAMILY}`;
  const LABEL_FONT = `600 12.5px ${FONT_FAMILY}`;
  const INK = '#1f2933';
  const GRID = 'rgba(31, 41, 51, 0.10)';
  const TICKS = 'rgba(31, 41, 51, 0.35)';

  const STYLES = new Set(['line', 'points', 'markers']);

  const plots = {};
  const errors = [];

  // A problem with the document, named by where it is.
  class ReportError extends Error {}

  // ---------------------------------------------------------------- format
  const minus = (s) => s.replace(/^-/, '\u2212');
  const SUPERSCRIPT = { '-': '\u207b', 0: '\u2070', 1: '\u00b9', 2: '\u00b2', 3: '\u00b3',
    4: '\u2074', 5: '\u2075', 6: '\u2076', 7: '\u2077', 8: '\u2078', 9: '\u2079' };

  // A value in the legend: five significant digits, exponent when far from 1.
  function fmtValue(v) {
    if (v == null || !Number.isFinite(v)) return '—';
    const a = Math.abs(v);
    if (a !== 0 && (a >= 1e6 || a < 1e-4)) return minus(v.toExponential(3));
    return minus(String(Number(v.toPrecision(5))));
  }

  // Decimals that write the tick step exactly: 0.25 needs 2, 2.5 needs 1,
  // 5 needs 0 (uPlot's steps are 1, 2, 2.5 and 5 x 10^k; the power of ten
  // alone would lose the 5 of a 2.5 step). Ticks are multiples of the step,
  // so they need no more.
  function tickDecimals(incr) {
    if (!(incr > 0) || !Number.isFinite(incr)) return 0;
    for (let d = 0; d < 12; d++) {
      const scaled = incr * 10 ** d;
      if (Math.abs(scaled - Math.round(scaled)) <= 1e-9 * scaled) return d;
    }
    return 12;
  }

  // Tick labels of a linear axis: as many decimals as the tick step has.
  function linearTicks(u, splits, axisIdx, space, incr) {
    const decimals = tickDecimals(incr);
    return splits.map((v) => {
      if (v == null) return '';
      const s = v.toFixed(decimals);
      return minus(/^-0(\.0*)?$/.test(s) ? s.slice(1) : s);  // a rounding -1e-17 is 0
    });
  }

  // Tick labels of a log axis: plain numbers, or powers of ten when far from 1.
  function logTicks(u, splits) {
    return splits.map((v) => {
      if (v == null) return '';
      const a = Math.abs(v);
      if (a >= 1e-4 && a < 1e6) return minus(String(Number(v.toPrecision(6))));
      const exp = Math.floor(Math.log10(a) + 1e-9);
      const mant = Number((v / 10 ** exp).toPrecision(3));
      const power = '10' + String(exp).split('').map((c) => SUPERSCRIPT[c]).join('');
      return mant === 1 ? power : `${minus(String(mant))}×${power}`;
    });
  }

  function rgba(hex, alpha) {
    const n = parseInt(hex.slice(1), 16);
    return `rgba(${(n >> 16) & 255}, ${(n >> 8) & 255}, ${n & 255}, ${alpha})`;
  }

  // -------------------------------------------------------------- messages
  // A visible error where it happened (a chart's div, or the top of the page).
  function showError(where, message) {
    errors.push(message);
    console.error(`report: ${message}`);
    const box = document.createElement('div');
    box.className = 'report-error';
    box.setAttribute('role', 'alert');
    box.textContent = `Chart error: ${message}`;
    if (where) {
      where.replaceChildren(box);
    } else {
      const main = document.querySelector('main') || document.body;
      main.prepend(box);
    }
  }

  function showNoData(el, title, why) {
    const box = document.createElement('div');
    box.className = 'chart-empty';
    box.style.height = `${Math.min(EMPTY_HEIGHT_PX, el.dataset.heightPx || DEFAULT_HEIGHT_PX)}px`;
    if (title) {
      const t = document.createElement('div');
      t.className = 'chart-empty-title';
      t.textContent = title;
      box.append(t);
    }
    const text = document.createElement('div');
    text.className = 'chart-empty-text';
    text.textContent = why ? `no data (${why})` : 'no data';
    box.append(text);
    el.replaceChildren(box);
  }

  // ------------------------------------------------------------- validation
  const isObject = (v) => v != null && typeof v === 'object' && !Array.isArray(v);

  function numberArray(value, where, nullable) {
    if (!Array.isArray(value)) throw new ReportError(`${where} is not an array`);
    for (let i = 0; i < value.length; i++) {
      const v = value[i];
      if (v === null && nullable) continue;
      if (typeof v !== 'number' || !Number.isFinite(v)) {
        throw new ReportError(`${where}[${i}] is ${JSON.stringify(v)}, not a number`);
      }
    }
    return value;
  }

  function axisSpec(value, where) {
    if (value === undefined) return { label: '', log: false };
    if (!isObject(value)) throw new ReportError(`${where} is not an object`);
    if (value.label !== undefined && typeof value.label !== 'string') {
      throw new ReportError(`${where}.label is not a string`);
    }
    if (value.log !== undefined && typeof value.log !== 'boolean') {
      throw new ReportError(`${where}.log is not true or false`);
    }
    return { label: value.label || '', log: !!value.log };
  }

  // Checks one series and returns it sorted by x (y and band along).
  function checkSeries(s, where) {
    if (!isObject(s)) throw new ReportError(`${where} is not an object`);
    const label = s.label === undefined ? '' : s.label;
    if (typeof label !== 'string') throw new ReportError(`${where}.label is not a string`);
    const named = label ? `${where} "${label}"` : where;
    const style = s.style === undefined ? 'line' : s.style;
    if (!STYLES.has(style)) {
      throw new ReportError(
        `${named}: style ${JSON.stringify(style)} is not line, points or markers`);
    }
    const axis = s.axis === undefined ? 'y' : s.axis;
    if (axis !== 'y' && axis !== 'y2') {
      throw new ReportError(`${named}: axis ${JSON.stringify(axis)} is not "y" or "y2"`);
    }
    const x = numberArray(s.x, `${named}.x`, false);
    const y = numberArray(s.y, `${named}.y`, true);
    if (y.length !== x.length) {
      throw new ReportError(`${named}: y has ${y.length} values, x has ${x.length}`);
    }
    let band = null;
    if (s.band !== undefined && s.band !== null) {
      if (!isObject(s.band)) throw new ReportError(`${named}.band is not an object`);
      const lo = numberArray(s.band.lo, `${named}.band.lo`, true);
      const hi = numberArray(s.band.hi, `${named}.band.hi`, true);
      if (lo.length !== x.length || hi.length !== x.length) {
        throw new ReportError(`${named}.band: lo/hi have ${lo.length}/${hi.length} values, ` +
          `x has ${x.length}`);
      }
      if (s.band.label !== undefined && typeof s.band.label !== 'string') {
        throw new ReportError(`${named}.band.label is not a string`);
      }
      band = { lo, hi, label: s.band.label || '' };
    }
    if (s.dash !== undefined && typeof s.dash !== 'boolean') {
      throw new ReportError(`${named}.dash is not true or false`);
    }

    let order = null;
    for (let i = 1; i < x.length; i++) {
      if (x[i] < x[i - 1]) {
        order = x.map((_, j) => j).sort((a, b) => x[a] - x[b] || a - b);
        break;
      }
    }
    const pick = (a) => (order ? order.map((j) => a[j]) : a.slice());
    return {
      label, style, axis, dash: !!s.dash,
      x: pick(x), y: pick(y),
      band: band && { lo: pick(band.lo), hi: pick(band.hi), label: band.label },
    };
  }

  function checkChart(c, where) {
    if (!isObject(c)) throw new ReportError(`${where} is not an object`);
    if (typeof c.id !== 'string' || !c.id) throw new ReportError(`${where}.id is not a name`);
    const named = `chart "${c.id}"`;
    if (c.title !== undefined && typeof c.title !== 'string') {
      throw new ReportError(`${named}: title is not a string`);
    }
    let height = DEFAULT_HEIGHT_PX;
    if (c.height_px !== undefined) {
      if (typeof c.height_px !== 'number' || !(c.height_px >= 120 && c.height_px <= 2000)) {
        throw new ReportError(
          `${named}: height_px ${JSON.stringify(c.height_px)} is not 120…2000`);
      }
      height = Math.round(c.height_px);
    }
    if (!Array.isArray(c.series)) throw new ReportError(`${named}: series is not an array`);
    return {
      id: c.id,
      title: c.title || '',
      height,
      x: axisSpec(c.x, `${named}: x`),
      y: axisSpec(c.y, `${named}: y`),
      y2: c.y2 === undefined || c.y2 === null ? null : axisSpec(c.y2, `${named}: y2`),
      series: c.series.map((s, i) => checkSeries(s, `${named}: series ${i}`)),
    };
  }

  // ---------------------------------------------------------------- drawing
  // Log axes: a point at x <= 0 is dropped, y/band values <= 0 become gaps.
  function forLogAxes(s, xLog, yLog) {
    let { x, y, band } = s;
    if (xLog) {
      const keep = [];
      x.forEach((v, i) => { if (v > 0) keep.push(i); });
      if (keep.length !== x.length) {
        const pick = (a) => keep.map((i) => a[i]);
        x = pick(x);
        y = pick(y);
        band = band && { lo: pick(band.lo), hi: pick(band.hi), label: band.label };
      }
    }
    if (yLog) {
      const gap = (a) => a.map((v) => (v != null && v > 0 ? v : null));
      y = gap(y);
      band = band && { lo: gap(band.lo), hi: gap(band.hi), label: band.label };
    }
    return Object.assign({}, s, { x, y, band });
  }

  // Range of finite values, or null when there are none.
  function extent(arrays) {
    let lo = Infinity;
    let hi = -Infinity;
    for (const a of arrays) {
      for (const v of a) {
        if (v == null) continue;
        if (v < lo) lo = v;
        if (v > hi) hi = v;
      }
    }
    return lo <= hi ? [lo, hi] : null;
  }

  function paddedRange(ext, log, padFraction) {
    if (!ext) return log ? [1, 10] : [0, 1];
    const [lo, hi] = ext;
    if (log) return uPlot.rangeLog(lo, hi, 10, true);
    const span = hi - lo;
    const pad = span > 0 ? span * padFraction : Math.abs(hi) * 0.05 || 1;
    return [lo - pad, hi + pad];
  }

  // Draws "points"/"markers" from the series' own sorted arrays (all of them,
  // duplicate x included) as filled circles, clipped just outside the plot.
  function dotPaths(raw, radiusPx) {
    return (u, si) => {
      const s = u.series[si];
      const r = radiusPx * uPlot.pxRatio;
      const fill = new Path2D();
      const { left, top, width, height } = u.bbox;
      for (let i = 0; i < raw.x.length; i++) {
        const yv = raw.y[i];
        if (yv == null) continue;
        const cx = u.valToPos(raw.x[i], 'x', true);
        const cy = u.valToPos(yv, s.scale, true);
        if (!Number.isFinite(cx) || !Number.isFinite(cy)) continue;
        fill.moveTo(cx + r, cy);
        fill.arc(cx, cy, r, 0, 2 * Math.PI);
      }
      const clip = new Path2D();
      clip.rect(left - 2 * r, top - 2 * r, width + 4 * r, height + 4 * r);
      return { stroke: s.points.width > 0 ? fill : null, fill, clip, flags: 3 };
    };
  }

  let measureCtx = null;

  // Axis thickness that fits its longest tick label (tick labels change with width).
  function axisSize(u, values, axisIdx, cycleNum) {
    const axis = u.axes[axisIdx];
    if (cycleNum > 1 && axis._size) return axis._size;
    measureCtx = measureCtx || document.createElement('canvas').getContext('2d');
    measureCtx.font = TICK_FONT;
    let widest = 0;
    for (const v of values || []) widest = Math.max(widest, measureCtx.measureText(v).width);
    return Math.ceil(widest + axis.ticks.size + axis.gap + 4);
  }

  function axisOptions(scale, spec, side) {
    const opts = {
      scale,
      side,
      label: spec.label || undefined,
      labelFont: LABEL_FONT,
      labelSize: 22,
      font: TICK_FONT,
      stroke: INK,
      gap: 5,
      grid: { show: side !== 1, stroke: GRID, width: 1 },
      ticks: { stroke: TICKS, width: 1, size: 5 },
      values: spec.log ? logTicks : linearTicks,
    };
    opts.size = side === 2 ? 30 : axisSize;
    return opts;
  }

  // One chart's uPlot options and data, or null when there is nothing to plot.
  function buildPlot(chart, width) {
    const y2Log = !!(chart.y2 && chart.y2.log);
    const specs = chart.series.map((s, i) => Object.assign(
      forLogAxes(s, chart.x.log, s.axis === 'y2' ? y2Log : chart.y.log),
      { colour: PALETTE[i % PALETTE.length] }));
    const hasValues = specs.some((s) => s.y.some((v) => v != null) ||
      (s.band && (s.band.lo.some((v) => v != null) || s.band.hi.some((v) => v != null))));
    if (!hasValues) return null;

    // uPlot series order (= drawing and legend order): band edges under
    // everything, then scatters, lines, markers on top. Colours follow the
    // document's series order.
    const rank = { points: 1, line: 2, markers: 3 };
    const drawn = specs.map((s, i) => i).sort((a, b) =>
      rank[specs[a].style] - rank[specs[b].style] || a - b);

    const tables = [];
    const series = [{ label: chart.x.label || 'x', value: (u, v) => fmtValue(v) }];
    const bands = [];
    const bandEdges = new Map();  // uPlot index of a series -> indices of its band edges
    const mainIndex = new Map();  // document index -> uPlot index
    const dotted = new Set();     // uPlot indices of "points" and "markers" series

    specs.forEach((s, i) => {
      if (!s.band) return;
      tables.push([s.x, s.band.lo, s.band.hi]);
      const lo = series.length;
      const edge = (which) => ({
        label: `${s.label} ${which}`,
        class: 'gt-band-edge',
        scale: s.axis,
        stroke: rgba(s.colour, 0.45),
        width: 1,
        value: (u, v) => fmtValue(v),
        points: { show: false },
      });
      series.push(edge('lower bound'), edge('upper bound'));
      bands.push({ series: [lo + 1, lo], fill: rgba(s.colour, BAND_ALPHA) });
      bandEdges.set(i, [lo, lo + 1]);
    });

    for (const i of drawn) {
      const s = specs[i];
      tables.push([s.x, s.y]);
      mainIndex.set(i, series.length);
      let label = s.label || `series ${i + 1}`;
      if (s.band) label += ` (shaded: ${s.band.label || 'bounds'})`;
      const opts = {
        label,
        scale: s.axis,
        stroke: s.colour,
        value: (u, v) => fmtValue(v),
        dash: s.dash ? DASH : undefined,
      };
      if (s.style === 'line') {
        const finite = s.y.reduce((n, v) => n + (v != null), 0);
        Object.assign(opts, {
          width: 2,
          points: { show: finite <= LINE_POINTS_MAX, size: 6, width: 1.5, fill: '#fff' },
        });
      } else {
        const marker = s.style === 'markers';
        dotted.add(series.length);
        const r = marker ? MARKER_RADIUS_PX : POINT_RADIUS_PX;
        Object.assign(opts, {
          width: 0,
          paths: () => null,
          points: {
            show: true,
            size: 2 * r,
            width: marker ? 1.5 : 0,
            stroke: marker ? '#fff' : undefined,
            fill: marker ? s.colour : rgba(s.colour, POINTS_ALPHA),
            paths: dotPaths(s, r),
          },
        });
      }
      series.push(opts);
    }

    // A "band" series' edges follow it when its legend entry is toggled.
    const edgesOf = new Map();
    for (const [doc, edges] of bandEdges) edgesOf.set(mainIndex.get(doc), edges);

    const data = uPlot.join(tables);
    const onY = (axis) => specs.filter((s) => s.axis === axis);
    const values = (list) => list.flatMap((s) => (s.band ? [s.y, s.band.lo, s.band.hi] : [s.y]));
    // Room at the ends for dots; lines alone span the plot edge to edge.
    const dots = dotted.size > 0 || series.some((o) => o.points && o.points.show === true);
    const xRange = paddedRange(extent(specs.map((s) => s.x)), chart.x.log, dots ? 0.03 : 0);
    const yRange = paddedRange(extent(values(onY('y'))), chart.y.log, 0.06);
    const useY2 = onY('y2').length > 0;
    const y2Range = paddedRange(extent(values(onY('y2'))), y2Log, 0.06);

    const scales = {
      x: { time: false, auto: false, range: () => xRange, distr: chart.x.log ? 3 : 1 },
      y: { auto: false, range: () => yRange, distr: chart.y.log ? 3 : 1 },
    };
    const axes = [axisOptions('x', chart.x, 2), axisOptions('y', chart.y, 3)];
    if (useY2) {
      const y2 = chart.y2 || { label: '', log: false };
      scales.y2 = { auto: false, range: () => y2Range, distr: y2Log ? 3 : 1 };
      axes.push(axisOptions('y2', y2, 1));
    }

    const markerOf = (u, i) => dotted.has(i);
    const idle = (u) => u.root.classList.toggle('gt-idle', u.cursor.idx == null);
    const opts = {
      title: chart.title || undefined,
      width,
      height: chart.height,
      pxAlign: 0,
      scales,
      axes,
      series,
      bands,
      cursor: {
        drag: { x: false, y: false, setScale: false },
        points: { size: 8, width: 1.5 },
      },
      legend: {
        live: true,
        markers: {
          width: (u, i) => (markerOf(u, i) ? 0 : 2),
          stroke: (u, i) => u.series[i]._stroke || u.series[i].stroke(u, i),
          fill: (u, i) => (markerOf(u, i) ? u.series[i].stroke(u, i) : 'transparent'),
          dash: (u, i) => (u.series[i].dash ? 'dashed' : 'solid'),
        },
      },
      hooks: {
        init: [idle],
        setCursor: [idle],
        setSeries: [(u, i, o) => {
          if (o == null || o.show == null) return;
          for (const e of edgesOf.get(i) || []) {
            if (u.series[e].show !== o.show) u.setSeries(e, { show: o.show });
          }
        }],
      },
    };
    return { opts, data };
  }

  function chartWidth(el) {
    return Math.max(MIN_WIDTH_PX, Math.floor(el.clientWidth));
  }

  function drawChart(el, chart) {
    el.dataset.heightPx = String(chart.height);
    el.setAttribute('role', 'img');
    if (chart.title) el.setAttribute('aria-label', chart.title);
    const built = buildPlot(chart, chartWidth(el));
    if (!built) {
      const why = chart.series.some((s) => s.x.length) &&
        (chart.x.log || chart.y.log) ? 'no positive values for the log axes' : '';
      showNoData(el, chart.title, why);
      return;
    }
    el.replaceChildren();
    const plot = new uPlot(built.opts, built.data, el);
    for (const row of plot.root.querySelectorAll('.u-legend .gt-band-edge')) {
      row.style.display = 'none';
    }
    plots[chart.id] = plot;
    new ResizeObserver(() => resize(el, plot)).observe(el);
  }

  function resize(el, plot) {
    const w = chartWidth(el);
    if (w !== plot.width) plot.setSize({ width: w, height: plot.height });
  }

  function resizeAll() {
    for (const [id, plot] of Object.entries(plots)) {
      const el = document.getElementById(id);
      if (el) resize(el, plot);
    }
  }

  // ------------------------------------------------------------------- main
  function readDocument() {
    const script = document.getElementById('report-data');
    if (!script) throw new ReportError('no <script id="report-data"> in the page');
    let doc;
    try {
      doc = JSON.parse(script.textContent);
    } catch (err) {
      throw new ReportError(`report-data is not valid JSON: ${err.message}`);
    }
    if (!isObject(doc)) throw new ReportError('report-data is not a JSON object');
    if (doc.schema !== 1) {
      throw new ReportError(`report-data schema ${JSON.stringify(doc.schema)} is not 1`);
    }
    if (!Array.isArray(doc.charts)) throw new ReportError('report-data has no charts array');
    return doc;
  }

  function main() {
    if (typeof uPlot !== 'function') {
      showError(null, 'uPlot is not loaded: the page lacks its inlined script');
      return;
    }
    let doc;
    try {
      doc = readDocument();
    } catch (err) {
      showError(null, err.message);
      return;
    }

    const divs = new Map();
    for (const el of document.querySelectorAll('div.chart')) {
      if (el.id) divs.set(el.id, el);
      else showError(el, 'a <div class="chart"> has no id');
    }
    const drawn = new Set();
    doc.charts.forEach((raw, i) => {
      const id = isObject(raw) && typeof raw.id === 'string' ? raw.id : null;
      const twice = id !== null && drawn.has(id);
      const el = id && !twice ? divs.get(id) : null;  // a second description leaves the first drawn
      try {
        if (twice) throw new ReportError(`chart "${id}" is described twice`);
        const chart = checkChart(raw, `charts[${i}]`);
        if (!el) {
          throw new ReportError(`chart "${chart.id}": no <div class="chart" id="${chart.id}">`);
        }
        drawn.add(chart.id);
        drawChart(el, chart);
      } catch (err) {
        if (id) drawn.add(id);
        const message = err instanceof ReportError ? err.message
          : `chart ${id ? `"${id}"` : i}: ${err && err.message ? err.message : err}`;
        showError(el || null, message);
      }
    });
    for (const [id, el] of divs) {
      if (!drawn.has(id)) showError(el, `chart "${id}" has no description in report-data`);
    }

    // Print layout is narrower than the screen: fit the charts to it and back.
    window.addEventListener('beforeprint', resizeAll);
    window.addEventListener('afterprint', resizeAll);
    window.matchMedia('print').addEventListener('change', resizeAll);
  }

  // Outside a page (node's unit test, tests/browser/report_format.test.mjs):
  // only the pure formatters, nothing drawn.
  if (typeof document === 'undefined') {
    globalThis.gyrothermReportFormat = { linearTicks, logTicks, fmtValue };
    return;
  }

  try {
    main();
  } catch (err) {
    showError(null, `report script failed: ${err && err.message ? err.message : err}`);
  }
  window.report = { plots, errors, done: true };
})();
