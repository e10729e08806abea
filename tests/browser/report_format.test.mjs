// Unit test of the report's tick-label formatters (daemon/calibration/report/report.js),
// run by node's own test runner:
//
//   node --test tests/browser/report_format.test.mjs
//
// report.js is loaded into a bare node:vm context (no document): it then only
// publishes its pure formatters as globalThis.gyrothermReportFormat. The
// labels are compared with the numbers the ticks stand for: uPlot's linear
// steps are 1, 2, 2.5 and 5 x 10^k, and a 2.5 x 10^k step needs one decimal
// more than its power of ten (10.75 must not print as 10.8, 22.5 not as 23).
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import test from 'node:test';
import { fileURLToPath } from 'node:url';
import vm from 'node:vm';

const here = path.dirname(fileURLToPath(import.meta.url));
const source = fs.readFileSync(path.join(here, '../../daemon/calibration/report/report.js'), 'utf8');
const context = vm.createContext({ console });
vm.runInContext(source, context, { filename: 'report.js' });
const format = context.gyrothermReportFormat;

// The labels' numbers (U+2212 minus back to '-').
const numbers = (labels) => Array.from(labels, (s) => Number(s.replace('\u2212', '-')));

test('report.js publishes its formatters outside a page', () => {
  assert.equal(typeof format, 'object', 'globalThis.gyrothermReportFormat is missing');
  assert.equal(typeof format.linearTicks, 'function');
});

test('every tick of every uPlot step keeps its value', () => {
  for (let k = -6; k <= 6; k++) {
    for (const m of [1, 2, 2.5, 5]) {
      const incr = Number((m * 10 ** k).toPrecision(12));
      // Ticks from an odd multiple of the step, far from zero and around it.
      for (const start of [-3, 41, 1000]) {
        const splits = [0, 1, 2, 3].map((i) => (start + i) * incr);
        const labels = format.linearTicks(null, splits, 0, 50, incr);
        const got = numbers(labels);
        splits.forEach((v, i) => {
          assert.ok(Math.abs(got[i] - v) <= 1e-9 * Math.max(Math.abs(v), incr),
            `step ${incr}: tick ${v} printed as "${labels[i]}"`);
        });
        // No more decimals than the step needs: the labels stay short.
        const decimals = labels.map((s) => (s.includes('.') ? s.split('.')[1].length : 0));
        const needed = Math.max(0, -Math.floor(Math.log10(incr) + 1e-9)) + (m === 2.5 ? 1 : 0);
        assert.ok(Math.max(...decimals) <= needed,
          `step ${incr}: labels ${labels.join(', ')} have more than ${needed} decimals`);
      }
    }
  }
});

test('the figures of the issue: 10.75 and 22.5', () => {
  // Arrays of the vm context: compared as plain arrays of this one.
  const ticks = (splits, incr) => Array.from(format.linearTicks(null, splits, 0, 50, incr));
  assert.deepEqual(ticks([10.5, 10.75, 11], 0.25), ['10.50', '10.75', '11.00']);
  assert.deepEqual(ticks([20, 22.5, 25], 2.5), ['20.0', '22.5', '25.0']);
  assert.deepEqual(ticks([-5, -2.5, 0, null], 2.5), ['\u22125.0', '\u22122.5', '0.0', '']);
  assert.deepEqual(ticks([0, 5, 10], 5), ['0', '5', '10']);
  assert.deepEqual(ticks([-0.25, -1e-17, 0.25], 0.25), ['\u22120.25', '0.00', '0.25']);
});
