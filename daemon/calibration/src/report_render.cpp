// The files of a calibration report (report.h): the HTML page, CSV, JSON and
// C headers.
#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <map>
#include <nlohmann/json.hpp>
#include <set>

#include "gyrotherm/analysis/allan.h"
#include "gyrotherm/analysis/start_temperature.h"
#include "gyrotherm/calibration/report.h"
#include "gyrotherm/core/clock.h"
#include "gyrotherm/core/text.h"
#include "report_assets.h"

namespace gyrotherm::calibration {

namespace {

using json = nlohmann::json;
constexpr const char* kDash = "—";

// ------------------------------------------------------------ text helpers

// 17 significant digits: reads back as the same double; "" for non-finite.
std::string exact(double v) { return std::isfinite(v) ? fmt::format("{:.17g}", v) : ""; }
std::string exact(const std::optional<double>& v) { return v ? exact(*v) : ""; }

// A CSV field: quoted when it holds a comma, quote or newline.
std::string csv_field(std::string_view s) {
  if (s.find_first_of(",\"\n\r") == std::string_view::npos) return std::string(s);
  std::string out = "\"";
  for (char c : s) {
    if (c == '"') out += '"';
    out += c;
  }
  return out + "\"";
}

// A number cell: right-aligned, "—" (class missing) when not finite.
std::string num_cell(double v, int decimals) {
  if (!std::isfinite(v)) return fmt::format("<td class=\"num missing\">{}</td>", kDash);
  return fmt::format("<td class=\"num\">{:.{}f}</td>", v, decimals);
}
std::string num_cell(const std::optional<double>& v, int decimals) {
  return v ? num_cell(*v, decimals) : num_cell(std::nan(""), decimals);
}
std::string sci_cell(double v) {
  if (!std::isfinite(v)) return fmt::format("<td class=\"num missing\">{}</td>", kDash);
  return fmt::format("<td class=\"num\">{:.6g}</td>", v);
}

std::string step_name(int segment_index) { return fmt::format("{}", segment_index + 1); }

// ------------------------------------------------------------ JSON of the plots

// Plotted values to 7 significant digits (a screen shows fewer; the CSV
// and JSON files carry the exact ones): the page stays small.
double plot_value(double x) {
  if (x == 0) return 0;
  const double scale = std::pow(10.0, 6 - static_cast<int>(std::floor(std::log10(std::fabs(x)))));
  return std::round(x * scale) / scale;
}

json number_array(const std::vector<double>& v) {
  json a = json::array();
  for (double x : v) a.push_back(std::isfinite(x) ? json(plot_value(x)) : json(nullptr));
  return a;
}

// ------------------------------------------------------------ HTML sections

struct Page {
  std::string title;
  std::vector<std::pair<std::string, std::string>> provenance;  // term, definition (HTML)
  std::vector<std::pair<std::string, std::string>> sections;    // id, HTML
  std::vector<std::string> section_titles;
  std::vector<Plot> plots;
};

std::string section(const std::string& id, const std::string& title, const std::string& body) {
  return fmt::format("<section id=\"{}\">\n<h2>{}</h2>\n{}</section>\n", id,
                     text::html_escape(title), body);
}

void add_section(Page& page, const std::string& id, const std::string& title,
                 const std::string& body) {
  page.sections.emplace_back(id, section(id, title, body));
  page.section_titles.push_back(title);
}

std::string chart(const Plot& p, const std::string& caption) {
  return fmt::format(
      "<figure><div class=\"chart\" id=\"{}\"></div><figcaption>{}</figcaption></figure>\n",
      text::html_escape(p.id), caption);
}

const Plot* find_plot(const std::vector<Plot>& plots, std::string_view id) {
  for (const auto& p : plots) {
    if (p.id == id) return &p;
  }
  return nullptr;
}

// A result's verdict as a table cell: "ok" with its coverage, "FLAGGED:"
// or "left out:" with the reasons, or "not assessed" (stored before v11).
std::string quality_cell(const storage::ResultQuality& q) {
  const std::string reasons = text::html_escape(fmt::format("{}", fmt::join(q.reasons, "; ")));
  const std::string coverage =
      q.coverage ? fmt::format("coverage {:.2f} %", *q.coverage * 100.0) : "coverage not known";
  if (q.flagged()) return fmt::format("<td class=\"flagged\">FLAGGED: {}</td>", reasons);
  if (q.excluded()) return fmt::format("<td class=\"flagged\">left out: {}</td>", reasons);
  if (q.verdict == "unassessed") {
    return "<td class=\"missing\" title=\"stored before results were assessed\">not "
           "assessed</td>";
  }
  return fmt::format("<td>ok, {}</td>", coverage);
}

std::string row_open(const storage::ResultQuality& q, bool warn) {
  if (q.flagged() || q.excluded()) return "<tr class=\"flagged\">";
  return warn ? "<tr class=\"warn\">" : "<tr>";
}

// The visible line under a flagged result; "" when it is not flagged.
std::string flagged_html(const storage::ResultQuality& q) {
  if (!q.flagged()) return "";
  return fmt::format("<p class=\"flagged\">FLAGGED: {}</p>\n",
                     text::html_escape(fmt::format("{}", fmt::join(q.reasons, "; "))));
}

// The half-width of the bias mean's 95 % interval; "RW" when rate random
// walk dominates it; a dash (with the reason as a tooltip) when there is none.
std::string bias_u_cell(const storage::SegmentStatsRecord& r) {
  if (!r.bias_u) {
    return fmt::format("<td class=\"num\" title=\"{}\">—</td>", text::html_escape(r.bias_u_note));
  }
  return fmt::format("<td class=\"num\">{:.4f}{}</td>", r.bias_u->expanded_dph,
                     r.bias_u->random_walk_dominated ? " RW" : "");
}

std::string table1_html(const std::vector<const storage::SegmentStatsRecord*>& rows,
                        bool with_run) {
  if (rows.empty()) return "<p class=\"problem\">No completed soak: no Table I row.</p>\n";
  std::string h = "<table class=\"numbers\">\n<thead><tr>";
  if (with_run) h += "<th>run</th>";
  h += "<th>step</th><th>set point (°C)</th><th>mean shell temperature (°C)</th><th>points "
       "(bins)</th><th>duration (s)</th><th>mean zero bias (°/h)</th><th>± U95 (°/h)</th>"
       "<th>mean, Earth rate "
       "removed (°/h)</th><th>std (°/h)</th><th>std after the moving average (°/h)</th>"
       "<th>quality</th></tr></thead>\n<tbody>\n";
  for (const auto* r : rows) {
    h += row_open(r->quality, !std::isfinite(r->bias_std_ma_dph));
    if (with_run) h += fmt::format("<td class=\"num\">{}</td>", r->run_id);
    h += fmt::format("<td class=\"num\">{}</td>", step_name(r->segment_index));
    h += num_cell(r->setpoint_c, 1) + num_cell(r->temp_mean_c, 3) +
         fmt::format("<td class=\"num\">{}</td>", r->n) + num_cell(r->duration_s, 0) +
         num_cell(r->bias_mean_dph, 4) + bias_u_cell(*r) +
         num_cell(r->bias_mean_earth_removed_dph, 4) + num_cell(r->bias_std_dph, 4) +
         num_cell(r->bias_std_ma_dph, 4) + quality_cell(r->quality) + "</tr>\n";
  }
  h += "</tbody></table>\n";
  for (const auto* r : rows) {
    if (!r->quality.flagged()) continue;
    h += fmt::format("<p class=\"flagged\">FLAGGED: {}step {}: {}</p>\n",
                     with_run ? fmt::format("run {} ", r->run_id) : std::string(),
                     step_name(r->segment_index),
                     text::html_escape(fmt::format("{}", fmt::join(r->quality.reasons, "; "))));
  }
  const auto* first = rows.front();
  h += fmt::format(
      "<p class=\"note\">Each soak's acquisition is averaged into {:g} s bins (pauses cut out); "
      "the std after the moving average uses a {}-point window. Earth rate removed: {:.4f} °/h. "
      "± U95: the half-width of the mean's 95 % interval, from the soak's own noise model (white "
      "noise, bias instability, rate random walk fitted to its Allan curve and projected to the "
      "soak's duration); RW: rate random walk dominates it, and the interval covers less often "
      "than it says. The CSV files carry every value to 17 significant digits.</p>\n",
      first->bin_s, first->ma_window, first->earth_rate_dph);
  return h;
}

// Table I as the paper prints it: the soaks grouped by their schedule set
// point (analysis::table1_by_setpoint), each column's mean ± sample std over
// the repetitions. A run's page shows it when a set point repeats; the
// campaign summary always.
std::vector<analysis::Table1Soak> table1_soaks(
    const std::vector<const storage::SegmentStatsRecord*>& rows) {
  std::vector<analysis::Table1Soak> soaks;
  for (const auto* r : rows) {
    soaks.push_back({r->setpoint_c, table1_row_of(*r)});
  }
  return soaks;
}

bool has_repetitions(const std::vector<analysis::Table1SetpointRow>& groups) {
  return std::any_of(groups.begin(), groups.end(),
                     [](const analysis::Table1SetpointRow& g) { return g.repetitions > 1; });
}

std::string spread_cells(const analysis::MeanSpread& m, int decimals) {
  return num_cell(m.n == 0 ? std::nan("") : m.mean, decimals) + num_cell(m.std, decimals);
}

// The half-width of the 95 % interval of a set point's bias mean from the
// noise within its soaks, as bias_u_cell shows a soak's.
std::string group_u_cell(const analysis::Table1SetpointRow& g) {
  if (!g.bias_mean_u) {
    return fmt::format("<td class=\"num\" title=\"{}\">—</td>",
                       text::html_escape(g.bias_mean_u_note));
  }
  return fmt::format("<td class=\"num\">{:.4f}{}</td>", g.bias_mean_u->expanded_dph,
                     g.bias_mean_u->random_walk_dominated ? " RW" : "");
}

std::string table1_groups_html(const std::vector<analysis::Table1SetpointRow>& groups) {
  std::string h =
      "<table class=\"numbers\" id=\"table1-by-setpoint\">\n<thead><tr><th rowspan=\"2\">set "
      "point (°C)</th><th rowspan=\"2\">soaks</th><th colspan=\"2\">mean shell temperature "
      "(°C)</th><th colspan=\"3\">mean zero bias (°/h)</th><th colspan=\"2\">std (°/h)</th>"
      "<th colspan=\"2\">std after the moving average (°/h)</th><th colspan=\"2\">mean, Earth "
      "rate removed (°/h)</th></tr>\n<tr><th>mean</th><th>spread</th><th>mean</th><th>± "
      "U95</th><th>spread</th>";
  for (int i = 0; i < 3; ++i) h += "<th>mean</th><th>spread</th>";
  h += "</tr></thead>\n<tbody>\n";
  for (const auto& g : groups) {
    h += g.bias_std_ma_dph.n == g.repetitions ? "<tr>" : "<tr class=\"warn\">";
    h += num_cell(g.setpoint_c, 1) + fmt::format("<td class=\"num\">{}</td>", g.repetitions) +
         spread_cells(g.temp_mean_c, 3) +
         num_cell(g.bias_mean_dph.n == 0 ? std::nan("") : g.bias_mean_dph.mean, 4) +
         group_u_cell(g) + num_cell(g.bias_mean_dph.std, 4) + spread_cells(g.bias_std_dph, 4) +
         spread_cells(g.bias_std_ma_dph, 4) + spread_cells(g.bias_mean_earth_removed_dph, 4) +
         "</tr>\n";
  }
  h += "</tbody></table>\n<p class=\"note\">The paper's form of Table I: the soaks are grouped "
       "by their schedule set point (set points within 0.001 °C are one), not by the measured "
       "temperature; each column is the mean over the soaks of a set point and its spread, the "
       "sample standard deviation (ddof = 1; — for a single soak). A soak too short for the "
       "moving average is left out of that column (row marked). ± U95 is the half-width of "
       "the 95 % interval of the mean zero bias from the noise within the soaks (their own "
       "intervals combined, the soaks taken as independent; RW: rate random walk dominates, "
       "the interval covers less than it says); how much the bias moves from one soak to the "
       "next is the spread beside it.</p>\n";
  return h;
}

std::string table1_groups_csv(const std::vector<analysis::Table1SetpointRow>& groups) {
  std::string out = "setpoint_c,soaks";
  for (const char* c : {"temp_mean_c", "bias_mean_dph", "bias_std_dph", "bias_std_ma_dph",
                        "bias_mean_earth_removed_dph"}) {
    out += fmt::format(",{0}_mean,{0}_std,{0}_n", c);
  }
  out +=
      ",bias_mean_u_dph,bias_mean_u_expanded_dph,bias_mean_u_k,bias_mean_u_dof,"
      "bias_mean_u_random_walk,bias_mean_u_note\n";
  for (const auto& g : groups) {
    out += fmt::format("{},{}", exact(g.setpoint_c), g.repetitions);
    for (const auto* m : {&g.temp_mean_c, &g.bias_mean_dph, &g.bias_std_dph, &g.bias_std_ma_dph,
                          &g.bias_mean_earth_removed_dph}) {
      out += fmt::format(",{},{},{}", exact(m->mean), exact(m->std), m->n);
    }
    if (const auto& u = g.bias_mean_u) {
      out += fmt::format(",{},{},{},{},{},", exact(u->u_dph), exact(u->expanded_dph), exact(u->k),
                         exact(u->dof), u->random_walk_dominated ? 1 : 0);
    } else {
      out += ",,,,,," + csv_field(g.bias_mean_u_note);
    }
    out += "\n";
  }
  return out;
}

// `header`: whether its C header is in the export (a flagged fit's is only
// with --force).
std::string fit_html(const ReportFit& rf, const std::string& file_stem, bool header = true) {
  const auto& f = rf.fit;
  std::string h = fmt::format(
      "<h3>{} — {}</h3>\n<table class=\"numbers\">\n<thead><tr><th>coefficient</th>"
      "<th>value</th><th>standard error</th><th>unit</th></tr></thead>\n<tbody>\n",
      text::html_escape(analysis::to_string(f.spec)),
      text::html_escape(analysis::form_label(f.form)));
  for (const auto& name : analysis::coefficient_names(f.spec, f.form)) {
    const auto c = f.coefficients.find(name);
    const auto e = f.std_errors.find(name);
    h += fmt::format("<tr><td>{}</td>{}{}<td>{}</td></tr>\n", text::html_escape(name),
                     sci_cell(c == f.coefficients.end() ? std::nan("") : c->second),
                     sci_cell(e == f.std_errors.end() ? std::nan("") : e->second),
                     text::html_escape(analysis::coefficient_unit(name)));
  }
  h += "</tbody></table>\n";
  h += flagged_html(rf.quality);
  if (const std::string warning = analysis::near_zero_warning(f); !warning.empty()) {
    h += fmt::format("<p class=\"problem\">Warning: {}</p>\n", text::html_escape(warning));
  }
  std::string l0;
  if (f.form == analysis::DriftModelForm::kPaper && !f.l0_per_series_dph.empty()) {
    std::vector<std::string> parts;
    for (double v : f.l0_per_series_dph) parts.push_back(fmt::format("{:.4f}", v));
    l0 = fmt::format(" L0 (mean of the first {:g} s) = {} °/h.", rf.l0_window_s,
                     fmt::join(parts, ", "));
  }
  std::string coverage;
  if (rf.quality.coverage) {
    coverage = fmt::format(" Coverage {:.2f} % of the samples expected, longest gap {:.3g} s.",
                           *rf.quality.coverage * 100.0, rf.quality.longest_gap_s.value_or(0));
  }
  h += fmt::format(
      "<p class=\"note\">{} points; residual std {:.4f} °/h; R² {:.4f}; condition estimate "
      "{:.3g}; derivative window {:g} s.{} {}.{} Coefficients for the gyro's computer: <a "
      "href=\"{}.json\">{}.json</a>{}.</p>\n",
      f.n, f.residual_std_dph, f.r_squared, f.condition_estimate, f.derivative_window_s, l0,
      rf.stored_id > 0 ? fmt::format("Stored by the daemon as fit {}", rf.stored_id)
                       : std::string("Computed for this report"),
      coverage, file_stem, file_stem,
      header ? fmt::format(", <a href=\"{0}.h\">{0}.h</a> (C99)", file_stem)
             : fmt::format(" ({}.h not written: the fit is flagged)", file_stem));
  return h;
}

std::string comparison_html(const analysis::Comparison& c) {
  const bool loro = std::any_of(c.cells.begin(), c.cells.end(),
                                [](const auto& cell) { return cell.cross_validated.has_value(); });
  std::string h =
      "<table class=\"numbers\">\n<thead><tr><th>order of T</th>"
      "<th>{T} (Table II)</th><th>{T, dT} (Table III)</th><th>{T, dT, dT/dt} (Table IV)</th>"
      "</tr></thead>\n<tbody>\n";
  h += fmt::format("<tr><td>none</td><td colspan=\"3\">{:.4f} (uncompensated)</td></tr>\n",
                   c.none.std_dph);
  int max_order = 0;
  for (const auto& cell : c.cells) max_order = std::max(max_order, cell.order);
  for (int order = 1; order <= max_order; ++order) {
    h += fmt::format("<tr><td class=\"num\">{}</td>", order);
    for (auto terms : {analysis::TermSet::kT, analysis::TermSet::kTG, analysis::TermSet::kTGR}) {
      const analysis::ComparisonCell* found = nullptr;
      for (const auto& cell : c.cells) {
        if (cell.order == order && cell.terms == terms) found = &cell;
      }
      if (found == nullptr || !found->in_sample) {
        const std::string why = found == nullptr ? "not computed" : found->in_sample_error;
        h += fmt::format("<td class=\"num missing\" title=\"{}\">{}</td>", text::html_escape(why),
                         kDash);
        continue;
      }
      std::string text = fmt::format("{:.4f}", found->in_sample->std_dph);
      if (loro) {
        text += found->cross_validated ? fmt::format(" / {:.4f}", found->cross_validated->std_dph)
                                       : fmt::format(" / {}", kDash);
      }
      h += fmt::format("<td class=\"num\">{}</td>", text);
    }
    h += "</tr>\n";
  }
  h += "</tbody></table>\n";
  h += fmt::format(
      "<p class=\"note\">Standard deviation (°/h) of the output after compensation with each "
      "model ({} form, dT and dT/dt of order {} and {}), {}, fitted on {} run{}{}. A dash: the "
      "fit was not possible (hover for the reason).</p>\n",
      analysis::to_string(c.options.form), c.options.g_order, c.options.r_order,
      text::html_escape(analysis::smoothing_label(c.options.smooth_points)), c.runs,
      c.runs == 1 ? "" : "s",
      loro ? "; in-sample / leave-one-run-out (each run compensated by the fit of the others)"
           : "");
  return h;
}

// An Allan noise term's cell: the value; "< bound" (class bound) when the
// curve does not reach the term's region; "—" when unavailable. The tooltip
// says how it was read or why it is a bound / missing.
std::string noise_term_cell(const analysis::NoiseTerm& t, int decimals) {
  switch (t.kind) {
    case analysis::NoiseTermKind::kValue:
      return fmt::format("<td class=\"num\" title=\"{}\">{:.{}f}</td>", text::html_escape(t.note),
                         t.value, decimals);
    case analysis::NoiseTermKind::kUpperBound:
      return fmt::format("<td class=\"num bound\" title=\"upper bound: {}\">&lt; {:.{}f}</td>",
                         text::html_escape(t.note), t.value, decimals);
    case analysis::NoiseTermKind::kUnavailable:
      break;
  }
  return fmt::format("<td class=\"num missing\" title=\"{}\">{}</td>", text::html_escape(t.note),
                     kDash);
}

// The tau a bias instability was read at: "512", "≥ 1200" (the floor not
// reached yet), "≤ 0.1" (the curve rises from the start), "—".
std::string noise_term_tau_cell(const analysis::NoiseTerm& t) {
  if (!t.tau_s || t.kind == analysis::NoiseTermKind::kUnavailable) {
    return fmt::format("<td class=\"num missing\">{}</td>", kDash);
  }
  const char* rel = t.tau_relation == ">=" ? "≥ " : t.tau_relation == "<=" ? "≤ " : "";
  return fmt::format("<td class=\"num\">{}{:.0f}</td>", rel, *t.tau_s);
}

// The noise terms of a stored curve (the record keeps only the values; the
// bounds and reasons follow from the curve, n and tau0).
analysis::AllanNoiseTerms noise_terms_of(const storage::AllanRecord& a) {
  return analysis::allan_noise_terms(static_cast<std::size_t>(std::max<int64_t>(a.n_samples, 0)),
                                     a.tau0_s, a.tau_s, a.adev_dph);
}

std::string allan_html(const std::vector<const storage::AllanRecord*>& records, bool with_run) {
  if (records.empty()) return "<p class=\"problem\">No Allan deviation.</p>\n";
  std::string h = "<table class=\"numbers\">\n<thead><tr>";
  if (with_run) h += "<th>run</th>";
  h += "<th>step</th><th>samples</th><th>τ0 (s)</th><th>angle random walk (°/√h)</th>"
       "<th>bias instability (°/h)</th><th>at τ (s)</th><th>rate random walk (°/h/√h)</th>"
       "<th>quality</th></tr></thead>\n<tbody>\n";
  bool any_bound = false;
  for (const auto* a : records) {
    const analysis::AllanNoiseTerms terms = noise_terms_of(*a);
    for (const auto* t : {&terms.angle_random_walk_dprh, &terms.bias_instability_dph,
                          &terms.rate_random_walk_dphprh}) {
      any_bound |= t->kind == analysis::NoiseTermKind::kUpperBound;
    }
    h += row_open(a->quality, false);
    if (with_run) h += fmt::format("<td class=\"num\">{}</td>", a->run_id);
    h += fmt::format("<td class=\"num\">{}</td><td class=\"num\">{}</td>",
                     step_name(a->segment_index), a->n_samples) +
         num_cell(a->tau0_s, 4) + noise_term_cell(terms.angle_random_walk_dprh, 5) +
         noise_term_cell(terms.bias_instability_dph, 5) +
         noise_term_tau_cell(terms.bias_instability_dph) +
         noise_term_cell(terms.rate_random_walk_dphprh, 5) + quality_cell(a->quality) + "</tr>\n";
  }
  h += "</tbody></table>\n";
  for (const auto* a : records) {
    if (!a->quality.flagged()) continue;
    h += fmt::format("<p class=\"flagged\">FLAGGED: {}step {}: {}</p>\n",
                     with_run ? fmt::format("run {} ", a->run_id) : std::string(),
                     step_name(a->segment_index),
                     text::html_escape(fmt::format("{}", fmt::join(a->quality.reasons, "; "))));
  }
  h += fmt::format(
      "<p class=\"note\">Overlapping Allan deviation of each soak's longest acquisition window, "
      "samples as recorded, {} τ; the band is the 1σ confidence interval (χ²). Bias "
      "instability: {}.{}</p>\n",
      records.front()->taus, records.front()->bias_instability_method,
      any_bound ? " “&lt; x”: an upper bound — the curve does not reach the term's region (bias "
                  "instability: no minimum yet, the floor lies at τ ≥ the last τ; random walks: "
                  "no slope ∓½ stretch), so the term is below x, read from the curve's end point "
                  "(hover for details). A dash: not readable (hover for the reason)."
                : "");
  return h;
}

// ------------------------------------------------------------ scale factor

// A ppm cell of an optional figure (asymmetry, repeatability): "—" with the
// reason as its tooltip when absent.
std::string ppm_cell(const std::optional<double>& v, const char* why_absent) {
  if (!v) return fmt::format("<td class=\"num missing\" title=\"{}\">{}</td>", why_absent, kDash);
  return num_cell(*v, 1);
}

// The sequences' lines (one row each), with the run when `with_run`.
std::string sf_fits_html(const std::vector<const ReportScaleFactor*>& runs, bool with_run) {
  std::string h = "<table class=\"numbers\" id=\"sf-sequences\">\n<thead><tr>";
  if (with_run) h += "<th>run</th>";
  h += "<th>sequence</th><th>temperature (°C)</th><th>K</th><th>standard error of K</th>"
       "<th>bias (°/h)</th><th>nonlinearity (ppm of K)</th><th>nonlinearity (ppm of full "
       "scale)</th><th>asymmetry (ppm)</th><th>repeatability (ppm)</th><th>points</th>"
       "<th>quality</th></tr></thead>\n<tbody>\n";
  std::string flagged;
  for (const auto* sf : runs) {
    for (const auto& f : sf->fits) {
      h += row_open(f.quality, false);
      if (f.quality.flagged()) {
        flagged +=
            fmt::format("<p class=\"flagged\">FLAGGED: {}sequence {}: {}</p>\n",
                        with_run ? fmt::format("run {} ", f.run_id) : std::string(), f.sf_sequence,
                        text::html_escape(fmt::format("{}", fmt::join(f.quality.reasons, "; "))));
      }
      if (with_run) h += fmt::format("<td class=\"num\">{}</td>", f.run_id);
      h += fmt::format("<td class=\"num\">{}</td>", f.sf_sequence) + num_cell(f.temperature_c, 2) +
           num_cell(f.k, 9) + sci_cell(f.k_se) + num_cell(f.bias_dps * 3600.0, 4) +
           num_cell(f.nonlinearity_ppm, 1) + num_cell(f.nonlinearity_fs_ppm, 1) +
           ppm_cell(f.asymmetry_ppm, "one direction only") +
           ppm_cell(f.repeatability_ppm, "fewer than 2 repetitions") +
           fmt::format("<td class=\"num\">{}</td>", f.n_points) + quality_cell(f.quality) +
           "</tr>\n";
    }
  }
  h += "</tbody></table>\n" + flagged;
  h += "<p class=\"note\">Each sequence's rate points (both directions, every repetition) "
       "fitted by least squares to output = K · rate + bias, rates and output in °/s (the bias "
       "shown in °/h). Nonlinearity: the largest residual relative to K · rate (points at zero "
       "rate left out) and relative to K · the largest rate; asymmetry (K₊ − K₋) / K̄; "
       "repeatability the spread of K over the repetitions. A dash: not measured (hover for "
       "why). Definitions: docs/analysis.md, “Scale factor”.</p>\n";
  return h;
}

// K(T) and B(T): the coefficients and the temperature coefficients.
std::string sf_temperature_html(const ReportScaleFactor& sf, const std::string& sfx, bool header) {
  const auto& t = *sf.temperature_fit;
  std::string h = fmt::format(
      "<h3>K and bias over temperature</h3>\n<p>Polynomials of order {} in T − {:.3f} °C "
      "(the mean of the sequences' temperatures): K(T) = Σ kⱼ (T − T̄)ʲ, B(T) = Σ bⱼ (T − "
      "T̄)ʲ.</p>\n",
      t.order, t.t_centre_c);
  h += fmt::format(
      "<dl class=\"sf-coefficients\"><dt>Scale-factor temperature coefficient</dt><dd "
      "id=\"sf-k-ppm-per-c\">{:.3f} ppm/°C</dd><dt>Bias temperature coefficient</dt><dd "
      "id=\"sf-bias-dph-per-c\">{:.4f} (°/h)/°C</dd></dl>\n",
      t.k_ppm_per_c, t.bias_dph_per_c);
  if (sf.k_coeffs.empty()) return h;
  h += "<table class=\"numbers\" id=\"sf-polynomials\">\n<thead><tr><th>power j</th><th>kⱼ "
       "(per °Cʲ)</th><th>bⱼ (°/h per °Cʲ)</th></tr></thead>\n<tbody>\n";
  for (std::size_t j = 0; j < sf.k_coeffs.size(); ++j) {
    h +=
        fmt::format("<tr><td class=\"num\">{}</td>{}{}</tr>\n", j, sci_cell(sf.k_coeffs[j]),
                    sci_cell(j < sf.bias_coeffs_dph.size() ? sf.bias_coeffs_dph[j] : std::nan("")));
  }
  h += "</tbody></table>\n<p class=\"note\">The temperature coefficients are dK/dT / K and "
       "dB/dT at T̄ (k₁ / k₀ × 10⁶ and b₁). Coefficients for the gyro's computer: " +
       (header ? fmt::format("<a href=\"scale-factor{0}.json\">scale-factor{0}.json</a>, <a "
                             "href=\"scale-factor{0}.h\">scale-factor{0}.h</a> (C99).</p>\n",
                             text::html_escape(sfx))
               : fmt::format("<a href=\"scale-factor{0}.json\">scale-factor{0}.json</a> "
                             "(scale-factor{0}.h not written: a line is flagged).</p>\n",
                             text::html_escape(sfx)));
  return h;
}

const storage::ScaleFactorFitRecord* sf_fit_of(const ReportScaleFactor& sf, int sequence) {
  for (const auto& f : sf.fits) {
    if (f.sf_sequence == sequence) return &f;
  }
  return nullptr;
}

// residual / (K · rate) × 1e6; NaN at zero rate or without the line.
double residual_ppm(const storage::ScaleFactorPointRecord& p,
                    const storage::ScaleFactorFitRecord* f) {
  if (f == nullptr || p.rate_dps == 0 || f->k == 0) return std::nan("");
  return scale_factor_residual_dps(p, *f) / (f->k * p.rate_dps) * 1e6;
}

// Each sequence's rate points with their residuals from its line.
std::string sf_points_html(const ReportScaleFactor& sf, const std::string& sfx) {
  std::string h;
  std::set<int> sequences;
  for (const auto& p : sf.points) sequences.insert(p.sf_sequence);
  for (int seq : sequences) {
    const auto* f = sf_fit_of(sf, seq);
    h += f ? fmt::format("<h3>Sequence {} at {:.2f} °C — rate points</h3>\n", seq, f->temperature_c)
           : fmt::format("<h3>Sequence {} — rate points (no line stored)</h3>\n", seq);
    h += fmt::format(
        "<table class=\"numbers sf-points\" id=\"sf-points-{}\">\n<thead><tr><th>repetition</th>"
        "<th>rate (°/s)</th><th>measured rate (°/s)</th><th>output (°/s)</th><th>temperature "
        "(°C)</th><th>turns</th><th>duration (s)</th><th>residual (°/h)</th><th>residual (ppm "
        "of K · rate)</th><th>quality</th></tr></thead>\n<tbody>\n",
        seq);
    for (const auto& p : sf.points) {
      if (p.sf_sequence != seq) continue;
      h += row_open(p.quality, false) + fmt::format("<td class=\"num\">{}</td>", p.repetition) +
           num_cell(p.rate_dps, 3) + num_cell(p.measured_rate_dps, 6) + num_cell(p.output_dps, 6) +
           num_cell(p.temperature_c, 2) + num_cell(p.turns, 2) + num_cell(p.duration_s, 1) +
           num_cell(f ? scale_factor_residual_dps(p, *f) * 3600.0 : std::nan(""), 4) +
           num_cell(residual_ppm(p, f), 1) + quality_cell(p.quality) + "</tr>\n";
    }
    h += "</tbody></table>\n";
    for (const auto& p : sf.points) {
      if (p.sf_sequence != seq || !(p.quality.flagged() || p.quality.excluded())) continue;
      h += fmt::format(
          "<p class=\"flagged\">{}: point at {:g} °/s, {:.2f} °C (repetition {}): "
          "{}</p>\n",
          p.quality.excluded() ? "LEFT OUT" : "FLAGGED", p.rate_dps, p.temperature_c, p.repetition,
          text::html_escape(fmt::format("{}", fmt::join(p.quality.reasons, "; "))));
    }
  }
  if (!h.empty()) {
    const double guard_s = sf.points.empty() ? 0.0 : sf.points.front().guard_s;
    h += "<p class=\"note\">Residual: output − (K · rate + bias) with the demanded rate and the "
         "sequence's line; in ppm relative to K · rate (none at zero rate). The measured rate is "
         "the table's mean over the acquisition. " +
         fmt::format(
             "Guard band: {:g} s cut from both ends of each acquisition window before the mean "
             "(then to whole turns from its start where one is left); the duration and turns are "
             "what was averaged. A point left out is not in its sequence's line. ",
             guard_s) +
         fmt::format("<a href=\"scale-factor-points{0}.csv\">scale-factor-points{0}.csv</a>",
                     text::html_escape(sfx)) +
         " has every value to 17 significant digits.</p>\n";
  }
  return h;
}

// The C identifier of a prefix: characters other than [A-Za-z0-9_] become
// '_', a leading digit gets a '_' in front.
std::string c_identifier(const std::string& prefix) {
  std::string out = prefix.empty() ? std::string("gyrotherm_sf") : prefix;
  for (char& c : out) {
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '_') c = '_';
  }
  if (std::isdigit(static_cast<unsigned char>(out.front()))) out.insert(out.begin(), '_');
  return out;
}

// A file suffix ("-17-0042-z") as part of a C identifier ("_17_0042_z").
std::string c_identifier_part(const std::string& sfx) {
  std::string out = sfx;
  for (char& c : out) {
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '_') c = '_';
  }
  return out;
}

