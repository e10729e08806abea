// The lab summary page (central.h, lab_summary_html): the nightly report's
// campaign summary across stations and DUTs, read from the lab views in one
// snapshot. One self-contained HTML page: inline style, inline SVG drawn
// here, no script and no request beyond the page. Every text that comes
// from the database is escaped (a comment may hold "<script>").
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <nlohmann/json.hpp>
#include <set>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/core/text.h"
#include "gyrotherm/lab/central.h"
#include "read_util.h"

namespace gyrotherm::lab {

namespace {

using internal::json_rows;
using internal::Params;
using internal::str;
using nlohmann::json;

constexpr const char* kDash = "—";

// ------------------------------------------------------------ row access

const json& member(const json& row, const char* key) {
  static const json kNull;
  if (!row.is_object()) return kNull;
  const auto it = row.find(key);
  return it == row.end() ? kNull : *it;
}

std::optional<double> number(const json& v) {
  if (!v.is_number()) return std::nullopt;
  const double d = v.get<double>();
  return std::isfinite(d) ? std::optional<double>(d) : std::nullopt;
}

// "2026-11-21T05:38:43.120Z" → "2026-11-21 05:38:43"; "—" for none.
std::string utc(std::string_view s) {
  if (s.size() >= 19 && s[10] == 'T')
    return std::string(s.substr(0, 10)) + " " + std::string(s.substr(11, 8));
  return s.empty() ? kDash : std::string(s);
}

// A text cell, escaped; "—" when empty.
std::string cell(std::string_view text) {
  return text.empty() ? fmt::format("<td class=\"missing\">{}</td>", kDash)
                      : fmt::format("<td>{}</td>", text::html_escape(text));
}

// A UTC time cell ("2026-11-21 05:38:43"), kept on one line.
std::string time_cell(std::string_view iso) {
  return iso.empty() ? cell(iso)
                     : fmt::format("<td class=\"time\">{}</td>", text::html_escape(utc(iso)));
}

// A number cell with `decimals` (negative: 6 significant digits); "—"
// when missing or not finite.
std::string num(const json& v, int decimals, double factor = 1) {
  const auto d = number(v);
  if (!d) return fmt::format("<td class=\"num missing\">{}</td>", kDash);
  const double x = *d * factor;
  return decimals < 0 ? fmt::format("<td class=\"num\">{:.6g}</td>", x)
                      : fmt::format("<td class=\"num\">{:.{}f}</td>", x, decimals);
}

std::string header(std::initializer_list<const char*> names) {
  std::string h = "<thead><tr>";
  for (const char* n : names) h += fmt::format("<th>{}</th>", text::html_escape(n));
  return h + "</tr></thead>\n";
}

// "a, b, c" of a JSON array or a vector of strings.
std::string joined(const std::vector<std::string>& items) {
  std::string out;
  for (const auto& i : items) out += (out.empty() ? "" : ", ") + i;
  return out;
}

// The run a row belongs to, as people name it: "station-3/12".
std::string run_ref(const json& row) {
  const json& id = member(row, "run_local_id");
  return fmt::format("{}/{}", str(row, "station_id"), id.is_number() ? id.dump() : "?");
}

// A coefficient set {"T1": v, ...} with its standard errors, as
// "T1 = v ± se" lines.
std::string coefficients(const json& values, const json& errors) {
  if (!values.is_object() || values.empty()) return kDash;
  std::string out;
  for (const auto& [name, v] : values.items()) {
    if (!out.empty()) out += "<br>";
    const auto d = number(v);
    out += text::html_escape(name) + " = " + (d ? fmt::format("{:.6g}", *d) : std::string(kDash));
    if (const auto se = number(member(errors, name.c_str()))) out += fmt::format(" ± {:.2g}", *se);
  }
  return out;
}

std::string number_list(const json& values) {
  if (!values.is_array() || values.empty()) return kDash;
  std::vector<std::string> items;
  for (const auto& v : values) {
    const auto d = number(v);
    items.push_back(d ? fmt::format("{:.6g}", *d) : std::string(kDash));
  }
  return "[" + joined(items) + "]";
}

// ------------------------------------------------------------ the plot

// Ticks at 1, 2 or 5 × 10^k spanning [lo, hi]; `decimals` for their labels.
std::vector<double> ticks(double lo, double hi, int& decimals) {
  const double raw = (hi - lo) / 5;
  const double magnitude = std::pow(10.0, std::floor(std::log10(raw)));
  const double norm = raw / magnitude;
  const double step = (norm < 1.5 ? 1 : norm < 3 ? 2 : norm < 7 ? 5 : 10) * magnitude;
  decimals = std::max(0, -static_cast<int>(std::floor(std::log10(step) + 1e-9)));
  std::vector<double> out;
  for (double v = std::ceil(lo / step) * step; v <= hi + step * 1e-6; v += step) {
    out.push_back(std::fabs(v) < step * 1e-6 ? 0.0 : v);
  }
  return out;
}

constexpr const char* kColours[] = {"#1f77b4", "#d62728", "#2ca02c", "#9467bd",
                                    "#ff7f0e", "#17becf", "#8c564b", "#e377c2"};

// Zero bias against set point, one series per run (Table I rows of one
// DUT axis). "" when there is nothing to draw.
std::string bias_plot(const std::vector<json>& rows, const std::string& title) {
  struct Series {
    std::string label;
    std::vector<std::pair<double, double>> points;
  };
  std::vector<Series> series;
  double x_lo = INFINITY, x_hi = -INFINITY, y_lo = INFINITY, y_hi = -INFINITY;
  for (const auto& r : rows) {
    const auto x = number(member(r, "setpoint_c"));
    const auto y = number(member(r, "bias_mean_dph"));
    if (!x || !y) continue;
    const std::string label = run_ref(r);
    auto it = std::find_if(series.begin(), series.end(),
                           [&](const Series& s) { return s.label == label; });
    if (it == series.end()) it = series.insert(series.end(), Series{label, {}});
    it->points.emplace_back(*x, *y);
    x_lo = std::min(x_lo, *x);
    x_hi = std::max(x_hi, *x);
    y_lo = std::min(y_lo, *y);
    y_hi = std::max(y_hi, *y);
  }
  if (series.empty()) return "";
  if (x_hi - x_lo < 1e-9) {
    x_lo -= 1;
    x_hi += 1;
  }
  if (y_hi - y_lo < 1e-9) {
    const double pad = std::max(1e-3, std::fabs(y_hi) * 0.1);
    y_lo -= pad;
    y_hi += pad;
  }
  const double y_pad = (y_hi - y_lo) * 0.08;
  y_lo -= y_pad;
  y_hi += y_pad;
  constexpr double kW = 560, kH = 260, kLeft = 70, kRight = 14, kTop = 10, kBottom = 42;
  const auto px = [&](double x) {
    return kLeft + (x - x_lo) / (x_hi - x_lo) * (kW - kLeft - kRight);
  };
  const auto py = [&](double y) {
    return kTop + (y_hi - y) / (y_hi - y_lo) * (kH - kTop - kBottom);
  };

  std::string svg = fmt::format(
      "<figure><svg viewBox=\"0 0 {} {}\" width=\"{}\" "
      "height=\"{}\" role=\"img\"><title>{}</title>\n",
      kW, kH, kW, kH, text::html_escape(title));
  svg += fmt::format(
      "<rect x=\"{:.1f}\" y=\"{:.1f}\" width=\"{:.1f}\" height=\"{:.1f}\" class=\"frame\"/>\n",
      kLeft, kTop, kW - kLeft - kRight, kH - kTop - kBottom);
  int decimals = 0;
  for (const double t : ticks(x_lo, x_hi, decimals)) {
    svg += fmt::format(
        "<line x1=\"{0:.1f}\" x2=\"{0:.1f}\" y1=\"{1:.1f}\" y2=\"{2:.1f}\" class=\"grid\"/>"
        "<text x=\"{0:.1f}\" y=\"{3:.1f}\" text-anchor=\"middle\">{4:.{5}f}</text>\n",
        px(t), kTop, kH - kBottom, kH - kBottom + 14, t, decimals);
  }
  for (const double t : ticks(y_lo, y_hi, decimals)) {
    svg += fmt::format(
        "<line x1=\"{0:.1f}\" x2=\"{1:.1f}\" y1=\"{2:.1f}\" y2=\"{2:.1f}\" class=\"grid\"/>"
        "<text x=\"{3:.1f}\" y=\"{4:.1f}\" text-anchor=\"end\">{5:.{6}f}</text>\n",
        kLeft, kW - kRight, py(t), kLeft - 4, py(t) + 4, t, decimals);
  }
  svg += fmt::format(
      "<text x=\"{:.1f}\" y=\"{:.1f}\" text-anchor=\"middle\">set point (°C)</text>\n"
      "<text transform=\"translate(14 {:.1f}) rotate(-90)\" text-anchor=\"middle\">zero bias "
      "(°/h)</text>\n",
      (kLeft + kW - kRight) / 2, kH - 6, (kTop + kH - kBottom) / 2);
  std::string legend = "<figcaption>";
  for (std::size_t i = 0; i < series.size(); ++i) {
    Series& s = series[i];
    const char* colour = kColours[i % std::size(kColours)];
    std::sort(s.points.begin(), s.points.end());
    std::string points;
    for (const auto& [x, y] : s.points) points += fmt::format("{:.1f},{:.1f} ", px(x), py(y));
    svg += fmt::format("<polyline points=\"{}\" fill=\"none\" stroke=\"{}\"/>\n", points, colour);
    for (const auto& [x, y] : s.points) {
      svg += fmt::format(
          "<circle cx=\"{:.1f}\" cy=\"{:.1f}\" r=\"3\" fill=\"{}\"><title>{}: {:.2f} °C, "
          "{:.4f} °/h</title></circle>\n",
          px(x), py(y), colour, text::html_escape(s.label), x, y);
    }
    legend += fmt::format(
        "<span class=\"key\"><span class=\"swatch\" style=\"background:{}\">"
        "</span>{}</span> ",
        colour, text::html_escape(s.label));
  }
  return svg + "</svg>" + legend + "</figcaption></figure>\n";
}

// ------------------------------------------------------------ the DUTs' results

// The rows of a result view with their run (its local id, start) and the
// DUT's axis spelt out ('' = the DUT's primary axis, from its run_duts
// row), for runs started since $1 (NULL: all). `extra`: more members.
std::string dut_rows_sql(std::string_view view, std::string_view extra, std::string_view order) {
  return fmt::format(R"sql(
SELECT to_jsonb(t) || jsonb_build_object(
         'run_local_id', r.local_run_id, 'run_started_utc', r.started_utc,
         'shown_axis', coalesce(nullif(t.axis, ''), nullif(d.primary_axis, ''), ''),
         'dut_model', coalesce(d.model, ''){})
FROM {} t
JOIN lab.runs r ON r.station_id = t.station_id AND r.run_uuid = t.run_uuid
LEFT JOIN lab.run_duts d
  ON d.station_id = t.station_id AND d.run_uuid = t.run_uuid AND d.dut_serial = t.dut_serial
WHERE ($1::text IS NULL OR r.started_utc >= $1)
ORDER BY t.dut_serial, {}
)sql",
                     extra, view, order);
}

struct AxisResults {
  std::vector<json> table1, allan, fits, sf, sft;
};
struct DutResults {
  std::string model;
  std::map<std::string, AxisResults> axes;  // by axis name ("" = primary, not known)
};

std::string table1_html(const std::vector<json>& rows) {
  std::string h = "<table>\n";
  h += header({"set point (°C)", "station/run", "started (UTC)", "step", "T mean (°C)", "points",
               "bias mean (°/h)", "± U95 (°/h)", "std (°/h)", "std after MA (°/h)", "MA (points)",
               "Earth rate removed (°/h)", "adaptive soak ended"});
  h += "<tbody>\n";
  for (const auto& r : rows) {
    const auto step = number(member(r, "segment_index"));
    h += "<tr>" + num(member(r, "setpoint_c"), 2) + cell(run_ref(r)) +
         time_cell(str(r, "run_started_utc")) +
         cell(step ? std::to_string(static_cast<int64_t>(*step) + 1) : "") +
         num(member(r, "temp_mean_c"), 2) + num(member(r, "n"), 0) +
         num(member(r, "bias_mean_dph"), 4) + num(member(r, "bias_u_expanded_dph"), 4) +
         num(member(r, "bias_std_dph"), 4) + num(member(r, "bias_std_ma_dph"), 4) +
         num(member(r, "ma_window"), 0) + num(member(r, "bias_mean_earth_removed_dph"), 4) +
         cell(str(r, "acquire_stop")) + "</tr>\n";
  }
  return h + "</tbody></table>\n";
}

// One row per fit: its runs gathered (a fit may span runs of its station).
std::string fits_html(const std::vector<json>& rows) {
  std::vector<json> fits;
  std::vector<std::vector<std::string>> runs;
  for (const auto& r : rows) {
    const std::string key = str(r, "station_id") + "\n" + member(r, "fit_local_id").dump();
    auto it = std::find_if(fits.begin(), fits.end(), [&](const json& f) {
      return str(f, "station_id") + "\n" + member(f, "fit_local_id").dump() == key;
    });
    if (it == fits.end()) {
      fits.push_back(r);
      runs.emplace_back();
      it = fits.end() - 1;
    }
    runs[static_cast<std::size_t>(it - fits.begin())].push_back(run_ref(r));
  }
  std::string h = "<table>\n";
  h += header({"station/runs", "model", "form", "points", "coefficients ± standard error",
               "residual std (°/h)", "R²", "computed (UTC)"});
  h += "<tbody>\n";
  for (std::size_t i = 0; i < fits.size(); ++i) {
    const json& f = fits[i];
    h += "<tr>" + cell(joined(runs[i])) + cell(str(f, "model")) + cell(str(f, "form")) +
         num(member(f, "n"), 0) + "<td class=\"coefficients\">" +
         coefficients(member(f, "coefficients"), member(f, "standard_errors")) + "</td>" +
         num(member(f, "residual_std_dph"), 4) + num(member(f, "r_squared"), 4) +
         time_cell(str(f, "computed_utc")) + "</tr>\n";
  }
  return h + "</tbody></table>\n";
}

std::string allan_html(const std::vector<json>& rows) {
  std::string h = "<table>\n";
  h += header({"station/run", "step", "set point (°C)", "taus", "samples", "ARW (°/√h)",
               "bias instability (°/h)", "at τ (s)", "RRW (°/h/√h)"});
  h += "<tbody>\n";
  for (const auto& r : rows) {
    const auto step = number(member(r, "segment_index"));
    h += "<tr>" + cell(run_ref(r)) +
         cell(step ? std::to_string(static_cast<int64_t>(*step) + 1) : "") +
         num(member(r, "segment_setpoint_c"), 2) + cell(str(r, "taus")) +
         num(member(r, "n_samples"), 0) + num(member(r, "angle_random_walk_dprh"), -1) +
         num(member(r, "bias_instability_dph"), -1) + num(member(r, "bias_instability_tau_s"), 1) +
         num(member(r, "rate_random_walk_dphprh"), -1) + "</tr>\n";
  }
  return h + "</tbody></table>\n";
}

std::string scale_factor_html(const std::vector<json>& rows) {
  std::string h = "<table>\n";
  h += header({"station/run", "sequence", "T (°C)", "K", "K std error", "bias (°/h)",
               "nonlinearity (ppm)", "asymmetry (ppm)", "repeatability (ppm)", "points"});
  h += "<tbody>\n";
  for (const auto& r : rows) {
    h += "<tr>" + cell(run_ref(r)) + num(member(r, "sf_sequence"), 0) +
         num(member(r, "temperature_c"), 2) + num(member(r, "k"), 7) + num(member(r, "k_se"), -1) +
         num(member(r, "bias_dps"), 3, 3600.0) + num(member(r, "nonlinearity_ppm"), 1) +
         num(member(r, "asymmetry_ppm"), 1) + num(member(r, "repeatability_ppm"), 1) +
         num(member(r, "n_points"), 0) + "</tr>\n";
  }
  return h + "</tbody></table>\n";
}

std::string sf_temperature_html(const std::vector<json>& rows) {
  std::string h = "<table>\n";
  h += header({"station/run", "order", "centre (°C)", "K slope (ppm/°C)", "bias slope (°/h/°C)",
               "K(T) coefficients", "bias(T) coefficients (°/s)"});
  h += "<tbody>\n";
  for (const auto& r : rows) {
    h += "<tr>" + cell(run_ref(r)) + num(member(r, "poly_order"), 0) +
         num(member(r, "t_centre_c"), 2) + num(member(r, "k_ppm_per_c"), 3) +
         num(member(r, "bias_dph_per_c"), 4) + cell(number_list(member(r, "k_coeffs"))) +
         cell(number_list(member(r, "bias_coeffs"))) + "</tr>\n";
  }
  return h + "</tbody></table>\n";
}

constexpr const char* kStyle = R"css(
body { font-family: system-ui, sans-serif; margin: 1.5em; color: #222; }
h1 { font-size: 1.5em; } h2 { margin-top: 1.6em; border-bottom: 1px solid #ccc; }
h3 { margin-top: 1.4em; } h4 { margin: 1em 0 0.3em; }
table { border-collapse: collapse; margin: 0.3em 0 1em; font-size: 0.9em; }
th, td { border: 1px solid #ddd; padding: 0.2em 0.5em; vertical-align: top; }
th { background: #f3f3f3; text-align: left; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
td.missing { color: #999; }
td.time, td.uuid { white-space: nowrap; } td.uuid { font-family: monospace; font-size: 0.9em; }
td.coefficients { font-family: monospace; white-space: nowrap; }
dl.provenance { display: grid; grid-template-columns: max-content auto; gap: 0.2em 1em; }
dl.provenance dt { font-weight: bold; }
svg { font-size: 11px; } svg .frame { fill: none; stroke: #888; }
svg .grid { stroke: #e4e4e4; } figure { margin: 0.5em 0 1em; }
.key { margin-right: 1em; white-space: nowrap; }
.swatch { display: inline-block; width: 0.8em; height: 0.8em; margin-right: 0.3em; }
)css";

}  // namespace

Result<std::string> lab_summary_html(PgConnection& pg, const LabSummaryOptions& options) {
  auto since = internal::normalize_since(options.since_utc);
  if (!since) return since.error();
  auto snapshot = internal::ReadSnapshot::begin(pg);
  if (!snapshot) return snapshot.error();

  auto stations = internal::read_stations(pg);
  if (!stations) return stations.error();
  LabRunFilter filter;
  filter.since_utc = *since;
  filter.limit = 0;  // every run
  auto runs = internal::read_runs(pg, filter);
  if (!runs) return runs.error();
  auto version = pg.exec("SELECT coalesce(max(version), 0) FROM lab.schema_migrations");
  if (!version) return internal::read_error(pg, "lab.schema_migrations", version.error());
  const std::string schema_version =
      version->rows.empty() || !version->rows[0][0] ? "?" : *version->rows[0][0];

  const Params params = {since->empty() ? std::nullopt : std::optional<std::string>(*since)};
  const std::string run_order = "r.started_utc, t.station_id, r.local_run_id";
  struct Query {
    const char* view;
    std::string sql;
    std::vector<json> AxisResults::*slot;
  };
  const Query queries[] = {
      {"lab.table1",
       dut_rows_sql("lab.table1",
                    ", 'acquire_stop', (SELECT s.acquire_stop FROM lab.segments s "
                    "WHERE s.station_id = t.station_id AND s.run_uuid = t.run_uuid "
                    "AND s.idx = t.segment_index LIMIT 1)",
                    "t.setpoint_c, " + run_order + ", t.segment_index"),
       &AxisResults::table1},
      {"lab.allan",
       dut_rows_sql("lab.allan",
                    ", 'segment_setpoint_c', (SELECT s.setpoint_c FROM lab.segments s "
                    "WHERE s.station_id = t.station_id AND s.run_uuid = t.run_uuid "
                    "AND s.idx = t.segment_index LIMIT 1)",
                    run_order + ", t.segment_index, t.taus"),
       &AxisResults::allan},
      {"lab.fits",
       dut_rows_sql("lab.fits", "", "t.station_id, t.computed_utc, t.fit_local_id, " + run_order),
       &AxisResults::fits},
      {"lab.scale_factor_fits",
       dut_rows_sql("lab.scale_factor_fits", "", run_order + ", t.sf_sequence"), &AxisResults::sf},
      {"lab.scale_factor_temperature_fits",
       dut_rows_sql("lab.scale_factor_temperature_fits", "", run_order), &AxisResults::sft},
  };
  std::map<std::string, DutResults> duts;
  for (const Query& q : queries) {
    auto rows = json_rows(pg, q.view, q.sql, params);
    if (!rows) return rows.error();
    for (auto& r : *rows) {
      DutResults& dut = duts[str(r, "dut_serial")];
      if (!str(r, "dut_model").empty()) dut.model = str(r, "dut_model");
      (dut.axes[str(r, "shown_axis")].*q.slot).push_back(std::move(r));
    }
  }
  // DUTs recorded in the runs without results yet still get their heading.
  for (const auto& run : *runs) {
    for (const auto& serial : run.dut_serials) duts.try_emplace(serial);
  }

  const std::string generated =
      options.generated_utc.empty() ? wall_time_utc_iso() : options.generated_utc;
  const std::string server = options.server.empty() ? pg.server() : options.server;

  std::string h;
  h += "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n";
  h += "<title>Lab summary</title>\n<style>" + std::string(kStyle) + "</style>\n</head>\n<body>\n";
  h += "<h1>Lab summary</h1>\n<dl class=\"provenance\">\n";
  h += fmt::format("<dt>lab database</dt><dd>{} (lab schema version {})</dd>\n",
                   text::html_escape(server), text::html_escape(schema_version));
  h += fmt::format("<dt>generated</dt><dd>{} UTC</dd>\n", text::html_escape(utc(generated)));
  h += fmt::format("<dt>runs</dt><dd>{}</dd>\n",
                   since->empty()
                       ? std::string("every run relayed")
                       : fmt::format("started since {} UTC", text::html_escape(utc(*since))));
  h += fmt::format("<dt>contents</dt><dd>{} station{}, {} run{}, {} DUT{}</dd>\n", stations->size(),
                   stations->size() == 1 ? "" : "s", runs->size(), runs->size() == 1 ? "" : "s",
                   duts.size(), duts.size() == 1 ? "" : "s");
  h += "</dl>\n";

  h += "<section id=\"stations\">\n<h2>Stations</h2>\n";
  if (stations->empty()) {
    h += "<p>No station is registered.</p>\n";
  } else {
    h += "<table>\n" +
         header({"station", "role", "description", "registered (UTC)", "last batch (UTC)",
                 "last outbox seq", "records relayed", "runs"}) +
         "<tbody>\n";
    for (const auto& s : *stations) {
      h += "<tr>" + cell(s.station_id) + cell(s.db_role) + cell(s.description) +
           time_cell(s.registered_utc) +
           (s.last_batch_utc ? time_cell(*s.last_batch_utc) : cell("never")) +
           num(json(s.last_seq), 0) + num(json(s.records), 0) + num(json(s.runs), 0) + "</tr>\n";
    }
    h += "</tbody></table>\n";
  }
  h += "</section>\n";

  h += "<section id=\"runs\">\n<h2>Runs</h2>\n";
  if (runs->empty()) {
    h += "<p>No run.</p>\n";
  } else {
    h += "<table>\n" +
         header({"station", "run", "uuid", "schedule", "state", "started (UTC)", "ended (UTC)",
                 "operator", "DUTs", "tags", "comment"}) +
         "<tbody>\n";
    for (const auto& r : *runs) {
      h += "<tr>" + cell(r.station_id) + num(json(r.local_run_id), 0) + "<td class=\"uuid\">" +
           text::html_escape(r.run_uuid) + "</td>" + cell(r.schedule_name) + cell(r.state) +
           time_cell(r.started_utc) + time_cell(r.ended_utc) + cell(r.operator_name) +
           cell(joined(r.dut_serials)) + cell(joined(r.tags)) + cell(r.comment) + "</tr>\n";
    }
    h += "</tbody></table>\n";
  }
  h += "</section>\n";

  h += "<section id=\"duts\">\n<h2>DUTs</h2>\n";
  if (duts.empty()) h += "<p>No DUT.</p>\n";
  std::size_t dut_number = 0;
  for (const auto& [serial, dut] : duts) {
    ++dut_number;
    const std::string name = serial.empty() ? std::string("(no serial)") : serial;
    h += fmt::format("<h3 id=\"dut-{}\">DUT {}{}</h3>\n", dut_number, text::html_escape(name),
                     dut.model.empty() ? std::string() : " — " + text::html_escape(dut.model));
    if (dut.axes.empty()) h += "<p>No results relayed yet.</p>\n";
    for (const auto& [axis, results] : dut.axes) {
      const std::string axis_name = axis.empty() ? std::string("primary axis") : "axis " + axis;
      h += fmt::format("<h4>{} {}</h4>\n", text::html_escape(name), text::html_escape(axis_name));
      if (!results.table1.empty()) {
        h += "<p>Table I across runs and stations, by set point.</p>\n";
        h += table1_html(results.table1);
        h += bias_plot(results.table1, fmt::format("{} {}: zero bias against set point, one "
                                                   "series per run",
                                                   name, axis_name));
      }
      if (!results.fits.empty()) h += "<p>Drift fits.</p>\n" + fits_html(results.fits);
      if (!results.allan.empty()) h += "<p>Allan noise terms.</p>\n" + allan_html(results.allan);
      if (!results.sf.empty()) h += "<p>Scale factor.</p>\n" + scale_factor_html(results.sf);
      if (!results.sft.empty()) {
        h += "<p>Scale factor against temperature.</p>\n" + sf_temperature_html(results.sft);
      }
    }
  }
  h += "</section>\n</body>\n</html>\n";
  return h;
}

}  // namespace gyrotherm::lab