std::string c_array(const std::vector<double>& v) {
  std::string out;
  for (double x : v) out += (out.empty() ? "" : ", ") + fmt::format("{:.17g}", x);
  return out;
}

// Horner's rule on names[0] + x * (names[1] + ...), as C.
std::string c_horner(const std::string& array, std::size_t n, const std::string& x) {
  std::string e = fmt::format("{}[{}]", array, n - 1);
  for (std::size_t j = n - 1; j-- > 0;) e = fmt::format("{}[{}] + {} * ({})", array, j, x, e);
  return e;
}

// A run's "Scale factor" section: the sequences, K(T) and B(T), the
// figures, the rate points.
std::string sf_section_html(const ReportScaleFactor& sf, const std::vector<Plot>& plots,
                            const std::string& sfx, bool header) {
  std::string h = sf.fits.empty()
                      ? std::string(
                            "<p class=\"problem\">Rate points are stored but no line was "
                            "fitted to them.</p>\n")
                      : sf_fits_html({&sf}, false);
  if (sf.temperature_fit) h += sf_temperature_html(sf, sfx, header);
  if (const auto* p = find_plot(plots, "chart-sf-k-temperature")) {
    h += chart(*p,
               "K of each sequence relative to K at the centre temperature, in ppm, with the "
               "fitted polynomial K(T).");
  }
  if (const auto* p = find_plot(plots, "chart-sf-bias-temperature")) {
    h += chart(*p, "The bias of each sequence's line, °/h, with the fitted polynomial B(T).");
  }
  if (const auto* p = find_plot(plots, "chart-sf-nonlinearity")) {
    h += chart(*p, "Nonlinearity of each sequence, relative to K · rate and to full scale.");
  }
  h += sf_points_html(sf, sfx);
  return h;
}

// The summary's "Scale factor" section: every run's sequences, and each
// run's temperature coefficients.
std::string sf_campaign_html(const CampaignReport& c) {
  std::vector<const ReportScaleFactor*> runs;
  std::string coefficients;
  for (const auto& r : c.runs) {
    if (!r.scale_factor) continue;
    runs.push_back(&*r.scale_factor);
    const auto& sf = *r.scale_factor;
    if (!sf.temperature_fit) continue;
    const auto& t = *sf.temperature_fit;
    coefficients += fmt::format(
        "<tr><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td>{}{}{}{}"
        "<td><a href=\"run-{:04}/report{}.html#scale-factor\">run-{:04}</a></td></tr>\n",
        r.run.id, sf.fits.size(), t.order, num_cell(t.t_centre_c, 2),
        num_cell(sf.k_coeffs.empty() ? std::nan("") : sf.k_coeffs.front(), 9),
        num_cell(t.k_ppm_per_c, 3), num_cell(t.bias_dph_per_c, 4), r.run.id,
        text::html_escape(r.file_suffix), r.run.id);
  }
  std::string h = sf_fits_html(runs, true);
  if (!coefficients.empty()) {
    h += "<h3>Over temperature, per run</h3>\n<table class=\"numbers\" "
         "id=\"sf-temperature-coefficients\">\n<thead><tr><th>run</th><th>sequences</th>"
         "<th>order</th><th>centre temperature (°C)</th><th>K at the centre</th><th>K "
         "temperature coefficient (ppm/°C)</th><th>bias temperature coefficient "
         "((°/h)/°C)</th><th>report</th></tr></thead>\n<tbody>\n" +
         coefficients + "</tbody></table>\n";
  }
  return h;
}

std::string problems_html(const std::vector<std::string>& problems) {
  std::string h;
  for (const auto& p : problems)
    h += fmt::format("<p class=\"problem\">{}</p>\n", text::html_escape(p));
  return h;
}

std::string files_html(const std::vector<std::pair<std::string, std::string>>& files) {
  std::string h = "<ul class=\"files\">\n";
  for (const auto& [path, what] : files) {
    h += fmt::format("<li><a href=\"{}\">{}</a> — {}</li>\n", text::html_escape(path),
                     text::html_escape(path), text::html_escape(what));
  }
  return h + "</ul>\n";
}

std::string render_page(const Page& page, const std::string& generated_utc) {
  std::string h;
  h.reserve(256 * 1024);
  h += "<!doctype html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
       "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
       "<meta http-equiv=\"Content-Security-Policy\" content=\"default-src 'none'; script-src "
       "'unsafe-inline'; style-src 'unsafe-inline'; img-src data:\">\n";
  h += fmt::format("<title>{}</title>\n", text::html_escape(page.title));
  h += "<style>\n";
  h += report_assets::uplot_css();
  h += "\n</style>\n<style>\n";
  h += report_assets::report_css();
  h += "\n</style>\n</head>\n<body>\n<header class=\"report-header\">\n";
  h += fmt::format("<h1>{}</h1>\n<dl class=\"provenance\">\n", text::html_escape(page.title));
  for (const auto& [term, definition] : page.provenance) {
    h += fmt::format("<dt>{}</dt><dd>{}</dd>\n", text::html_escape(term), definition);
  }
  h += "</dl>\n</header>\n<nav class=\"toc\">";
  for (std::size_t i = 0; i < page.sections.size(); ++i) {
    h += fmt::format("<a href=\"#{}\">{}</a>", page.sections[i].first,
                     text::html_escape(page.section_titles[i]));
  }
  h += "</nav>\n<main>\n";
  for (const auto& [id, body] : page.sections) h += body;
  h += fmt::format(
      "</main>\n<footer>Generated by gyrotherm on {}. Plots drawn with uPlot; this file needs "
      "no network.</footer>\n",
      text::html_escape(generated_utc));
  h += "<script type=\"application/json\" id=\"report-data\">" + plots_json(page.plots) +
       "</script>\n<script>\n";
  h += report_assets::uplot_js();
  h += "\n</script>\n<script>\n";
  h += report_assets::report_js();
  h += "\n</script>\n</body>\n</html>\n";
  return h;
}

std::string generated(const ReportOptions& o) {
  return o.generated_utc.empty() ? wall_time_utc_iso() : o.generated_utc;
}

analysis::ExportInfo export_info(const std::string& station, const ReportFit& f,
                                 const std::string& computed_utc) {
  analysis::ExportInfo info;
  info.station = station;
  info.run_ids = f.run_ids;
  info.computed_utc = computed_utc;
  info.l0_window_s = f.l0_window_s;
  return info;
}

// The gyro (serial, model, axis) and the run's metadata, for the exports.
void add_stream_info(analysis::ExportInfo& info, const RunReport& r) {
  info.gyro_serial = r.stream.dut_serial;
  info.gyro_model = r.stream.dut_model;
  info.axis = r.stream.axis;
  info.operator_name = r.run.metadata.operator_name;
  info.comment = r.run.metadata.comment;
  info.tags = r.run.metadata.tags;
}

// The runs' metadata joined (distinct values, in run order), for an export
// of several runs of one DUT axis.
void add_campaign_info(analysis::ExportInfo& info, const CampaignReport& c) {
  info.gyro_serial = c.dut_serial;
  info.gyro_model = c.dut_model;
  info.axis = c.axis;
  std::vector<std::string> operators, comments;
  const auto add = [](std::vector<std::string>& to, const std::string& v) {
    if (!v.empty() && std::find(to.begin(), to.end(), v) == to.end()) to.push_back(v);
  };
  for (const auto& r : c.runs) {
    add(operators, r.run.metadata.operator_name);
    add(comments, r.run.metadata.comment);
    for (const auto& t : r.run.metadata.tags) add(info.tags, t);
  }
  info.operator_name = fmt::format("{}", fmt::join(operators, ", "));
  info.comment = fmt::format("{}", fmt::join(comments, "; "));
}

// "SN 17-0042 (KVH 1750), axis z": the DUT a report is of.
std::string dut_label(const AnalysedAxis& a) {
  std::string h = a.dut_serial.empty() ? std::string("(no serial)") : "SN " + a.dut_serial;
  if (!a.dut_model.empty()) h += " (" + a.dut_model + ")";
  if (!a.axis.empty()) h += ", axis " + a.axis;
  return h;
}

std::string tags_text(const std::vector<std::string>& tags) {
  return tags.empty() ? std::string(kDash) : fmt::format("{}", fmt::join(tags, ", "));
}

// Who ran the run, why, which DUT: the top of a run's page.
void add_metadata_provenance(Page& page, const RunReport& r) {
  const storage::RunMetadata& m = r.run.metadata;
  page.provenance.insert(
      page.provenance.begin() + std::min<std::size_t>(2, page.provenance.size()),
      {{"DUT", text::html_escape(dut_label(r.stream))},
       {"Operator", text::html_escape(m.operator_name.empty() ? kDash : m.operator_name)},
       {"Comment", text::html_escape(m.comment.empty() ? kDash : m.comment)},
       {"Tags", text::html_escape(tags_text(m.tags))}});
}

std::string figures_html(const std::vector<Plot>& plots, bool campaign) {
  std::string h;
  if (const auto* p = find_plot(plots, "chart-bias-temperature")) {
    h += "<h3>Bias vs temperature (Fig. 2)</h3>\n" +
         chart(*p, campaign ? "Bin means of every run, each run's Table I means, and the "
                              "temperature-only polynomials of orders 1–4 fitted on all runs "
                              "(paper form; curves drawn at the mean L0)."
                            : "Bin means of the whole run (soaks and ramps), the Table I means, "
                              "and the temperature-only polynomials of orders 1–4 fitted on the "
                              "run (paper form: L0 + Σ Aᵢ Tⁱ).");
  }
  if (const auto* p = find_plot(plots, "chart-output-t")) {
    h += "<h3>Output compensated with temperature terms (Fig. 4)</h3>\n" +
         chart(*p,
               "The output and the output compensated by the order-2 and order-4 polynomials in "
               "T, each as its moving average (the window of Table I's last column), over the raw "
               "1 s output (dots), with the mean shell temperature (right axis).");
  }
  if (const auto* p = find_plot(plots, "chart-bias-gradient")) {
    h += "<h3>Bias vs temperature gradient (Fig. 5)</h3>\n" +
         chart(*p,
               "Output against the shell gradient (top − side), raw and after the temperature "
               "compensation: what is left for the gradient term.");
  }
  if (const auto* p = find_plot(plots, "chart-output-tgr")) {
    h += "<h3>Output compensated with temperature, gradient and rate terms (Fig. 6)</h3>\n" +
         chart(*p,
               "The output and the output compensated by T² and T⁴ models with dT and dT/dt, each "
               "as its moving average (the window of Table I's last column), over the raw 1 s "
               "output (dots).");
  }
  return h;
}

}  // namespace

// ------------------------------------------------------------ public pieces

namespace {

// The quality columns of a CSV row: coverage (fraction), coverage_samples,
// coverage_expected, longest_gap_s, quality, quality_reasons ("; "-joined).
constexpr const char* kQualityCsvColumns =
    "coverage,coverage_samples,coverage_expected,longest_gap_s,quality,quality_reasons";
std::string quality_csv(const storage::ResultQuality& q) {
  return fmt::format("{},{},{},{},{},{}", exact(q.coverage),
                     q.verdict == "unassessed" ? std::string() : std::to_string(q.samples),
                     q.expected > 0 ? exact(q.expected) : std::string(), exact(q.longest_gap_s),
                     q.verdict, csv_field(fmt::format("{}", fmt::join(q.reasons, "; "))));
}

}  // namespace

std::string table1_csv(const std::vector<storage::SegmentStatsRecord>& rows) {
  std::string out =
      "run_id,step,segment_index,setpoint_c,temp_mean_c,n,duration_s,bias_mean_dph,"
      "bias_mean_earth_removed_dph,bias_std_dph,bias_std_ma_dph,earth_rate_dph,bin_s,ma_window,"
      "t_from_s,t_to_s,computed_utc," +
      std::string(kQualityCsvColumns) +
      ",bias_u_dph,bias_u_expanded_dph,bias_u_k,bias_u_dof,bias_u_floor_dph,bias_u_random_walk,"
      "bias_u_note\n";
  for (const auto& r : rows) {
    const auto& u = r.bias_u;
    out += fmt::format(
        "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n", r.run_id,
        r.segment_index + 1, r.segment_index, exact(r.setpoint_c), exact(r.temp_mean_c), r.n,
        exact(r.duration_s), exact(r.bias_mean_dph), exact(r.bias_mean_earth_removed_dph),
        exact(r.bias_std_dph), exact(r.bias_std_ma_dph), exact(r.earth_rate_dph), exact(r.bin_s),
        r.ma_window, exact(r.t_from_s), exact(r.t_to_s), csv_field(r.computed_utc),
        quality_csv(r.quality), u ? exact(u->u_dph) : "", u ? exact(u->expanded_dph) : "",
        u ? exact(u->k) : "", u ? exact(u->dof) : "", u ? exact(u->floor_dph) : "",
        u ? (u->random_walk_dominated ? "1" : "0") : "", csv_field(r.bias_u_note));
  }
  return out;
}

std::string allan_csv(const std::vector<storage::AllanRecord>& records) {
  std::string out =
      "run_id,step,segment_index,taus,tau0_s,n_samples,angle_random_walk_dprh,"
      "bias_instability_dph,bias_instability_tau_s,rate_random_walk_dphprh,t_from_s,t_to_s,"
      "angle_random_walk_kind,angle_random_walk_bound_dprh,bias_instability_kind,"
      "bias_instability_bound_dph,bias_instability_bound_tau_s,rate_random_walk_kind,"
      "rate_random_walk_bound_dphprh," +
      std::string(kQualityCsvColumns) + "\n";
  // The value columns are empty unless the term is a value; the *_kind columns
  // say value, upper_bound or unavailable, the *_bound_* columns the bound.
  const auto bound = [](const analysis::NoiseTerm& t) {
    return t.kind == analysis::NoiseTermKind::kUpperBound ? exact(t.value) : std::string();
  };
  for (const auto& a : records) {
    const analysis::AllanNoiseTerms terms = noise_terms_of(a);
    const auto& arw = terms.angle_random_walk_dprh;
    const auto& bi = terms.bias_instability_dph;
    const auto& rrw = terms.rate_random_walk_dphprh;
    out +=
        fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n", a.run_id,
                    a.segment_index + 1, a.segment_index, csv_field(a.taus), exact(a.tau0_s),
                    a.n_samples, exact(a.angle_random_walk_dprh), exact(a.bias_instability_dph),
                    exact(a.bias_instability_tau_s), exact(a.rate_random_walk_dphprh),
                    exact(a.t_from_s), exact(a.t_to_s), analysis::to_string(arw.kind), bound(arw),
                    analysis::to_string(bi.kind), bound(bi),
                    bi.kind == analysis::NoiseTermKind::kUpperBound && bi.tau_s ? exact(*bi.tau_s)
                                                                                : std::string(),
                    analysis::to_string(rrw.kind), bound(rrw), quality_csv(a.quality));
  }
  return out;
}

namespace {

std::string allan_curves_csv(const std::vector<const storage::AllanRecord*>& records) {
  std::string out = "run_id,step,tau_s,adev_dph,adev_lo_dph,adev_hi_dph\n";
  for (const auto* a : records) {
    for (std::size_t i = 0; i < a->tau_s.size(); ++i) {
      out += fmt::format("{},{},{},{},{},{}\n", a->run_id, a->segment_index + 1, exact(a->tau_s[i]),
                         exact(a->adev_dph[i]), exact(a->adev_lo_dph[i]), exact(a->adev_hi_dph[i]));
    }
  }
  return out;
}

}  // namespace

std::string comparison_csv(const analysis::Comparison& c) {
  std::string out =
      "terms,order,model,in_sample_n,in_sample_mean_dph,in_sample_std_dph,"
      "cross_validated_n,cross_validated_mean_dph,cross_validated_std_dph,problem\n";
  out += fmt::format("none,0,,{},{},{},,,,\n", c.none.n, exact(c.none.mean_dph),
                     exact(c.none.std_dph));
  for (const auto& cell : c.cells) {
    std::string problem = cell.in_sample_error;
    if (!cell.cross_validated_error.empty()) {
      problem += (problem.empty() ? "" : "; ") + cell.cross_validated_error;
    }
    const auto stats = [](const std::optional<analysis::CompensatedStats>& s) {
      return s ? fmt::format("{},{},{}", s->n, exact(s->mean_dph), exact(s->std_dph))
               : std::string(",,");
    };
    out += fmt::format("{},{},{},{},{},{}\n", csv_field(analysis::to_string(cell.terms)),
                       cell.order, csv_field(analysis::to_string(cell.spec)), stats(cell.in_sample),
                       stats(cell.cross_validated), csv_field(problem));
  }
  return out;
}

std::string scale_factor_csv(const std::vector<const ReportScaleFactor*>& runs) {
  std::string out =
      "run_id,sf_sequence,temperature_c,k,k_se,bias_dps,bias_dph,nonlinearity_ppm,"
      "nonlinearity_fs_ppm,asymmetry_ppm,repeatability_ppm,n_points,created_utc,guard_s," +
      std::string(kQualityCsvColumns) + "\n";
  for (const auto* sf : runs) {
    for (const auto& f : sf->fits) {
      out += fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n", f.run_id, f.sf_sequence,
                         exact(f.temperature_c), exact(f.k), exact(f.k_se), exact(f.bias_dps),
                         exact(f.bias_dps * 3600.0), exact(f.nonlinearity_ppm),
                         exact(f.nonlinearity_fs_ppm), exact(f.asymmetry_ppm),
                         exact(f.repeatability_ppm), f.n_points, csv_field(f.created_utc),
                         exact(f.guard_s), quality_csv(f.quality));
    }
  }
  return out;
}

std::string scale_factor_points_csv(const ReportScaleFactor& sf) {
  std::string out =
      "run_id,sf_sequence,repetition,segment_id,rate_dps,measured_rate_dps,output_dps,n,"
      "temperature_c,duration_s,turns,residual_dps,residual_ppm,guard_s," +
      std::string(kQualityCsvColumns) + "\n";
  for (const auto& p : sf.points) {
    const auto* f = sf_fit_of(sf, p.sf_sequence);
    out += fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n", p.run_id, p.sf_sequence,
                       p.repetition, p.segment_id, exact(p.rate_dps), exact(p.measured_rate_dps),
                       exact(p.output_dps), p.n, exact(p.temperature_c), exact(p.duration_s),
                       exact(p.turns), f ? exact(scale_factor_residual_dps(p, *f)) : std::string(),
                       exact(residual_ppm(p, f)), exact(p.guard_s), quality_csv(p.quality));
  }
  return out;
}

std::string scale_factor_json(const ReportScaleFactor& sf, const analysis::ExportInfo& info) {
  using ojson = nlohmann::ordered_json;
  const auto number = [](double v) { return std::isfinite(v) ? ojson(v) : ojson(nullptr); };
  const auto optional = [&number](const std::optional<double>& v) {
    return v ? number(*v) : ojson(nullptr);
  };
  ojson j;
  j["kind"] = "gyrotherm scale factor over temperature";
  j["model"] = "output_dps = K(T) * rate_dps + bias_dph(T) / 3600";
  j["units"] = {{"rate", "deg/s (table rate and gyro output)"},
                {"K", "(deg/s)/(deg/s)"},
                {"bias", "deg/h"},
                {"T", "degC, mean shell temperature (top + side) / 2"},
                {"k_coefficients", "per degC^j, j = 0 ... order, in (T - t_centre_c)"},
                {"bias_coefficients_dph", "deg/h per degC^j, in (T - t_centre_c)"}};
  if (sf.temperature_fit && !sf.k_coeffs.empty()) {
    const auto& t = *sf.temperature_fit;
    ojson k = ojson::array(), b = ojson::array();
    for (double v : sf.k_coeffs) k.push_back(number(v));
    for (double v : sf.bias_coeffs_dph) b.push_back(number(v));
    j["temperature_fit"] = {{"order", t.order},
                            {"t_centre_c", number(t.t_centre_c)},
                            {"k_coefficients", k},
                            {"bias_coefficients_dph", b},
                            {"k_ppm_per_c", number(t.k_ppm_per_c)},
                            {"bias_dph_per_c", number(t.bias_dph_per_c)}};
  } else {
    j["temperature_fit"] = nullptr;
  }
  ojson sequences = ojson::array();
  for (const auto& f : sf.fits) {
    sequences.push_back({{"sf_sequence", f.sf_sequence},
                         {"temperature_c", number(f.temperature_c)},
                         {"k", number(f.k)},
                         {"k_se", number(f.k_se)},
                         {"bias_dph", number(f.bias_dps * 3600.0)},
                         {"nonlinearity_ppm", number(f.nonlinearity_ppm)},
                         {"nonlinearity_fs_ppm", number(f.nonlinearity_fs_ppm)},
                         {"asymmetry_ppm", optional(f.asymmetry_ppm)},
                         {"repeatability_ppm", optional(f.repeatability_ppm)},
                         {"n_points", f.n_points}});
  }
  j["sequences"] = sequences;
  j["station"] = info.station;
  j["gyro_serial"] = info.gyro_serial;
  j["gyro_model"] = info.gyro_model;
  j["axis"] = info.axis;
  j["operator"] = info.operator_name;
  j["comment"] = info.comment;
  j["tags"] = info.tags;
  j["runs"] = info.run_ids;
  j["computed_utc"] = info.computed_utc;
  return j.dump(2);
}

storage::ResultQuality scale_factor_header_quality(const ReportScaleFactor& sf) {
  storage::ResultQuality q;
  q.verdict = "ok";
  for (const auto& f : sf.fits) {
    if (!f.quality.flagged()) continue;
    q.verdict = "flagged";
    for (const auto& r : f.quality.reasons) {
      q.reasons.push_back(fmt::format("sequence {}: {}", f.sf_sequence, r));
    }
  }
  return q;
}

std::string forced_header_comment(const storage::ResultQuality& quality) {
  if (!quality.flagged()) return "";
  std::string out =
      "/* FORCED: written with --force although gyrotherm flagged this result as implausible:\n";
  for (const auto& r : quality.reasons) out += " *   " + text::c_comment_text(r) + "\n";
  out += " * Check the result before using these coefficients. */\n";
  return out;
}

std::string scale_factor_c_header(const ReportScaleFactor& sf, const analysis::ExportInfo& info,
                                  const std::string& prefix) {
  const std::string p = c_identifier(prefix);
  std::string up = p;
  for (char& c : up) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  const std::string guard = up + "_SCALE_FACTOR_H_";
  std::string runs;
  for (int64_t id : info.run_ids) runs += (runs.empty() ? "" : ", ") + std::to_string(id);
  std::string out = fmt::format(
      "/* {}.h: scale factor and bias of a fiber-optic gyro over temperature, from rate-table\n"
      " * sequences. Generated by gyrotherm; do not edit.\n"
      " * Station: {}; gyro: {}; runs: {}; computed: {}\n"
      "{}"
      " *\n"
      " * output_dps = K(T) * rate_dps + bias_dph(T) / 3600, where\n"
      " *   rate_dps   = the rate about the sensitive axis, deg/s\n"
      " *   output_dps = the gyro's output converted to deg/s\n"
      " *   T          = mean shell temperature (top + side) / 2, degC\n"
      " *   K(T) = sum_j k[j] * (T - t_centre_c)^j, bias_dph(T) = sum_j bias_dph[j] * (T - "
      "t_centre_c)^j.\n"
      " * The table of sequences gives K and the bias measured at each temperature.\n"
      " */\n",
      p, text::c_comment_text(info.station.empty() ? "(unnamed)" : info.station),
      text::c_comment_text(info.gyro_serial.empty() ? "(no serial)" : info.gyro_serial),
      runs.empty() ? "(none)" : runs,
      text::c_comment_text(info.computed_utc.empty() ? "(unknown)" : info.computed_utc),
      analysis::export_metadata_c(info));
  out += fmt::format("#ifndef {0}\n#define {0}\n\n", guard);
  if (sf.temperature_fit && !sf.k_coeffs.empty()) {
    const auto& t = *sf.temperature_fit;
    const std::size_t n = sf.k_coeffs.size();
    out += fmt::format("#define {}_ORDER {}\n", up, t.order);
    out += fmt::format("static const double {}_t_centre_c = {:.17g};\n", p, t.t_centre_c);
    out += fmt::format("static const double {}_k[{}_ORDER + 1] = {{{}}};\n", p, up,
                       c_array(sf.k_coeffs));
    out += fmt::format("static const double {}_bias_dph[{}_ORDER + 1] = {{{}}};\n", p, up,
                       c_array(sf.bias_coeffs_dph));
    out += "/* dK/dT / K at t_centre_c, ppm/degC; dbias/dT there, (deg/h)/degC. */\n";
    out += fmt::format("static const double {}_k_ppm_per_c = {:.17g};\n", p, t.k_ppm_per_c);
    out += fmt::format("static const double {}_bias_dph_per_c = {:.17g};\n\n", p, t.bias_dph_per_c);
    out += fmt::format(
        "/* K at temperature t_c (degC). */\n"
        "static inline double {0}_k_at(double t_c) {{\n"
        "  const double x = t_c - {0}_t_centre_c;\n"
        "  return {1};\n}}\n\n"
        "/* The bias at temperature t_c (degC), deg/h. */\n"
        "static inline double {0}_bias_dph_at(double t_c) {{\n"
        "  const double x = t_c - {0}_t_centre_c;\n"
        "  return {2};\n}}\n\n"
        "/* The rate about the sensitive axis, deg/s, from the output (deg/s) at t_c (degC). */\n"
        "static inline double {0}_rate_dps(double output_dps, double t_c) {{\n"
        "  return (output_dps - {0}_bias_dph_at(t_c) / 3600.0) / {0}_k_at(t_c);\n}}\n\n",
        p, c_horner(p + "_k", n, "x"), c_horner(p + "_bias_dph", n, "x"));
  }
  std::vector<double> t_c, k, bias_dph;
  for (const auto& f : sf.fits) {
    if (!std::isfinite(f.temperature_c) || !std::isfinite(f.k) || !std::isfinite(f.bias_dps)) {
      continue;
    }
    t_c.push_back(f.temperature_c);
    k.push_back(f.k);
    bias_dph.push_back(f.bias_dps * 3600.0);
  }
  if (!t_c.empty()) {
    out += fmt::format(
        "/* The sequences: mean temperature (degC), K and bias (deg/h) of each. */\n"
        "#define {0}_N_SEQUENCES {1}\n"
        "static const double {2}_table_temperature_c[{0}_N_SEQUENCES] = {{{3}}};\n"
        "static const double {2}_table_k[{0}_N_SEQUENCES] = {{{4}}};\n"
        "static const double {2}_table_bias_dph[{0}_N_SEQUENCES] = {{{5}}};\n\n",
        up, t_c.size(), p, c_array(t_c), c_array(k), c_array(bias_dph));
  }
  out += fmt::format("#endif /* {} */\n", guard);
  return out;
}

std::string plots_json(const std::vector<Plot>& plots) {
  json charts = json::array();
  for (const auto& p : plots) {
    json c = {{"id", p.id},
              {"title", p.title},
              {"height_px", p.height_px},
              {"x", {{"label", p.x.label}, {"log", p.x.log}}},
              {"y", {{"label", p.y.label}, {"log", p.y.log}}}};
    if (p.y2) c["y2"] = {{"label", p.y2->label}, {"log", p.y2->log}};
    json series = json::array();
    for (const auto& s : p.series) {
      json j = {{"label", s.label},
                {"x", number_array(s.x)},
                {"y", number_array(s.y)},
                {"style", s.style}};
      if (s.axis != "y") j["axis"] = s.axis;
      if (s.dash) j["dash"] = true;
      if (!s.band_lo.empty()) {
        j["band"] = {{"lo", number_array(s.band_lo)},
                     {"hi", number_array(s.band_hi)},
                     {"label", s.band_label}};
      }
      series.push_back(std::move(j));
    }
    c["series"] = std::move(series);
    charts.push_back(std::move(c));
  }
  std::string text = json{{"schema", 1}, {"charts", std::move(charts)}}.dump(
      -1, ' ', false, json::error_handler_t::replace);
  // The text goes inside a <script> element, which "</" would close:
  // "<\/" is the same JSON string.
  for (std::size_t at = text.find("</"); at != std::string::npos; at = text.find("</", at + 3)) {
    text.replace(at, 2, "<\\/");
  }
  return text;
}

namespace {

// The report's "Mounting" line: the axis's direction and the Earth rate its
// Table I removes.
std::string mounting_text(const RunReport& r, const AnalysisSettings& s) {
  if (!r.stream.orientation) {
    return fmt::format("latitude {:g}°, axis {}; Earth rate removed {:.4f} °/h", r.run.latitude_deg,
                       text::html_escape(r.run.orientation), s.table1.earth_rate_dph);
  }
  const analysis::AxisOrientation o = *r.stream.orientation;
  const std::string axis = text::html_escape(r.stream.axis);
  if (o != analysis::AxisOrientation::kHorizontal) {
    return fmt::format("latitude {:g}°, axis {} {}; Earth rate removed {:.4f} °/h",
                       r.run.latitude_deg, axis, analysis::to_string(o),
                       analysis::earth_rate_component_dph(r.run.latitude_deg, o));
  }
  if (!r.stream.heading_deg) {
    return fmt::format(
        "latitude {:g}°, axis {} horizontal, no heading given: taken as east–west, Earth rate "
        "removed 0 °/h",
        r.run.latitude_deg, axis);
  }
  const double dph =
      analysis::earth_rate_component_dph(r.run.latitude_deg, o, r.stream.heading_deg);
  if (read_run_config(r.run).table_present) {
    return fmt::format(
        "latitude {:g}°, axis {} horizontal, heading {:g}° at table position 0 (turning with the "
        "table); Earth rate at position 0 {:.4f} °/h, removed per soak at the table's position",
        r.run.latitude_deg, axis, *r.stream.heading_deg, dph);
  }
  return fmt::format(
      "latitude {:g}°, axis {} horizontal, heading {:g}°; Earth rate removed {:.4f} °/h",
      r.run.latitude_deg, axis, *r.stream.heading_deg, dph);
}

}  // namespace

std::vector<ReportFile> render_run_files(const RunReport& r, const ReportOptions& options) {
  const std::string dir = fmt::format("run-{:04}/", r.run.id);
  const std::string& sfx = r.file_suffix;  // "" for the unnamed gyro's one axis
  const std::string when = generated(options);
  std::vector<ReportFile> files;
  std::vector<std::pair<std::string, std::string>> listed;
  Page page;
  page.title = fmt::format("Calibration report — run {} ({})", r.run.id, r.run.schedule_name);
  if (!sfx.empty()) page.title += " — " + dut_label(r.stream);
  const AnalysisSettings& s = r.settings;
  page.provenance = {
      {"Station", text::html_escape(r.station_name.empty() ? kDash : r.station_name)},
      {"Run", fmt::format("{} — schedule “{}”, {}", r.run.id,
                          text::html_escape(r.run.schedule_name), text::html_escape(r.run.state))},
      {"Started / ended (UTC)",
       fmt::format("{} / {}", text::html_escape(r.run.started_utc),
                   text::html_escape(r.run.ended_utc.empty() ? kDash : r.run.ended_utc))},
      {"Mounting", mounting_text(r, s)},
      {"Analysis",
       fmt::format("{:g} s bins, {}-point moving average, model {}, derivative window {:g} s, L0 "
                   "window {:g} s, Allan τ {}",
                   s.table1.bin_s, s.table1.ma_window,
                   text::html_escape(analysis::to_string(s.model)), s.fit.derivative_window_s,
                   s.fit.l0_window_s, analysis::to_string(s.allan_taus))},
      {"Source",
       fmt::format("Table I {}; Allan deviation {}",
                   r.table1_stored ? "as stored by the daemon" : "computed for this report",
                   r.allan_stored ? "as stored by the daemon" : "computed for this report")},
      {"Generated",
       text::html_escape(when) + (options.export_label.empty()
                                      ? std::string()
                                      : " — " + text::html_escape(options.export_label))},
  };
  if (!options.database_path.empty()) {
    page.provenance.emplace_back("Database", text::html_escape(options.database_path));
  }
  add_metadata_provenance(page, r);
  const auto name = [&sfx](std::string_view stem, std::string_view ext) {
    return fmt::format("{}{}.{}", stem, sfx, ext);
  };

  std::vector<const storage::SegmentStatsRecord*> rows;
  for (const auto& row : r.table1) rows.push_back(&row);
  std::string table1 = table1_html(rows, false);
  for (const auto& [index, stop] : r.acquire_stops) {
    table1 += fmt::format("<p class=\"note\">Adaptive soak, step {}: {}</p>\n", step_name(index),
                          text::html_escape(stop));
  }
  add_section(page, "table1", "Table I — zero bias at each set point", table1);
  files.push_back({dir + name("table1", "csv"), table1_csv(r.table1)});
  listed.emplace_back(name("table1", "csv"), "Table I rows");
  // A schedule that repeats set points: the paper's grouped form too.
  if (auto groups = analysis::table1_by_setpoint(table1_soaks(rows))) {
    if (has_repetitions(*groups)) {
      add_section(page, "table1-by-setpoint", "Table I — by set point",
                  table1_groups_html(*groups));
      files.push_back({dir + name("table1-by-setpoint", "csv"), table1_groups_csv(*groups)});
      listed.emplace_back(name("table1-by-setpoint", "csv"), "Table I by set point");
    }
  } else {
    add_section(
        page, "table1-by-setpoint", "Table I — by set point",
        fmt::format("<p class=\"problem\">{}</p>\n", text::html_escape(groups.error().message)));
  }

  std::string fits;
  for (const auto& rf : r.fits) {
    const std::string stem = fmt::format("drift-fit-{}{}", analysis::to_string(rf.fit.form), sfx);
    fits += fit_html(rf, stem, !rf.quality.flagged() || options.force_flagged);
    auto info = export_info(r.station_name, rf, when);
    add_stream_info(info, r);
    files.push_back({dir + stem + ".json", analysis::drift_fit_json(rf.fit, info)});
    listed.emplace_back(stem + ".json", "coefficients (JSON)");
    // A flagged fit's header only with --force (the run's problems say so).
    if (rf.quality.flagged() && !options.force_flagged) continue;
    // Names (and guard) per form, DUT and axis: the gyro's build can include
    // every header.
    files.push_back({dir + stem + ".h",
                     forced_header_comment(rf.quality) +
                         analysis::drift_fit_c_header(
                             rf.fit, info,
                             fmt::format("gyrotherm_drift_{}{}", analysis::to_string(rf.fit.form),
                                         c_identifier_part(sfx)))});
    listed.emplace_back(stem + ".h", "coefficients (C99 header)");
  }
  if (fits.empty()) fits = "<p class=\"problem\">No fit of the drift model.</p>\n";
  add_section(page, "fit", "Drift model (eq. 1)", fits);

  if (r.comparison) {
    add_section(page, "comparison", "Tables II–IV — compensation by model and order",
                comparison_html(*r.comparison));
    files.push_back({dir + name("comparison", "csv"), comparison_csv(*r.comparison)});
    listed.emplace_back(name("comparison", "csv"), "Tables II–IV grid");
  } else {
    add_section(page, "comparison", "Tables II–IV — compensation by model and order",
                fmt::format("<p class=\"problem\">Not computed: {}</p>\n",
                            text::html_escape(r.comparison_error)));
  }

  add_section(page, "figures", "Figures", figures_html(r.plots, false));

  std::vector<const storage::AllanRecord*> allan;
  for (const auto& a : r.allan) allan.push_back(&a);
  std::string allan_body = allan_html(allan, false);
  if (const auto* p = find_plot(r.plots, "chart-allan")) {
    allan_body += chart(*p, "Allan deviation of each soak, log-log, with its 1σ bounds.");
  }
  add_section(page, "allan", "Allan deviation", allan_body);
  files.push_back({dir + name("allan", "csv"), allan_csv(r.allan)});
  files.push_back({dir + name("allan-curves", "csv"), allan_curves_csv(allan)});
  listed.emplace_back(name("allan", "csv"), "Allan noise terms per soak");
  listed.emplace_back(name("allan-curves", "csv"), "Allan deviation curves with bounds");

  if (r.scale_factor) {
    const ReportScaleFactor& sf = *r.scale_factor;
    add_section(
        page, "scale-factor", "Scale factor",
        sf_section_html(sf, r.plots, sfx,
                        !scale_factor_header_quality(sf).flagged() || options.force_flagged));
    files.push_back({dir + name("scale-factor", "csv"), scale_factor_csv({&sf})});
    files.push_back({dir + name("scale-factor-points", "csv"), scale_factor_points_csv(sf)});
    listed.emplace_back(name("scale-factor", "csv"), "scale factor of each sequence");
    listed.emplace_back(name("scale-factor-points", "csv"), "rate points with their residuals");
    if (!sf.fits.empty()) {
      analysis::ExportInfo info;
      info.station = r.station_name;
      info.run_ids = {r.run.id};
      info.computed_utc = when;
      add_stream_info(info, r);
      files.push_back({dir + name("scale-factor", "json"), scale_factor_json(sf, info)});
      listed.emplace_back(name("scale-factor", "json"), "scale factor over temperature (JSON)");
      const storage::ResultQuality quality = scale_factor_header_quality(sf);
      if (!quality.flagged() || options.force_flagged) {
        files.push_back(
            {dir + name("scale-factor", "h"),
             forced_header_comment(quality) +
                 scale_factor_c_header(sf, info, "gyrotherm_sf" + c_identifier_part(sfx))});
        listed.emplace_back(name("scale-factor", "h"),
                            "scale factor over temperature (C99 header)");
      }
    }
  }

  if (!r.problems.empty()) add_section(page, "problems", "Problems", problems_html(r.problems));
  add_section(page, "files", "Files", files_html(listed));
  page.plots = r.plots;
  files.push_back({dir + name("report", "html"), render_page(page, when)});
  return files;
}

std::vector<ReportFile> render_campaign_files(const CampaignReport& c,
                                              const ReportOptions& options) {
  const std::string when = generated(options);
  const std::string& sfx = c.file_suffix;
  const auto name = [&sfx](std::string_view stem, std::string_view ext) {
    return fmt::format("{}{}.{}", stem, sfx, ext);
  };
  std::vector<ReportFile> files;
  std::vector<std::pair<std::string, std::string>> listed;
  Page page;
  page.title =
      fmt::format("Calibration summary — {} run{}", c.runs.size(), c.runs.size() == 1 ? "" : "s");
  AnalysedAxis group;
  group.dut_serial = c.dut_serial;
  group.dut_model = c.dut_model;
  group.axis = c.axis;
  if (!sfx.empty()) page.title += " — " + dut_label(group);
  page.provenance = {
      {"Station", text::html_escape(c.station_name.empty() ? kDash : c.station_name)},
      {"Export",
       text::html_escape(options.export_label.empty() ? "on demand" : options.export_label)},
      {"Generated", text::html_escape(when)},
  };
  if (!options.database_path.empty()) {
    page.provenance.emplace_back("Database", text::html_escape(options.database_path));
  }
  page.provenance.insert(page.provenance.begin() + 1, {"DUT", text::html_escape(dut_label(group))});

  std::string runs =
      "<table class=\"numbers\">\n<thead><tr><th>run</th><th>schedule</th><th>started "
      "(UTC)</th><th>ended (UTC)</th><th>operator</th><th>tags</th><th>start temperature "
      "(°C)</th><th>soaks</th><th>report</th></tr></thead>\n<tbody>\n";
  for (std::size_t i = 0; i < c.runs.size(); ++i) {
    const auto& r = c.runs[i];
    std::optional<double> t0;
    if (r.series) {
      if (auto t = analysis::start_temperature_c(*r.series)) t0 = *t;
    }
    const std::string link = fmt::format("run-{:04}/report{}.html", r.run.id, r.file_suffix);
    runs += fmt::format(
        "<tr{}><td class=\"num\">{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td>"
        "{}<td class=\"num\">{}</td><td><a href=\"{}\">{}</a></td></tr>\n",
        r.problems.empty() ? "" : " class=\"warn\"", r.run.id,
        text::html_escape(r.run.schedule_name), text::html_escape(r.run.started_utc),
        text::html_escape(r.run.ended_utc),
        text::html_escape(r.run.metadata.operator_name.empty() ? kDash
                                                               : r.run.metadata.operator_name),
        text::html_escape(tags_text(r.run.metadata.tags)), num_cell(t0, 2), r.table1.size(),
        text::html_escape(link), text::html_escape(link));
  }
  runs += "</tbody></table>\n";
  add_section(page, "runs", "Runs", runs);

  std::vector<const storage::SegmentStatsRecord*> rows;
  std::vector<storage::SegmentStatsRecord> all_rows;
  std::vector<const storage::AllanRecord*> allan;
  std::vector<storage::AllanRecord> all_allan;
  for (const auto& r : c.runs) {
    for (const auto& row : r.table1) {
      rows.push_back(&row);
      all_rows.push_back(row);
    }
    for (const auto& a : r.allan) {
      allan.push_back(&a);
      all_allan.push_back(a);
    }
  }
  add_section(page, "table1", "Table I — every run", table1_html(rows, true));
  files.push_back({name("table1", "csv"), table1_csv(all_rows)});
  listed.emplace_back(name("table1", "csv"), "Table I rows of every run");
  if (!rows.empty()) {
    auto groups = analysis::table1_by_setpoint(table1_soaks(rows));
    add_section(page, "table1-by-setpoint", "Table I — by set point, all runs",
                groups ? table1_groups_html(*groups)
                       : fmt::format("<p class=\"problem\">{}</p>\n",
                                     text::html_escape(groups.error().message)));
    if (groups) {
      files.push_back({name("table1-by-setpoint", "csv"), table1_groups_csv(*groups)});
      listed.emplace_back(name("table1-by-setpoint", "csv"), "Table I by set point, all runs");
    }
  }

  if (c.comparison) {
    add_section(page, "comparison", "Tables II–IV — all runs", comparison_html(*c.comparison));
    files.push_back({name("comparison", "csv"), comparison_csv(*c.comparison)});
    listed.emplace_back(name("comparison", "csv"),
                        "Tables II–IV grid, in-sample and leave-one-run-out");
  } else {
    add_section(page, "comparison", "Tables II–IV — all runs",
                fmt::format("<p class=\"problem\">Not computed: {}</p>\n",
                            text::html_escape(c.comparison_error)));
  }

  if (c.joint_fit) {
    auto info = export_info(c.station_name, *c.joint_fit, when);
    add_campaign_info(info, c);
    const std::string stem = "drift-fit" + sfx;
    add_section(
        page, "fit", "Drift model fitted on all runs",
        fit_html(*c.joint_fit, stem, !c.joint_fit->quality.flagged() || options.force_flagged));
    files.push_back({stem + ".json", analysis::drift_fit_json(c.joint_fit->fit, info)});
    listed.emplace_back(stem + ".json", "joint fit coefficients (JSON)");
    if (!c.joint_fit->quality.flagged() || options.force_flagged) {
      files.push_back({stem + ".h", forced_header_comment(c.joint_fit->quality) +
                                        analysis::drift_fit_c_header(
                                            c.joint_fit->fit, info,
                                            "gyrotherm_drift" + c_identifier_part(sfx))});
      listed.emplace_back(stem + ".h", "joint fit coefficients (C99 header)");
    }
  } else {
    add_section(page, "fit", "Drift model fitted on all runs",
                fmt::format("<p class=\"note\">No joint fit: {}.</p>\n",
                            text::html_escape(c.joint_fit_error)));
  }

  if (c.start_model) {
    const auto& m = *c.start_model;
    std::string h = fmt::format(
        "<p class=\"note\">Each coefficient of {} ({} form) as a cubic in the start "
        "temperature T0 (eq. 3), from {} runs with T0 = ",
        text::html_escape(analysis::to_string(m.spec)), analysis::to_string(m.form), m.t0_c.size());
    std::vector<std::string> t0s;
    for (double t : m.t0_c) t0s.push_back(fmt::format("{:.2f}", t));
    h += fmt::format("{} °C.</p>\n", fmt::join(t0s, ", "));
    h += "<table class=\"numbers\">\n<thead><tr><th>coefficient</th><th>A0</th><th>A1 (per "
         "°C)</th><th>A2 (per °C²)</th><th>A3 (per °C³)</th><th>residual std</th></tr></thead>\n"
         "<tbody>\n";
    for (const auto& name : analysis::coefficient_names(m.spec, m.form)) {
      const auto it = m.cubic.find(name);
      if (it == m.cubic.end()) continue;
      h += fmt::format("<tr><td>{}</td>", text::html_escape(name));
      for (double a : it->second) h += sci_cell(a);
      const auto rs = m.cubic_residual_std.find(name);
      h += sci_cell(rs == m.cubic_residual_std.end() ? std::nan("") : rs->second) + "</tr>\n";
    }
    h += fmt::format(
        "</tbody></table>\n<p class=\"note\"><a href=\"start-model{0}.json\">start-model{0}.json"
        "</a>, <a href=\"start-model{0}.h\">start-model{0}.h</a> (C99).</p>\n",
        text::html_escape(sfx));
    add_section(page, "start-model", "Start-temperature model (eq. 3)", h);
    analysis::ExportInfo info;
    info.station = c.station_name;
    for (const auto& r : c.runs) info.run_ids.push_back(r.run.id);
    info.computed_utc = when;
    info.l0_window_s = m.l0_window_s;
    add_campaign_info(info, c);
    files.push_back({name("start-model", "json"), analysis::start_model_json(m, info)});
    files.push_back(
        {name("start-model", "h"),
         analysis::start_model_c_header(m, info, "gyrotherm_start" + c_identifier_part(sfx))});
    listed.emplace_back(name("start-model", "json"), "start-temperature model (JSON)");
    listed.emplace_back(name("start-model", "h"), "start-temperature model (C99 header)");
  } else {
    add_section(page, "start-model", "Start-temperature model (eq. 3)",
                fmt::format("<p class=\"note\">Not fitted: {}.</p>\n",
                            text::html_escape(c.start_model_note)));
  }

  add_section(page, "figures", "Figures", figures_html(c.plots, true));
  std::string allan_body = allan_html(allan, true);
  if (const auto* p = find_plot(c.plots, "chart-allan")) {
    allan_body += chart(*p, "Allan deviation of every soak, log-log, with 1σ bounds.");
  }
  add_section(page, "allan", "Allan deviation", allan_body);
  files.push_back({name("allan", "csv"), allan_csv(all_allan)});
  listed.emplace_back(name("allan", "csv"), "Allan noise terms of every soak");

  std::vector<const ReportScaleFactor*> sf_runs;
  for (const auto& r : c.runs) {
    if (r.scale_factor) sf_runs.push_back(&*r.scale_factor);
  }
  if (!sf_runs.empty()) {
    add_section(page, "scale-factor", "Scale factor — every run", sf_campaign_html(c));
    files.push_back({name("scale-factor", "csv"), scale_factor_csv(sf_runs)});
    listed.emplace_back(name("scale-factor", "csv"), "scale factor of each sequence of every run");
  }

  if (!c.problems.empty()) add_section(page, "problems", "Problems", problems_html(c.problems));
  for (const auto& r : c.runs) {
    listed.emplace_back(fmt::format("run-{:04}/report{}.html", r.run.id, r.file_suffix),
                        fmt::format("report of run {}", r.run.id));
  }
  add_section(page, "files", "Files", files_html(listed));
  page.plots = c.plots;
  files.push_back(
      {sfx.empty() ? std::string("index.html") : name("summary", "html"), render_page(page, when)});
  return files;
}

ReportFile render_run_index(const std::vector<RunReport>& reports, const ReportOptions& options) {
  const std::string when = generated(options);
  Page page;
  if (reports.empty()) return {"", ""};
  const storage::RunRecord& run = reports.front().run;
  const storage::RunMetadata& m = run.metadata;
  page.title = fmt::format("Calibration report — run {} ({})", run.id, run.schedule_name);
  page.provenance = {
      {"Station", text::html_escape(
                      reports.front().station_name.empty() ? kDash : reports.front().station_name)},
      {"Run", fmt::format("{} — schedule “{}”, {}", run.id, text::html_escape(run.schedule_name),
                          text::html_escape(run.state))},
      {"Operator", text::html_escape(m.operator_name.empty() ? kDash : m.operator_name)},
      {"Comment", text::html_escape(m.comment.empty() ? kDash : m.comment)},
      {"Tags", text::html_escape(tags_text(m.tags))},
      {"Started / ended (UTC)",
       fmt::format("{} / {}", text::html_escape(run.started_utc),
                   text::html_escape(run.ended_utc.empty() ? kDash : run.ended_utc))},
      {"Generated",
       text::html_escape(when) + (options.export_label.empty()
                                      ? std::string()
                                      : " — " + text::html_escape(options.export_label))},
  };
  std::string h =
      "<table class=\"numbers\" id=\"duts\">\n<thead><tr><th>DUT</th><th>model</th><th>axis</th>"
      "<th>orientation</th><th>Table I rows</th><th>Allan</th><th>fits</th><th>scale-factor "
      "sequences</th><th>report</th></tr></thead>\n<tbody>\n";
  for (const auto& r : reports) {
    const std::string link = fmt::format("report{}.html", r.file_suffix);
    h += fmt::format(
        "<tr{}><td>{}</td><td>{}</td><td>{}{}</td><td>{}</td><td class=\"num\">{}</td><td "
        "class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td><a "
        "href=\"{}\">{}</a></td></tr>\n",
        r.problems.empty() ? "" : " class=\"warn\"",
        text::html_escape(r.stream.dut_serial.empty() ? "(no serial)" : r.stream.dut_serial),
        text::html_escape(r.stream.dut_model.empty() ? kDash : r.stream.dut_model),
        text::html_escape(r.stream.axis), r.stream.primary ? " (primary)" : "",
        r.stream.orientation ? analysis::to_string(*r.stream.orientation)
                             : std::string_view(run.orientation),
        r.table1.size(), r.allan.size(), r.fits.size(),
        r.scale_factor ? r.scale_factor->fits.size() : 0, text::html_escape(link),
        text::html_escape(link));
  }
  h += "</tbody></table>\n";
  add_section(page, "duts", "Devices under test", h);
  return {fmt::format("run-{:04}/report.html", run.id), render_page(page, when)};
}

ReportFile render_summary_index(const std::vector<CampaignReport>& groups,
                                const ReportOptions& options) {
  const std::string when = generated(options);
  Page page;
  std::set<int64_t> run_ids;
  for (const auto& g : groups) {
    for (const auto& r : g.runs) run_ids.insert(r.run.id);
  }
  page.title =
      fmt::format("Calibration summary — {} run{}, {} DUT ax{}", run_ids.size(),
                  run_ids.size() == 1 ? "" : "s", groups.size(), groups.size() == 1 ? "is" : "es");
  page.provenance = {
      {"Station", text::html_escape(groups.empty() || groups.front().station_name.empty()
                                        ? kDash
                                        : groups.front().station_name)},
      {"Export",
       text::html_escape(options.export_label.empty() ? "on demand" : options.export_label)},
      {"Generated", text::html_escape(when)},
  };
  if (!options.database_path.empty()) {
    page.provenance.emplace_back("Database", text::html_escape(options.database_path));
  }
  // The runs, once each, with their metadata and DUT axes.
  std::map<int64_t, std::pair<const RunReport*, std::vector<const RunReport*>>> runs;
  for (const auto& g : groups) {
    for (const auto& r : g.runs) {
      auto& e = runs[r.run.id];
      if (e.first == nullptr) e.first = &r;
      e.second.push_back(&r);
    }
  }
  std::string h =
      "<table class=\"numbers\" id=\"runs\">\n<thead><tr><th>run</th><th>schedule</th><th>started "
      "(UTC)</th><th>operator</th><th>comment</th><th>tags</th><th>reports</th></tr></thead>\n"
      "<tbody>\n";
  for (const auto& [id, e] : runs) {
    const storage::RunRecord& run = e.first->run;
    std::string links;
    for (const auto* r : e.second) {
      const std::string link = fmt::format("run-{:04}/report{}.html", id, r->file_suffix);
      links += fmt::format("{}<a href=\"{}\">{}</a>", links.empty() ? "" : ", ",
                           text::html_escape(link), text::html_escape(dut_label(r->stream)));
    }
    h += fmt::format(
        "<tr><td class=\"num\">{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td>"
        "<td>{}</td></tr>\n",
        id, text::html_escape(run.schedule_name), text::html_escape(run.started_utc),
        text::html_escape(run.metadata.operator_name.empty() ? kDash : run.metadata.operator_name),
        text::html_escape(run.metadata.comment.empty() ? kDash : run.metadata.comment),
        text::html_escape(tags_text(run.metadata.tags)), links);
  }
  h += "</tbody></table>\n";
  add_section(page, "runs", "Runs", h);
  std::string d =
      "<table class=\"numbers\" id=\"dut-axes\">\n<thead><tr><th>DUT</th><th>runs</th><th>Table "
      "I rows</th><th>joint fit</th><th>summary</th></tr></thead>\n<tbody>\n";
  std::vector<std::string> problems;
  for (const auto& g : groups) {
    AnalysedAxis a;
    a.dut_serial = g.dut_serial;
    a.dut_model = g.dut_model;
    a.axis = g.axis;
    std::size_t rows = 0;
    for (const auto& r : g.runs) rows += r.table1.size();
    const std::string link = fmt::format("summary{}.html", g.file_suffix);
    d += fmt::format(
        "<tr{}><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td>{}</td><td><a "
        "href=\"{}\">{}</a></td></tr>\n",
        g.problems.empty() ? "" : " class=\"warn\"", text::html_escape(dut_label(a)), g.runs.size(),
        rows,
        g.joint_fit ? fmt::format("{} (residual std {:.4f} °/h)",
                                  text::html_escape(analysis::to_string(g.joint_fit->fit.spec)),
                                  g.joint_fit->fit.residual_std_dph)
                    : text::html_escape(g.joint_fit_error),
        text::html_escape(link), text::html_escape(link));
    for (const auto& p : g.problems) problems.push_back(dut_label(a) + ": " + p);
  }
  d += "</tbody></table>\n";
  add_section(page, "duts", "Devices under test", d);
  if (!problems.empty()) add_section(page, "problems", "Problems", problems_html(problems));
  return {"index.html", render_page(page, when)};
}

std::vector<ReportFile> render_export_files(const std::vector<std::vector<RunReport>>& runs,
                                            const ReportOptions& options,
                                            std::vector<std::string>& problems) {
  std::vector<ReportFile> files;
  std::vector<RunReport> all;
  for (const auto& streams : runs) {
    for (const auto& r : streams) {
      auto run_files = render_run_files(r, options);
      files.insert(files.end(), std::make_move_iterator(run_files.begin()),
                   std::make_move_iterator(run_files.end()));
    }
    if (streams.size() > 1 || (streams.size() == 1 && !streams.front().file_suffix.empty())) {
      files.push_back(render_run_index(streams, options));
    }
    for (const auto& r : streams) {
      RunReport copy = r;
      copy.plots.clear();  // rendered; the campaign draws its own
      all.push_back(std::move(copy));
    }
  }
  const std::vector<CampaignReport> groups = collect_campaign_reports(std::move(all), options);
  for (const auto& c : groups) {
    auto campaign_files = render_campaign_files(c, options);
    files.insert(files.end(), std::make_move_iterator(campaign_files.begin()),
                 std::make_move_iterator(campaign_files.end()));
    for (const auto& p : c.problems) {
      problems.push_back(c.file_suffix.empty() ? p
                                               : fmt::format("{}: {}", c.file_suffix.substr(1), p));
    }
  }
  if (groups.size() > 1 || (groups.size() == 1 && !groups.front().file_suffix.empty())) {
    files.push_back(render_summary_index(groups, options));
  }
  return files;
}

}  // namespace gyrotherm::calibration
