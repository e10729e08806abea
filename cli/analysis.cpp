#include "analysis.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/stat.h>
#include <toml++/toml.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cerrno>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <iostream>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>

#include "control.h"
#include "gyrotherm/analysis/allan.h"
#include "gyrotherm/analysis/comparison.h"
#include "gyrotherm/analysis/csv_window.h"
#include "gyrotherm/analysis/drift_model.h"
#include "gyrotherm/analysis/noise_model.h"
#include "gyrotherm/analysis/scale_factor.h"
#include "gyrotherm/analysis/start_temperature.h"
#include "gyrotherm/analysis/table1.h"
#include "gyrotherm/calibration/report.h"
#include "gyrotherm/calibration/run_analysis.h"
#include "gyrotherm/config/run_config.h"
#include "gyrotherm/core/files.h"
#include "gyrotherm/storage/database.h"
#include "output.h"

namespace gyrotherm::cli {

using nlohmann::json;

namespace {

constexpr const char* kDash = "—";

json num(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }
json num(const std::optional<double>& v) { return v ? num(*v) : json(nullptr); }

std::string fixed(double v, int decimals) {
  return std::isfinite(v) ? fmt::format("{:.{}f}", v, decimals) : kDash;
}
std::string or_dash(const std::string& s) { return s.empty() ? std::string(kDash) : s; }
std::string sci(double v) { return std::isfinite(v) ? fmt::format("{:.6e}", v) : kDash; }
std::string general(double v) { return std::isfinite(v) ? fmt::format("{:.6g}", v) : kDash; }

std::string join_ids(const std::vector<int64_t>& ids) {
  std::string s;
  for (auto id : ids) s += (s.empty() ? "" : ",") + std::to_string(id);
  return s;
}

std::string now_utc_iso() {
  const auto now = std::chrono::system_clock::now();
  const std::time_t t = std::chrono::system_clock::to_time_t(now);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

using calibration::read_run_config;
using config::RunConfig;

}  // namespace

// ---------------------------------------------------------------- public helpers

Result<std::vector<int64_t>> parse_run_list(std::string_view list) {
  auto trim = [](std::string_view s) {
    while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
    while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
    return s;
  };
  auto id = [](std::string_view s) -> std::optional<int64_t> {
    int64_t v = 0;
    const auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
    if (s.empty() || ec != std::errc() || p != s.data() + s.size() || v <= 0) return std::nullopt;
    return v;
  };
  if (trim(list).empty()) return Error::Permanent("run list is empty (e.g. \"1,2,5\" or \"3-7\")");
  std::vector<int64_t> out;
  std::set<int64_t> seen;
  auto add = [&](int64_t v, std::string_view item) -> Status {
    if (!seen.insert(v).second) {
      return Error::Permanent(
          fmt::format("run list \"{}\": run {} is listed twice (in \"{}\")", list, v, item));
    }
    out.push_back(v);
    return Status::Ok();
  };
  std::size_t pos = 0;
  while (pos <= list.size()) {
    const std::size_t comma = std::min(list.find(',', pos), list.size());
    const std::string_view item = trim(list.substr(pos, comma - pos));
    pos = comma + 1;
    if (item.empty()) {
      return Error::Permanent(fmt::format("run list \"{}\": empty item", list));
    }
    const std::size_t dash = item.find('-', 1);
    if (dash == std::string_view::npos) {
      const auto v = id(item);
      if (!v) {
        return Error::Permanent(fmt::format(
            "run list \"{}\": \"{}\" is not a run id (a positive integer)", list, item));
      }
      if (auto st = add(*v, item); !st) return st.error();
      continue;
    }
    const auto from = id(trim(item.substr(0, dash)));
    const auto to = id(trim(item.substr(dash + 1)));
    if (!from || !to) {
      return Error::Permanent(fmt::format(
          "run list \"{}\": \"{}\" is not a range of run ids (e.g. \"3-7\")", list, item));
    }
    if (*to < *from) {
      return Error::Permanent(
          fmt::format("run list \"{}\": range \"{}\" ends before it starts", list, item));
    }
    if (*to - *from >= 100000) {
      return Error::Permanent(fmt::format("run list \"{}\": range \"{}\" is too long", list, item));
    }
    for (int64_t v = *from; v <= *to; ++v) {
      if (auto st = add(v, item); !st) return st.error();
    }
  }
  return out;
}

// ---------------------------------------------------------------- parsed options

namespace {

struct Args {
  CLI::App* stats = nullptr;
  CLI::App* allan = nullptr;
  CLI::App* fit = nullptr;
  CLI::App* compare = nullptr;
  CLI::App* start_model = nullptr;
  CLI::App* scale_factor = nullptr;

  // Input.
  std::string db_path;
  std::string config_path;  // --config: its [storage] db is the database
  std::optional<int64_t> run;
  std::optional<std::string> runs;
  std::vector<std::string> csv;
  bool json = false;
  std::vector<std::string> duts;  // --dut: the DUTs analysed (none: every DUT)
  std::vector<std::string> axes;  // --axis: the axes analysed (none: every analysed axis)
  bool stored = false;            // stats: the rows the daemon stored, not recomputed
  bool by_setpoint = false;       // stats: one row per set point (the paper's Table I)

  // Table I.
  std::optional<double> bin_s;
  std::optional<int> ma_window;
  std::optional<double> earth_rate_dph;
  std::optional<double> latitude_deg;
  std::optional<std::string> orientation;
  std::optional<double> heading_deg;  // --heading-deg, with --orientation horizontal
  // Allan.
  std::optional<std::string> taus;
  // Fits.
  std::optional<std::string> model;
  std::string form{analysis::to_string(analysis::kDefaultDriftModelForm)};
  std::optional<int> smooth_points;  // compare: moving-average points, 1 = raw
  std::optional<double> derivative_window_s;
  std::optional<double> l0_window_s;
  int max_order = 4, g_order = 1, r_order = 1;
  std::optional<double> t0_c;
  std::optional<double> t0_window_s;
  std::string coefficients_json;
  std::string c_header;
  bool force = false;  // fit: write the C header of a flagged fit too
  // Scale factor.
  std::string sf_csv;
  int sf_order = 1;
};

using Parsed = Args;

// ---------------------------------------------------------------- quality

// A result's quality as the REST API gives it (docs/api.md).
json quality_json(const storage::ResultQuality& q) {
  const bool assessed = q.verdict != "unassessed";
  return {{"verdict", q.verdict},
          {"reasons", q.reasons},
          {"coverage", q.coverage ? num(*q.coverage) : json(nullptr)},
          {"coverage_samples", assessed ? json(q.samples) : json(nullptr)},
          {"coverage_expected", q.expected > 0 ? num(q.expected) : json(nullptr)},
          {"longest_gap_s", q.longest_gap_s ? num(*q.longest_gap_s) : json(nullptr)}};
}

// The quality column of the text tables.
std::string quality_mark(const storage::ResultQuality& q) {
  if (q.flagged()) return "FLAGGED";
  if (q.verdict == "unassessed") return kDash;
  return q.verdict;
}

// The run's quality rules (its stored [quality]; the defaults when its
// settings do not parse).
analysis::QualityRules quality_rules_of(const storage::RunRecord& run) {
  auto s = calibration::analysis_settings_of_run(run);
  return s ? s->quality : analysis::QualityRules{};
}

// ---------------------------------------------------------------- input

// An open database and the runs chosen from it.
struct DbInput {
  storage::Database db;
  std::vector<storage::RunRecord> runs;  // in the order asked for
  std::vector<int64_t> ids() const {
    std::vector<int64_t> v;
    for (const auto& r : runs) v.push_back(r.id);
    return v;
  }
};

// The input of one command: a database with runs, or CSV files.
struct Input {
  std::optional<DbInput> db;
  std::vector<analysis::CsvWindow> csv;
};

enum class RunsNeeded { kOptional, kRequired };

// Opens what the options name. Errors are usage or input errors (exit 2).
Result<Input> open_input(const Parsed& p, RunsNeeded needed) {
  const bool has_db = !p.db_path.empty();
  if (has_db == !p.csv.empty()) {
    return Error::Permanent("give either --db FILE or --csv FILE (not both)");
  }
  Input in;
  if (!has_db) {
    if (p.run || p.runs) return Error::Permanent("--run and --runs go with --db, not --csv");
    if (!p.duts.empty() || !p.axes.empty()) {
      return Error::Permanent(
          "--dut and --axis go with --db, not --csv (a CSV file is one series)");
    }
    for (const auto& path : p.csv) {
      auto w = analysis::read_csv_window(path);
      if (!w) return w.error();
      in.csv.push_back(std::move(*w));
    }
    return in;
  }
  if (p.run && p.runs) return Error::Permanent("give --run ID or --runs LIST, not both");
  if (needed == RunsNeeded::kRequired && !p.run && !p.runs) {
    return Error::Permanent("--db needs --run ID or --runs LIST (e.g. --runs 1,2,5 or 3-7)");
  }
  std::vector<int64_t> ids;
  if (p.run) {
    ids.push_back(*p.run);
  } else if (p.runs) {
    auto list = parse_run_list(*p.runs);
    if (!list) return Error::Permanent("--runs: " + list.error().message);
    ids = std::move(*list);
  }
  auto db = storage::Database::open_read_only(p.db_path);
  if (!db) return db.error();
  auto all = db->runs();
  if (!all) return all.error();
  DbInput d{std::move(*db), {}};
  if (ids.empty()) {
    d.runs = std::move(*all);
    std::sort(d.runs.begin(), d.runs.end(),
              [](const auto& a, const auto& b) { return a.id < b.id; });
  } else {
    for (const int64_t id : ids) {
      const auto it =
          std::find_if(all->begin(), all->end(), [id](const auto& r) { return r.id == id; });
      if (it == all->end()) {
        return Error::Permanent(fmt::format("{}: unknown run {} (the database has {} run{})",
                                            p.db_path, id, all->size(),
                                            all->size() == 1 ? "" : "s"));
      }
      d.runs.push_back(*it);
    }
  }
  in.db = std::move(d);
  return in;
}

// ---------------------------------------------------------------- DUT axes

bool picked(const std::vector<std::string>& picks, const std::string& value) {
  return picks.empty() || std::find(picks.begin(), picks.end(), value) != picks.end();
}

bool same_stream(const calibration::AnalysedAxis& a, const calibration::AnalysedAxis& b) {
  return a.dut_serial == b.dut_serial && a.axis == b.axis;
}

// "SN 17-0042 z" for the text's block titles.
std::string stream_title(const calibration::AnalysedAxis& a) { return a.name(); }

// A run's DUT axes as --dut and --axis choose them; by default every
// analysed axis of every DUT (calibration::analysed_axes order: DUTs by
// position, the primary axis first).
Result<std::vector<calibration::AnalysedAxis>> chosen_axes(const Parsed& p, storage::Database& db,
                                                           int64_t run_id) {
  auto all = calibration::analysed_axes(db, run_id);
  if (!all) return Error::Permanent(fmt::format("run {}: {}", run_id, all.error().message));
  std::vector<calibration::AnalysedAxis> out;
  for (auto& a : *all) {
    if (picked(p.duts, a.dut_serial) && picked(p.axes, a.axis)) out.push_back(std::move(a));
  }
  return out;
}

// Every --dut must name a DUT of the runs and every --axis an analysed axis
// of a chosen DUT; else a usage error saying what the runs hold.
Status check_choice(const Parsed& p, DbInput& d) {
  if (p.duts.empty() && p.axes.empty()) return Status::Ok();
  std::set<std::string> serials, axes;
  std::vector<std::string> held;
  for (const auto& run : d.runs) {
    auto all = calibration::analysed_axes(d.db, run.id);
    if (!all) return Error::Permanent(fmt::format("run {}: {}", run.id, all.error().message));
    for (const auto& a : *all) {
      serials.insert(a.dut_serial);
      if (picked(p.duts, a.dut_serial)) axes.insert(a.axis);
      const std::string name = a.dut_serial.empty() ? "the gyro (no serial)" : a.name();
      if (std::find(held.begin(), held.end(), name) == held.end()) held.push_back(name);
    }
  }
  const std::string runs =
      fmt::format("run{} {}", d.runs.size() == 1 ? "" : "s", join_ids(d.ids()));
  for (const auto& dut : p.duts) {
    if (!serials.count(dut)) {
      return Error::Permanent(fmt::format("--dut {}: not a DUT of {} (analysed: {})", dut, runs,
                                          fmt::join(held, ", ")));
    }
  }
  for (const auto& axis : p.axes) {
    if (!axes.count(axis)) {
      return Error::Permanent(fmt::format("--axis {}: not an analysed axis of {} (analysed: {})",
                                          axis, runs, fmt::join(held, ", ")));
    }
  }
  return Status::Ok();
}

// The DUT axes a command over several runs fits, each over every run: the
// chosen axes of the first run that every run holds. One some run lacks is
// left out, with a note, unless --dut or --axis asked for it by name: then
// it is an error naming the run.
Result<std::vector<calibration::AnalysedAxis>> common_axes(const Parsed& p, DbInput& d,
                                                           std::vector<std::string>& notes) {
  if (auto st = check_choice(p, d); !st) return st.error();
  std::vector<calibration::AnalysedAxis> out;
  std::vector<std::vector<calibration::AnalysedAxis>> per_run;
  for (const auto& run : d.runs) {
    auto axes = chosen_axes(p, d.db, run.id);
    if (!axes) return axes.error();
    per_run.push_back(std::move(*axes));
  }
  if (per_run.empty()) return out;
  for (const auto& a : per_run.front()) {
    std::vector<int64_t> lacking;
    for (std::size_t r = 1; r < per_run.size(); ++r) {
      if (std::none_of(per_run[r].begin(), per_run[r].end(),
                       [&](const auto& b) { return same_stream(a, b); })) {
        lacking.push_back(d.runs[r].id);
      }
    }
    if (lacking.empty()) {
      out.push_back(a);
    } else if (!p.duts.empty() || !p.axes.empty()) {
      return Error::Permanent(fmt::format("{}: not in run{} {} (fit over runs that all hold it)",
                                          a.name(), lacking.size() == 1 ? "" : "s",
                                          join_ids(lacking)));
    } else {
      notes.push_back(fmt::format("{}: left out: not in run{} {}", a.name(),
                                  lacking.size() == 1 ? "" : "s", join_ids(lacking)));
    }
  }
  if (out.empty()) {
    return Error::Permanent(
        fmt::format("no DUT axis is in every one of runs {}", join_ids(d.ids())));
  }
  return out;
}

// Earth rate removed from a window's mean: --earth-rate-dph, else from
// --latitude/--orientation, else (database) the run's own.
Result<double> earth_rate_dph(const Parsed& p, const storage::RunRecord* run) {
  if (p.earth_rate_dph) return *p.earth_rate_dph;
  std::optional<double> lat = p.latitude_deg;
  std::string orient = p.orientation.value_or("");
  if (run != nullptr) {
    if (!lat) lat = run->latitude_deg;
    if (orient.empty()) orient = run->orientation;
  }
  if (!lat) {
    if (p.orientation) return Error::Permanent("--orientation needs --latitude DEG");
    if (p.heading_deg) return Error::Permanent("--heading-deg needs --latitude DEG");
    return 0.0;
  }
  if (orient.empty()) orient = "up";
  auto o = analysis::parse_orientation(orient);
  if (!o) {
    return Error::Permanent(
        run != nullptr && !p.orientation
            ? fmt::format("run {}: stored orientation \"{}\": {} (give --earth-rate-dph)", run->id,
                          orient, o.error().message)
            : fmt::format("--orientation: {}", o.error().message));
  }
  if (p.heading_deg && *o != analysis::AxisOrientation::kHorizontal) {
    return Error::Permanent(fmt::format(
        "--heading-deg {:g}: only a horizontal axis has a heading (give --orientation horizontal)",
        *p.heading_deg));
  }
  return analysis::earth_rate_component_dph(*lat, *o, p.heading_deg);
}

// An options struct's is_valid message names its field ("l0_window_s must be
// positive"); the user typed the option (--l0-window-s).
std::string as_option(std::string message) {
  for (const char* field : {"max_order", "g_order", "r_order", "l0_window_s", "derivative_window_s",
                            "t0_window_s", "bin_s", "ma_window", "smooth_points"}) {
    const std::string f = field;
    if (message.rfind(f, 0) == 0) {
      std::string option = "--" + f;
      std::replace(option.begin(), option.end(), '_', '-');
      return option + message.substr(f.size());
    }
  }
  return message;
}

Result<analysis::Table1Options> table1_options(const Parsed& p, const RunConfig& cfg,
                                               const storage::RunRecord* run) {
  analysis::Table1Options o;
  o.bin_s = p.bin_s.value_or(cfg.bin_s.value_or(o.bin_s));
  const int window = p.ma_window.value_or(cfg.ma_window.value_or(static_cast<int>(o.ma_window)));
  if (window < 2) return Error::Permanent(fmt::format("--ma-window {}: must be >= 2", window));
  o.ma_window = static_cast<std::size_t>(window);
  auto e = earth_rate_dph(p, run);
  if (!e) return e.error();
  o.earth_rate_dph = *e;
  std::string why;
  if (!o.is_valid(&why)) return Error::Permanent(as_option(why));
  return o;
}

// The first run's stored config for multi-run commands ({} for CSV).
RunConfig first_run_config(const Input& in) {
  return in.db && !in.db->runs.empty() ? read_run_config(in.db->runs.front()) : RunConfig{};
}

Result<analysis::DriftFitOptions> fit_options(const Parsed& p, const RunConfig& cfg) {
  analysis::DriftFitOptions o;
  o.derivative_window_s =
      p.derivative_window_s.value_or(cfg.derivative_window_s.value_or(o.derivative_window_s));
  o.l0_window_s = p.l0_window_s.value_or(cfg.l0_window_s.value_or(o.l0_window_s));
  std::string why;
  if (!o.is_valid(&why)) return Error::Permanent(as_option(why));
  return o;
}

Result<analysis::DriftModelSpec> model_spec(const Parsed& p, const RunConfig& cfg) {
  const std::string text = p.model.value_or(cfg.model.value_or("T4+R1+G1"));
  auto spec = analysis::parse_model_spec(text);
  if (!spec) {
    return Error::Permanent(fmt::format("{} \"{}\": {}", p.model ? "--model" : "stored model", text,
                                        spec.error().message));
  }
  return spec;
}

// Every run's (or file's) analysis series, in order; `names` says which is
// which in messages. Errors are analysis errors (exit 1).
struct SeriesSet {
  std::vector<analysis::AnalysisSeries> series;
  std::vector<analysis::Coverage> coverage;  // each run's (none for CSV files)
  std::vector<std::string> names;
  json inputs;  // {"runs": [..]} or {"csv": [..]}
};

// `stream`: the DUT axis read from each run (its own channel there).
Result<SeriesSet> load_series(Input& in, double bin_s, const calibration::AnalysedAxis* stream) {
  SeriesSet s;
  if (in.db) {
    for (const auto& r : in.db->runs) {
      auto axes = calibration::analysed_axes(in.db->db, r.id);
      if (!axes) return Error::Permanent(fmt::format("run {}: {}", r.id, axes.error().message));
      const auto axis = std::find_if(axes->begin(), axes->end(), [&](const auto& a) {
        return stream == nullptr || same_stream(a, *stream);
      });
      if (axis == axes->end()) {
        return Error::Permanent(fmt::format("run {}: no {}", r.id, stream->name()));
      }
      calibration::RunSeriesCoverage coverage;
      auto series = calibration::run_series(in.db->db, r.id, bin_s, *axis, &coverage);
      if (!series) return Error::Permanent(fmt::format("run {}: {}", r.id, series.error().message));
      s.series.push_back(std::move(*series));
      s.coverage.push_back(coverage.coverage);
      s.names.push_back(fmt::format("run {}", r.id));
    }
    s.inputs = {{"database", in.db->db.path()}, {"runs", in.db->ids()}};
  } else {
    json files = json::array();
    for (const auto& w : in.csv) {
      auto series = analysis::csv_analysis_series(w, bin_s);
      if (!series) return Error::Permanent(fmt::format("{}: {}", w.source, series.error().message));
      s.series.push_back(std::move(*series));
      s.names.push_back(w.source);
      files.push_back(w.source);
    }
    s.inputs = {{"csv", files}};
  }
  s.inputs["bin_s"] = bin_s;
  return s;
}

// --bin-s, else the run's [analysis] bin_s, else 1 s; an error unless positive.
Result<double> bin_s_of(const Parsed& p, const RunConfig& cfg) {
  const double bin_s = p.bin_s.value_or(cfg.bin_s.value_or(1.0));
  if (!(bin_s > 0) || !std::isfinite(bin_s)) {
    return Error::Permanent(fmt::format("--bin-s {:g}: must be positive", bin_s));
  }
  return bin_s;
}

// What the coefficient exports say of where they come from; `l0_window_s`:
// the fit's L0 window.
analysis::ExportInfo export_info(const Input& in, const RunConfig& cfg, double l0_window_s,
                                 const calibration::AnalysedAxis* stream) {
  analysis::ExportInfo info;
  info.station = cfg.station_name;
  info.l0_window_s = l0_window_s;
  if (stream != nullptr) {
    info.gyro_serial = stream->dut_serial;
    info.gyro_model = stream->dut_model;
    info.axis = stream->axis;
  }
  if (in.db) {
    info.run_ids = in.db->ids();
    if (!in.db->runs.empty()) {
      const storage::RunMetadata& m = in.db->runs.front().metadata;
      info.operator_name = m.operator_name;
      info.comment = m.comment;
      info.tags = m.tags;
    }
  }
  info.computed_utc = now_utc_iso();
  return info;
}

// Writes the export files that were asked for. Errors exit 1 (the analysis
// is done; the output could not be written).
int write_exports(const Parsed& p, const std::function<std::string()>& json_text,
                  const std::function<std::string()>& header_text) {
  if (!p.coefficients_json.empty()) {
    if (auto st = write_file_atomically(p.coefficients_json, json_text()); !st) {
      return fail(st.error().message, kExitFailed);
    }
  }
  if (!p.c_header.empty()) {
    if (auto st = write_file_atomically(p.c_header, header_text()); !st) {
      return fail(st.error().message, kExitFailed);
    }
  }
  return 0;
}

// ---------------------------------------------------------------- stats

// A soak result's identity in the JSON of stats and allan: its run, step
// (1-based), DUT axis, set point and the span of its windows.
json soak_json(const calibration::SoakWindow& soak, const calibration::AnalysedAxis& axis,
               double from_s, double to_s) {
  return {{"run_id", soak.run_id},
          {"segment", soak.segment_index + 1},
          {"dut_serial", axis.dut_serial},
          {"axis", axis.axis},
          {"setpoint_c", num(soak.setpoint_c)},
          {"t_from_s", num(from_s)},
          {"t_to_s", num(to_s)}};
}

json stats_json(const analysis::Table1Row& row, const analysis::Table1Options& o) {
  json j = {{"n", row.n},
            {"duration_s", num(row.duration_s)},
            {"temp_mean_c", num(row.temp_mean_c)},
            {"bias_mean_dph", num(row.bias_mean_dph)},
            {"bias_std_dph", num(row.bias_std_dph)},
            {"bias_std_ma101_dph", num(row.bias_std_ma_dph)},
            {"bias_mean_earth_removed_dph", num(row.bias_mean_earth_removed_dph)},
            {"earth_rate_dph", num(o.earth_rate_dph)},
            {"bin_s", o.bin_s},
            {"ma_window", o.ma_window},
            {"bias_u", calibration::mean_uncertainty_json(row.bias_u)},
            {"bias_u_note", row.bias_u_note}};
  json warnings = json::array();
  if (row.n <= o.ma_window) {
    warnings.push_back(
        fmt::format("{} points, not more than the {}-point moving average: no moving-average std",
                    row.n, o.ma_window));
  }
  if (!row.bias_u && !row.bias_u_note.empty()) {
    warnings.push_back("no uncertainty of the bias mean: " + row.bias_u_note);
  }
  j["warnings"] = warnings;
  return j;
}

// The half-width of the bias mean's 95 % interval, "RW" when rate random walk
// dominates it (it covers less than it says); a dash when there is none.
std::string bias_u_text(const std::optional<analysis::MeanUncertainty>& u) {
  if (!u) return std::string(kDash);
  return fixed(u->expanded_dph, 4) + (u->random_walk_dominated ? " RW" : "");
}

json mean_spread_json(const analysis::MeanSpread& m) {
  return {{"mean", num(m.mean)}, {"std", num(m.std)}, {"n", m.n}};
}

std::string mean_spread_text(const analysis::MeanSpread& m, int decimals) {
  if (m.n == 0) return kDash;
  return fmt::format("{} ± {}", fixed(m.mean, decimals), fixed(m.std, decimals));
}

// `gyrotherm stats --by-setpoint`: Table I as the paper prints it, the soaks
// grouped by their schedule set point (analysis::table1_by_setpoint).
// A soak's Table I row, with the DUT axis it is of ({"", ""}: CSV input).
struct StreamSoak {
  storage::StreamKey stream;
  std::string name;  // calibration::AnalysedAxis::name(); "" for CSV input
  analysis::Table1Soak soak;
  json id;  // {"run_id", "segment"}
};

// One group per DUT axis and set point: the DUT axes in the order they
// first come, each one's set points as table1_by_setpoint groups them.
int print_by_setpoint(const Parsed& p, const std::vector<StreamSoak>& soaks,
                      const std::vector<std::string>& notes, const std::set<std::string>& footer) {
  std::vector<std::string> order;
  for (const auto& s : soaks) {
    if (std::find(order.begin(), order.end(), s.name) == order.end()) order.push_back(s.name);
  }
  const bool named =
      order.size() > 1 || (order.size() == 1 && !soaks.front().stream.dut_serial.empty());
  json out = json::array();
  std::vector<std::vector<std::string>> rows;
  for (const auto& name : order) {
    std::vector<analysis::Table1Soak> group_soaks;
    std::vector<const StreamSoak*> members_of;
    for (const auto& s : soaks) {
      if (s.name != name) continue;
      group_soaks.push_back(s.soak);
      members_of.push_back(&s);
    }
    auto groups = analysis::table1_by_setpoint(group_soaks);
    if (!groups) return fail(fmt::format("{}: {}", name, groups.error().message), kExitFailed);
    for (const auto& g : *groups) {
      json members = json::array();
      for (std::size_t i : g.soaks) members.push_back(members_of[i]->id);
      out.push_back(
          {{"dut_serial", members_of.front()->stream.dut_serial},
           {"axis", members_of.front()->stream.axis},
           {"setpoint_c", num(g.setpoint_c)},
           {"repetitions", g.repetitions},
           {"soaks", members},
           {"temp_mean_c", mean_spread_json(g.temp_mean_c)},
           {"bias_mean_dph", mean_spread_json(g.bias_mean_dph)},
           {"bias_mean_u", calibration::mean_uncertainty_json(g.bias_mean_u)},
           {"bias_mean_u_note", g.bias_mean_u_note},
           {"bias_std_dph", mean_spread_json(g.bias_std_dph)},
           {"bias_std_ma101_dph", mean_spread_json(g.bias_std_ma_dph)},
           {"bias_mean_earth_removed_dph", mean_spread_json(g.bias_mean_earth_removed_dph)}});
      std::vector<std::string> row = {fixed(g.setpoint_c, 2),
                                      std::to_string(g.repetitions),
                                      mean_spread_text(g.temp_mean_c, 2),
                                      mean_spread_text(g.bias_mean_dph, 4),
                                      bias_u_text(g.bias_mean_u),
                                      mean_spread_text(g.bias_std_dph, 4),
                                      mean_spread_text(g.bias_std_ma_dph, 4),
                                      mean_spread_text(g.bias_mean_earth_removed_dph, 4)};
      if (named) {
        row.insert(
            row.begin(),
            {members_of.front()->stream.dut_serial.empty() ? std::string(kDash)
                                                           : members_of.front()->stream.dut_serial,
             members_of.front()->stream.axis.empty() ? std::string(kDash)
                                                     : members_of.front()->stream.axis});
      }
      rows.push_back(std::move(row));
    }
  }
  if (p.json) {
    std::cout << out.dump(2) << "\n";
    return 0;
  }
  for (const auto& n : notes) std::cout << n << "\n";
  if (rows.empty()) {
    std::cout << "no Table I rows\n";
    return 0;
  }
  std::vector<std::string> header = {"setpt °C",  "reps",    "temp °C",    "bias °/h",
                                     "± U95 °/h", "std °/h", "std MA °/h", "bias−Ω °/h"};
  if (named) header.insert(header.begin(), {"DUT", "axis"});
  std::cout << table(header, rows, named ? 2 : 0);
  std::cout << "(each column: mean ± sample std over the soaks of the set point; soaks grouped by "
               "their schedule set point)\n"
               "(± U95: half-width of the 95 % interval of the mean bias from the noise within "
               "the soaks, their own intervals combined; the spread between soaks is the ± "
               "beside the bias; RW: rate random walk dominates)\n";
  for (const auto& f : footer) std::cout << "(" << f << ")\n";
  return 0;
}

int cmd_stats(const Parsed& p) {
  auto in = open_input(p, RunsNeeded::kOptional);
  if (!in) return fail(in.error().message, kExitInput);
  json out = json::array();
  std::vector<std::vector<std::string>> rows;
  std::vector<std::string> notes;
  std::set<std::string> footer;
  // For --by-setpoint: each soak's DUT axis, set point, row and JSON identity.
  std::vector<StreamSoak> soaks_for_groups;
  // A DUT and axis column when the rows name their DUTs.
  bool named = false;
  if (in->db) {
    if (auto st = check_choice(p, *in->db); !st) return fail(st.error().message, kExitInput);
  }
  // Database rows carry their quality: a column, and the reasons of each
  // flagged row after the table.
  std::vector<std::string> flagged;
  // Adaptive soaks: why each one's acquisition ended (segments.acquire_stop),
  // by run and segment index, in each row's JSON and after the table.
  std::map<std::pair<int64_t, int>, std::string> acquire_stops;
  auto read_acquire_stops = [&](storage::Database& db, int64_t run_id) -> Status {
    auto segments = db.segments(run_id);
    if (!segments) return segments.error();
    for (const auto& seg : *segments) {
      if (!seg.acquire_stop.empty()) acquire_stops[{run_id, seg.index}] = seg.acquire_stop;
    }
    return Status::Ok();
  };
  auto acquire_stop_of = [&](int64_t run_id, int index) -> json {
    auto it = acquire_stops.find({run_id, index});
    return it == acquire_stops.end() ? json(nullptr) : json(it->second);
  };
  auto add_row = [&](std::vector<std::string> lead, const analysis::Table1Row& r,
                     const analysis::Table1Options& o,
                     const storage::ResultQuality* quality = nullptr) {
    for (std::string v :
         {std::to_string(r.n), fixed(r.duration_s, 0), fixed(r.temp_mean_c, 2),
          fixed(r.bias_mean_dph, 4), bias_u_text(r.bias_u), fixed(r.bias_std_dph, 4),
          fixed(r.bias_std_ma_dph, 4), fixed(r.bias_mean_earth_removed_dph, 4)}) {
      lead.push_back(std::move(v));
    }
    if (quality != nullptr) {
      lead.push_back(quality_mark(*quality));
      if (quality->flagged()) {
        flagged.push_back(fmt::format("run {} segment {}{}: FLAGGED: {}", lead[0], lead[1],
                                      lead[3] == kDash ? "" : " DUT " + lead[3] + " " + lead[4],
                                      fmt::join(quality->reasons, "; ")));
      }
    }
    rows.push_back(std::move(lead));
    footer.insert(
        fmt::format("std MA: after a {}-point moving average ({:g} s bins); bias−Ω: "
                    "Earth rate {:.4f} °/h removed",
                    o.ma_window, o.bin_s, o.earth_rate_dph));
    footer.insert(
        "± U95: half-width of the bias mean's 95 % interval, from the soak's noise model "
        "(docs/analysis.md \"Uncertainty of a mean\"); RW: rate random walk dominates it, the "
        "interval covers less than it says");
  };
  if (in->db && p.stored) {
    if (p.bin_s || p.ma_window || p.earth_rate_dph || p.latitude_deg || p.orientation ||
        p.heading_deg) {
      return fail(
          "--stored prints the rows as the daemon stored them: --bin-s, --ma-window and the "
          "Earth-rate options do not apply",
          kExitInput);
    }
    for (const auto& run : in->db->runs) {
      auto stored = in->db->db.segment_stats(run.id);
      if (!stored) return fail(stored.error().message, kExitFailed);
      if (auto st = read_acquire_stops(in->db->db, run.id); !st) {
        return fail(st.error().message, kExitFailed);
      }
      for (const auto& rec : *stored) {
        if (!picked(p.duts, rec.dut_serial) || !picked(p.axes, rec.axis)) continue;
        named = named || !rec.dut_serial.empty();
        analysis::Table1Options o;
        o.bin_s = rec.bin_s;
        o.ma_window = static_cast<std::size_t>(std::max(rec.ma_window, 0));
        o.earth_rate_dph = rec.earth_rate_dph;
        const auto row = calibration::table1_row_of(rec);
        json j = {{"run_id", rec.run_id},
                  {"segment", rec.segment_index + 1},
                  {"dut_serial", rec.dut_serial},
                  {"axis", rec.axis},
                  {"setpoint_c", num(rec.setpoint_c)},
                  {"t_from_s", num(rec.t_from_s)},
                  {"t_to_s", num(rec.t_to_s)},
                  {"computed_utc", rec.computed_utc}};
        j.update(stats_json(row, o));
        j["quality"] = quality_json(rec.quality);
        j["acquire_stop"] = acquire_stop_of(rec.run_id, rec.segment_index);
        out.push_back(std::move(j));
        calibration::AnalysedAxis named_axis;
        named_axis.dut_serial = rec.dut_serial;
        named_axis.axis = rec.axis;
        soaks_for_groups.push_back({{rec.dut_serial, rec.axis},
                                    named_axis.name(),
                                    {rec.setpoint_c, row},
                                    {{"run_id", rec.run_id}, {"segment", rec.segment_index + 1}}});
        add_row({std::to_string(rec.run_id), std::to_string(rec.segment_index + 1),
                 fixed(rec.setpoint_c, 2), or_dash(rec.dut_serial), or_dash(rec.axis)},
                row, o, &rec.quality);
      }
    }
  } else if (in->db) {
    auto& db = in->db->db;
    for (const auto& run : in->db->runs) {
      const RunConfig cfg = read_run_config(run);
      auto opts = table1_options(p, cfg, &run);
      if (!opts) return fail(opts.error().message, kExitInput);
      auto soaks = calibration::soak_windows(db, run.id);
      if (!soaks)
        return fail(fmt::format("run {}: {}", run.id, soaks.error().message), kExitFailed);
      if (auto st = read_acquire_stops(db, run.id); !st) {
        return fail(st.error().message, kExitFailed);
      }
      if (soaks->empty()) {
        notes.push_back(
            fmt::format("run {}: no completed soak with an acquisition window", run.id));
      }
      auto axes = chosen_axes(p, db, run.id);
      if (!axes) return fail(axes.error().message, kExitFailed);
      const analysis::QualityRules rules = quality_rules_of(run);
      for (const auto& soak : *soaks) {
        for (const auto& axis : *axes) {
          auto rec = calibration::soak_table1(db, soak, *opts, axis, rules);
          if (!rec) return fail(rec.error().message, kExitFailed);
          named = named || !axis.dut_serial.empty();
          const auto row = calibration::table1_row_of(*rec);
          json j = soak_json(soak, axis, rec->t_from_s, rec->t_to_s);
          j.update(stats_json(row, *opts));
          j["quality"] = quality_json(rec->quality);
          j["acquire_stop"] = acquire_stop_of(run.id, soak.segment_index);
          out.push_back(std::move(j));
          soaks_for_groups.push_back({axis.key(),
                                      axis.name(),
                                      {soak.setpoint_c, row},
                                      {{"run_id", run.id}, {"segment", soak.segment_index + 1}}});
          add_row({std::to_string(run.id), std::to_string(soak.segment_index + 1),
                   fixed(soak.setpoint_c, 2), or_dash(axis.dut_serial), or_dash(axis.axis)},
                  row, *opts, &rec->quality);
        }
      }
    }
  } else {
    if (p.by_setpoint) {
      return fail("--by-setpoint groups a database's soaks by their set point; a CSV file has none",
                  kExitInput);
    }
    auto opts = table1_options(p, RunConfig{}, nullptr);
    if (!opts) return fail(opts.error().message, kExitInput);
    for (const auto& w : in->csv) {
      auto series = analysis::csv_analysis_series(w, opts->bin_s);
      if (!series)
        return fail(fmt::format("{}: {}", w.source, series.error().message), kExitFailed);
      auto row = analysis::table1_row(*series, *opts);
      if (!row) return fail(fmt::format("{}: {}", w.source, row.error().message), kExitFailed);
      json j = {{"source", w.source}};
      j.update(stats_json(*row, *opts));
      out.push_back(std::move(j));
      add_row({w.source}, *row, *opts);
    }
  }
  if (p.by_setpoint) return print_by_setpoint(p, soaks_for_groups, notes, footer);
  if (p.json) {
    std::cout << out.dump(2) << "\n";
    return 0;
  }
  for (const auto& n : notes) std::cout << n << "\n";
  if (rows.empty()) {
    std::cout << "no Table I rows\n";
    return 0;
  }
  std::vector<std::string> header = {"n",         "length s", "temp °C",    "bias °/h",
                                     "± U95 °/h", "std °/h",  "std MA °/h", "bias−Ω °/h"};
  const std::vector<std::string> lead =
      in->db ? std::vector<std::string>{"run", "seg", "setpt °C", "DUT", "axis"}
             : std::vector<std::string>{"file"};
  header.insert(header.begin(), lead.begin(), lead.end());
  if (in->db) header.push_back("quality");
  if (in->db && !named) {
    // One unnamed gyro: no DUT and axis columns.
    header.erase(header.begin() + 3, header.begin() + 5);
    for (auto& r : rows) r.erase(r.begin() + 3, r.begin() + 5);
  }
  std::cout << table(header, rows, in->db ? 0 : 1);
  for (const auto& f : footer) std::cout << "(" << f << ")\n";
  for (const auto& f : flagged) std::cout << f << "\n";
  for (const auto& [key, stop] : acquire_stops) {
    std::cout << fmt::format("run {} segment {}: adaptive soak: {}\n", key.first, key.second + 1,
                             stop);
  }
  for (const auto& j : out) {
    for (const auto& w : j["warnings"]) {
      const std::string who = j.contains("source")
                                  ? j["source"].get<std::string>()
                                  : fmt::format("run {} segment {}", j["run_id"].get<int64_t>(),
                                                j["segment"].get<int>());
      std::cout << who << ": " << w.get<std::string>() << "\n";
    }
  }
  return 0;
}

// ---------------------------------------------------------------- allan

// The curve and noise terms in the command's JSON and text forms.
struct AllanView {
  double tau0_s = 0;
  int64_t n_samples = 0;
  std::vector<double> tau_s, adev, lo, hi, edf;
  std::vector<int64_t> n_terms;
  // The noise identified at each tau (AllanResult::noise_alpha); empty for a
  // stored curve, whose edf is then white rate noise's.
  std::vector<int> noise_alpha;
  analysis::AllanNoiseTerms noise;
  std::string bi_method;
  // The noise model fitted to the curve and the uncertainty it gives the
  // mean of the whole record (analysis/noise_model.h); or why there is none.
  std::optional<analysis::NoiseModel> model;
  std::optional<analysis::MeanUncertainty> mean_u;
  std::string model_error;
};

// Fits the noise model to v's curve and projects u of the record's mean.
void add_noise_model(AllanView& v) {
  auto model = analysis::fit_noise_model(v.tau_s, v.adev, v.edf);
  if (!model) {
    v.model_error = model.error().message;
    return;
  }
  v.model = *model;
  auto u = analysis::mean_uncertainty(*model, static_cast<double>(v.n_samples) * v.tau0_s);
  if (u) {
    v.mean_u = *u;
  } else {
    v.model_error = u.error().message;
  }
}

AllanView view_of(const analysis::AllanResult& a) {
  AllanView v{a.tau0_s,
              static_cast<int64_t>(a.n_samples),
              a.tau_s,
              a.adev_dph,
              a.adev_lo_dph,
              a.adev_hi_dph,
              a.edf,
              {},
              a.noise_alpha,
              a.noise,
              a.bias_instability_method,
              {},
              {},
              {}};
  for (auto t : a.n_terms) v.n_terms.push_back(static_cast<int64_t>(t));
  add_noise_model(v);
  return v;
}

// The stored record lacks the number of terms, the edf and the bounds; all
// follow from n and the cluster size m = tau / tau0 (allan_noise_terms).
AllanView view_of(const storage::AllanRecord& a) {
  const auto n = static_cast<std::size_t>(std::max<int64_t>(a.n_samples, 0));
  AllanView v{a.tau0_s,
              a.n_samples,
              a.tau_s,
              a.adev_dph,
              a.adev_lo_dph,
              a.adev_hi_dph,
              {},
              {},
              a.noise_alpha.size() == a.tau_s.size() ? a.noise_alpha : std::vector<int>{},
              analysis::allan_noise_terms(n, a.tau0_s, a.tau_s, a.adev_dph),
              a.bias_instability_method,
              {},
              {},
              {}};
  for (const double tau : a.tau_s) {
    const auto m = static_cast<std::size_t>(std::llround(a.tau0_s > 0 ? tau / a.tau0_s : 0));
    v.n_terms.push_back(2 * m <= n + 1 ? static_cast<int64_t>(n - 2 * m + 1) : 0);
    v.edf.push_back(analysis::allan_edf_white_fm(n, m));
  }
  // Computed just now (not read back): the bounds' own edf.
  if (a.edf.size() == a.tau_s.size()) v.edf = a.edf;
  add_noise_model(v);
  return v;
}

// One noise term as JSON: kind (value, upper_bound, unavailable), value (the
// value or the bound; null when unavailable), tau_s and tau_relation, note.
json noise_term_json(const analysis::NoiseTerm& t) {
  const bool has = t.kind != analysis::NoiseTermKind::kUnavailable;
  return {{"kind", analysis::to_string(t.kind)},
          {"value", has ? num(t.value) : json(nullptr)},
          {"tau_s", num(t.tau_s)},
          {"tau_relation", t.tau_relation},
          {"note", t.note}};
}

json model_term_json(const analysis::NoiseModelTerm& t) {
  return {{"value", num(t.value)}, {"lo", num(t.lo)}, {"hi", num(t.hi)}, {"fitted", t.fitted}};
}

// The noise model and the uncertainty of the record's mean; null when the
// curve could not be fitted (noise_model_error says why).
json noise_model_json(const AllanView& v) {
  if (!v.model) return nullptr;
  json j = {{"angle_random_walk_dprh", model_term_json(v.model->angle_random_walk_dprh)},
            {"bias_instability_dph", model_term_json(v.model->bias_instability_dph)},
            {"rate_random_walk_dphprh", model_term_json(v.model->rate_random_walk_dphprh)},
            {"gauss_markov_dph", model_term_json(v.model->gauss_markov_dph)},
            {"gauss_markov_tc_s", v.model->gm_tc_s > 0 ? num(v.model->gm_tc_s) : json(nullptr)},
            {"chi2", num(v.model->chi2)},
            {"mean_uncertainty", nullptr}};
  j["mean_uncertainty"] = calibration::mean_uncertainty_json(v.mean_u);
  return j;
}

json allan_json(const AllanView& v, std::string_view taus) {
  auto arr = [](const std::vector<double>& x) {
    json a = json::array();
    for (double d : x) a.push_back(num(d));
    return a;
  };
  const auto value = [](const analysis::NoiseTerm& t) {
    return t.is_value() ? num(t.value) : json(nullptr);
  };
  const auto& bi = v.noise.bias_instability_dph;
  return {{"taus", taus},
          {"tau0_s", num(v.tau0_s)},
          {"n_samples", v.n_samples},
          {"tau_s", arr(v.tau_s)},
          {"adev_dph", arr(v.adev)},
          {"adev_lo_dph", arr(v.lo)},
          {"adev_hi_dph", arr(v.hi)},
          {"n_terms", v.n_terms},
          {"edf", arr(v.edf)},
          {"noise_alpha", v.noise_alpha.empty() ? json(nullptr) : json(v.noise_alpha)},
          {"angle_random_walk_dprh", value(v.noise.angle_random_walk_dprh)},
          {"bias_instability_dph", value(bi)},
          {"bias_instability_tau_s", bi.is_value() && bi.tau_s ? num(*bi.tau_s) : json(nullptr)},
          {"bias_instability_method", v.bi_method},
          {"rate_random_walk_dphprh", value(v.noise.rate_random_walk_dphprh)},
          {"noise_terms",
           {{"angle_random_walk_dprh", noise_term_json(v.noise.angle_random_walk_dprh)},
            {"bias_instability_dph", noise_term_json(bi)},
            {"rate_random_walk_dphprh", noise_term_json(v.noise.rate_random_walk_dphprh)}}},
          {"noise_model", noise_model_json(v)},
          {"noise_model_error", v.model_error.empty() ? json(nullptr) : json(v.model_error)}};
}

// "0.0157 [0.0155, 0.0159] °/√h", or "— (< 0.03 °/√h)" for a term the curve
// does not show.
std::string model_term_text(const analysis::NoiseModelTerm& t, std::string_view unit) {
  if (!t.fitted) return fmt::format("{} (< {} {})", kDash, general(t.hi), unit);
  return fmt::format("{} [{}, {}] {}", general(t.value), general(t.lo), general(t.hi), unit);
}

// A noise term for the text output: "0.0123 °/h", "< 0.0456 °/h", "—".
std::string noise_term_short(const analysis::NoiseTerm& t, std::string_view unit) {
  switch (t.kind) {
    case analysis::NoiseTermKind::kValue:
      return fmt::format("{} {}", general(t.value), unit);
    case analysis::NoiseTermKind::kUpperBound:
      return fmt::format("< {} {}", general(t.value), unit);
    case analysis::NoiseTermKind::kUnavailable:
      break;
  }
  return std::string(kDash);
}

// The term with where it was read and how: "< 0.0456 °/h at τ ≥ 1200 s (upper
// bound: no minimum yet: ...)".
std::string noise_term_line(const analysis::NoiseTerm& t, std::string_view unit) {
  std::string out = noise_term_short(t, unit);
  if (t.tau_s && t.kind != analysis::NoiseTermKind::kUnavailable) {
    const std::string_view rel = t.tau_relation == ">=" ? "≥" : t.tau_relation == "<=" ? "≤" : "=";
    out += fmt::format(" at τ {} {} s", rel, general(*t.tau_s));
  }
  const bool bound = t.kind == analysis::NoiseTermKind::kUpperBound;
  if (!t.note.empty()) out += fmt::format(" ({}{})", bound ? "upper bound: " : "", t.note);
  return out;
}

std::string allan_text(const std::string& title, const AllanView& v, std::string_view taus) {
  std::string out = fmt::format("{}: {} samples, τ0 {} s, {} taus\n", title, v.n_samples,
                                general(v.tau0_s), taus);
  std::vector<std::vector<std::string>> rows;
  for (std::size_t i = 0; i < v.tau_s.size(); ++i) {
    rows.push_back({general(v.tau_s[i]), sci(v.adev[i]), i < v.lo.size() ? sci(v.lo[i]) : kDash,
                    i < v.hi.size() ? sci(v.hi[i]) : kDash,
                    i < v.n_terms.size() ? std::to_string(v.n_terms[i]) : kDash,
                    i < v.edf.size() ? general(v.edf[i]) : kDash,
                    i < v.noise_alpha.size() ? fmt::format("{:+d}", v.noise_alpha[i]) : kDash});
  }
  out += table({"τ s", "σ °/h", "σ lo °/h", "σ hi °/h", "terms", "edf", "α"}, rows, 0, "  ");
  out += fmt::format("  angle random walk  {}\n",
                     noise_term_line(v.noise.angle_random_walk_dprh, "°/√h"));
  // A value's note is the method; a bound or a dash names it too.
  const auto& bi = v.noise.bias_instability_dph;
  out += fmt::format(
      "  bias instability   {}{}\n", noise_term_line(bi, "°/h"),
      bi.is_value()
          ? std::string()
          : fmt::format(" [method: {}]", v.bi_method.empty() ? "minimum / 0.664" : v.bi_method));
  out += fmt::format("  rate random walk   {}\n",
                     noise_term_line(v.noise.rate_random_walk_dphprh, "°/h/√h"));
  out += v.noise_alpha.empty()
             ? "  (bounds: as stored; edf: white rate noise's; \"< x\": the curve does not reach "
               "the term's region, so the term is below x)\n"
             : "  (bounds: 68.3 % chi-squared with the edf of the noise identified at each τ, "
               "α: 0 white rate noise, -1 flicker, -2 rate random walk, +1/+2 angle noise; "
               "\"< x\": the curve does not reach the term's region, so the term is below x)\n";
  if (v.model) {
    out += fmt::format("  noise model (95 %)  ARW {}, bias instability {}, RRW {}\n",
                       model_term_text(v.model->angle_random_walk_dprh, "°/√h"),
                       model_term_text(v.model->bias_instability_dph, "°/h"),
                       model_term_text(v.model->rate_random_walk_dphprh, "°/h/√h"));
    if (v.model->gauss_markov_dph.fitted) {
      out += fmt::format("  a wandering bias (Gauss-Markov) {}, correlation time {:.0f} s\n",
                         model_term_text(v.model->gauss_markov_dph, "°/h"), v.model->gm_tc_s);
    }
  }
  if (v.mean_u) {
    const auto& u = *v.mean_u;
    out += fmt::format(
        "  mean of the {} s record: u {} °/h, ±{} °/h at {:g} % (k {}, {} dof); floor {} °/h{}\n",
        general(u.window_s), general(u.u_dph), general(u.expanded_dph), 100 * u.coverage,
        general(u.k), std::isfinite(u.dof) ? general(u.dof) : std::string("∞"),
        general(u.floor_dph),
        u.random_walk_dominated ? " [rate random walk dominates: the interval is less sure]" : "");
  } else if (!v.model_error.empty()) {
    out += fmt::format("  noise model: {}\n", v.model_error);
  }
  return out;
}

// One summary row per curve (several soaks / runs / files): the three terms.
struct AllanSummaryRow {
  std::string who;
  analysis::AllanNoiseTerms noise;
};

std::string allan_summary(const std::vector<AllanSummaryRow>& rows) {
  std::vector<std::vector<std::string>> cells;
  for (const auto& r : rows) {
    const auto& bi = r.noise.bias_instability_dph;
    std::string bi_text = noise_term_short(bi, "°/h");
    if (bi.tau_s && bi.kind != analysis::NoiseTermKind::kUnavailable) {
      const std::string_view rel = bi.tau_relation == ">="   ? "≥"
                                   : bi.tau_relation == "<=" ? "≤"
                                                             : "=";
      bi_text += fmt::format(" (τ {} {} s)", rel, general(*bi.tau_s));
    }
    cells.push_back({r.who, noise_term_short(r.noise.angle_random_walk_dprh, "°/√h"), bi_text,
                     noise_term_short(r.noise.rate_random_walk_dphprh, "°/h/√h")});
  }
  return "Summary (\"< x\": upper bound, the curve does not reach the term's region; "
         "—: unavailable, see the curve's own lines)\n" +
         table({"curve", "ARW", "bias instability", "RRW"}, cells, 1, "  ");
}

int cmd_allan(const Parsed& p) {
  auto in = open_input(p, RunsNeeded::kOptional);
  if (!in) return fail(in.error().message, kExitInput);
  // --taus, else the run's stored [analysis] allan_taus, else octave.
  auto tau_set = [&p](const RunConfig& cfg) -> Result<analysis::TauSet> {
    const std::string text = p.taus.value_or(cfg.allan_taus.value_or("octave"));
    auto taus = analysis::parse_tau_set(text);
    if (!taus) {
      return Error::Permanent(fmt::format("{} \"{}\": {}", p.taus ? "--taus" : "stored allan_taus",
                                          text, taus.error().message));
    }
    return taus;
  };
  if (auto check = tau_set({}); !check) return fail(check.error().message, kExitInput);
  json out = json::array();
  std::string text;
  std::vector<AllanSummaryRow> summary;
  if (in->db) {
    if (auto st = check_choice(p, *in->db); !st) return fail(st.error().message, kExitInput);
    auto& db = in->db->db;
    for (const auto& run : in->db->runs) {
      auto taus = tau_set(read_run_config(run));
      if (!taus) return fail(taus.error().message, kExitInput);
      const std::string taus_name(analysis::to_string(*taus));
      auto soaks = calibration::soak_windows(db, run.id);
      if (!soaks)
        return fail(fmt::format("run {}: {}", run.id, soaks.error().message), kExitFailed);
      if (soaks->empty()) {
        text += fmt::format("run {}: no completed soak with an acquisition window\n", run.id);
      }
      auto axes = chosen_axes(p, db, run.id);
      if (!axes) return fail(axes.error().message, kExitFailed);
      const analysis::QualityRules rules = quality_rules_of(run);
      for (const auto& soak : *soaks) {
        for (const auto& axis : *axes) {
          auto rec = calibration::soak_allan(db, soak, *taus, axis, rules);
          if (!rec) return fail(rec.error().message, kExitFailed);
          const AllanView v = view_of(*rec);
          json j = soak_json(soak, axis, rec->t_from_s, rec->t_to_s);
          j.update(allan_json(v, taus_name));
          j["quality"] = quality_json(rec->quality);
          out.push_back(std::move(j));
          // "run 3 segment 2" (one unnamed gyro), else with its DUT axis.
          const std::string who =
              axis.dut_serial.empty()
                  ? fmt::format("run {} segment {}", run.id, soak.segment_index + 1)
                  : fmt::format("run {} segment {} {}", run.id, soak.segment_index + 1,
                                axis.name());
          if (rec->quality.flagged()) {
            text += fmt::format("{}: FLAGGED: {}\n", who, fmt::join(rec->quality.reasons, "; "));
          }
          summary.push_back({fmt::format("{} ({:g} °C)", who, soak.setpoint_c), v.noise});
          text += allan_text(fmt::format("{} (soak {:g} °C), samples {}–{} s", who, soak.setpoint_c,
                                         general(rec->t_from_s), general(rec->t_to_s)),
                             v, taus_name);
        }
      }
    }
  } else {
    const analysis::TauSet taus = *tau_set({});
    const std::string taus_name(analysis::to_string(taus));
    for (const auto& w : in->csv) {
      auto a = analysis::allan_deviation(w.t_s, w.rate_dph, {.taus = taus});
      if (!a) return fail(fmt::format("{}: {}", w.source, a.error().message), kExitFailed);
      const AllanView v = view_of(*a);
      json j = {{"source", w.source}};
      j.update(allan_json(v, taus_name));
      out.push_back(std::move(j));
      summary.push_back({w.source, v.noise});
      text += allan_text(w.source, v, taus_name);
    }
  }
  if (p.json) {
    std::cout << out.dump(2) << "\n";
  } else {
    // Several curves (a campaign, several soaks or files): a summary after them.
    if (summary.size() > 1) text += "\n" + allan_summary(summary);
    std::cout << (text.empty() ? "no Allan deviation\n" : text);
  }
  return 0;
}

// ---------------------------------------------------------------- per DUT axis

// A command over several runs, once per DUT axis (common_axes): `one`
// prints its text and hands back its JSON object, which gets "dut_serial"
// and "axis". Text: a title before each block when the runs name their
// DUTs. JSON: the object for one DUT axis, an array of them for several.
// The coefficient files are for one DUT axis: with several, --dut and
// --axis must choose one.
using PerStream = int (*)(const Parsed&, Input&, const calibration::AnalysedAxis*, json&);

int for_each_stream(const Parsed& p, RunsNeeded needed, PerStream one) {
  auto in = open_input(p, needed);
  if (!in) return fail(in.error().message, kExitInput);
  if (!in->db) {
    json j;
    const int code = one(p, *in, nullptr, j);
    if (code == 0 && p.json) std::cout << j.dump(2) << "\n";
    return code;
  }
  std::vector<std::string> notes;
  auto streams = common_axes(p, *in->db, notes);
  if (!streams) return fail(streams.error().message, kExitInput);
  if (streams->size() > 1 && (!p.c_header.empty() || !p.coefficients_json.empty())) {
    std::vector<std::string> names;
    for (const auto& a : *streams) names.push_back(a.name());
    return fail(fmt::format("--c-header and --coefficients-json are for one DUT axis; the runs "
                            "have {} ({}): choose one with --dut and --axis",
                            streams->size(), fmt::join(names, ", ")),
                kExitInput);
  }
  for (const auto& n : notes) (p.json ? std::cerr : std::cout) << n << "\n";
  json all = json::array();
  for (std::size_t i = 0; i < streams->size(); ++i) {
    const auto& a = (*streams)[i];
    if (!p.json && !a.dut_serial.empty()) {
      std::cout << (i == 0 ? "" : "\n") << "== " << stream_title(a) << "\n";
    }
    json j;
    if (const int code = one(p, *in, &a, j); code != 0) return code;
    j["dut_serial"] = a.dut_serial;
    j["axis"] = a.axis;
    all.push_back(std::move(j));
  }
  if (p.json) std::cout << (all.size() == 1 ? all[0] : all).dump(2) << "\n";
  return 0;
}

// ---------------------------------------------------------------- fit

json coefficient_map(const std::map<std::string, double>& m) {
  json j = json::object();
  for (const auto& [k, v] : m) j[k] = num(v);
  return j;
}

// Unit of a coefficient in the physical form.
// Coefficients in a fixed order: intercept, T1.., R1.., G1...
template <class V>
std::vector<std::string> ordered_keys(const std::map<std::string, V>& m) {
  std::vector<std::string> keys;
  if (m.count("intercept")) keys.push_back("intercept");
  for (const char* family : {"T", "R", "G"}) {
    for (int i = 1; i <= 4; ++i) {
      const std::string k = family + std::to_string(i);
      if (m.count(k)) keys.push_back(k);
    }
  }
  for (const auto& kv : m) {
    if (std::find(keys.begin(), keys.end(), kv.first) == keys.end()) keys.push_back(kv.first);
  }
  return keys;
}

int fit_one(const Parsed& p, Input& input, const calibration::AnalysedAxis* stream,
            json& json_out) {
  Input* in = &input;
  const RunConfig cfg = first_run_config(*in);
  auto spec = model_spec(p, cfg);
  if (!spec) return fail(spec.error().message, kExitInput);
  auto form = analysis::parse_drift_model_form(p.form);
  if (!form) return fail("--form: " + form.error().message, kExitInput);
  auto options = fit_options(p, cfg);
  if (!options) return fail(options.error().message, kExitInput);
  const auto bin = bin_s_of(p, cfg);
  if (!bin) return fail(bin.error().message, kExitInput);
  const double bin_s = *bin;

  auto set = load_series(*in, bin_s, stream);
  if (!set) return fail(set.error().message, kExitFailed);
  std::string what =
      in->db ? fmt::format("run{} {}", in->db->runs.size() == 1 ? "" : "s", join_ids(in->db->ids()))
             : fmt::format("{}", fmt::join(set->names, ", "));
  if (stream != nullptr && !stream->dut_serial.empty()) what += " (" + stream->name() + ")";
  auto fit = analysis::fit_drift_model(set->series, *spec, *form, *options);
  if (!fit) {
    return fail(fmt::format("fit of {} to {} ({} form): {}", what, analysis::to_string(*spec),
                            analysis::to_string(*form), fit.error().message),
                kExitFailed);
  }
  json inputs = set->inputs;
  inputs["derivative_window_s"] = options->derivative_window_s;
  inputs["l0_window_s"] = options->l0_window_s;
  json l0s = json::array();
  for (double l : fit->l0_per_series_dph) l0s.push_back(num(l));
  const std::string warning = analysis::near_zero_warning(*fit);
  const json out = {{"model", analysis::to_string(fit->spec)},
                    {"form", analysis::to_string(fit->form)},
                    {"form_label", std::string(analysis::form_label(fit->form))},
                    {"near_zero", analysis::near_zero_coefficients(*fit)},
                    {"warnings", warning.empty() ? json::array() : json::array({warning})},
                    {"coefficients", coefficient_map(fit->coefficients)},
                    {"standard_errors", coefficient_map(fit->std_errors)},
                    {"residual_std_dph", num(fit->residual_std_dph)},
                    {"r_squared", num(fit->r_squared)},
                    {"n", fit->n},
                    {"parameters", fit->parameters},
                    {"l0_dph", num(fit->l0_dph)},
                    {"l0_per_run_dph", l0s},
                    {"condition_estimate", num(fit->condition_estimate)},
                    {"inputs", inputs}};

  // Its quality: a flagged fit's C header only with --force.
  const storage::ResultQuality quality = calibration::fit_quality(
      *fit, set->series, set->coverage,
      in->db ? quality_rules_of(in->db->runs.front()) : analysis::QualityRules{});
  json with_quality = out;
  with_quality["quality"] = quality_json(quality);
  const auto info = export_info(*in, cfg, options->l0_window_s, stream);
  if (quality.flagged() && !p.c_header.empty() && !p.force) {
    Parsed json_only = p;
    json_only.c_header.clear();
    if (int code =
            write_exports(json_only, [&] { return analysis::drift_fit_json(*fit, info); }, {});
        code != 0) {
      return code;
    }
    return fail(
        fmt::format("--c-header {}: not written: the fit is flagged: {} (--force writes it, "
                    "marked as forced)",
                    p.c_header, fmt::join(quality.reasons, "; ")),
        kExitFailed);
  }
  if (int code = write_exports(
          p, [&] { return analysis::drift_fit_json(*fit, info); },
          [&] {
            return calibration::forced_header_comment(quality) +
                   analysis::drift_fit_c_header(*fit, info);
          });
      code != 0) {
    return code;
  }
  json_out = with_quality;
  if (p.json) return 0;
  std::cout << fmt::format("model {}, {}, {}: {} points ({:g} s bins)\n",
                           analysis::to_string(fit->spec), analysis::form_label(fit->form), what,
                           fit->n, bin_s);
  if (fit->form == analysis::DriftModelForm::kPaper) {
    std::cout << fmt::format("L0 {} °/h (mean rate over the first {:g} s", fixed(fit->l0_dph, 4),
                             options->l0_window_s);
    if (fit->l0_per_series_dph.size() > 1) {
      std::vector<std::string> each;
      for (double l : fit->l0_per_series_dph) each.push_back(fixed(l, 4));
      std::cout << fmt::format("; per run {}", fmt::join(each, ", "));
    }
    std::cout << ")\n";
  }
  std::vector<std::vector<std::string>> rows;
  for (const auto& k : ordered_keys(fit->coefficients)) {
    const auto se = fit->std_errors.find(k);
    rows.push_back({k, analysis::coefficient_unit(k), sci(fit->coefficients.at(k)),
                    se == fit->std_errors.end() ? kDash : sci(se->second)});
  }
  std::cout << table({"term", "unit", "coefficient", "std error"}, rows, 2);
  std::cout << fmt::format("residual std {} °/h, R² {}, condition {}\n",
                           fixed(fit->residual_std_dph, 4), fixed(fit->r_squared, 6),
                           general(fit->condition_estimate));
  if (!warning.empty()) std::cout << "warning: " << warning << "\n";
  if (quality.coverage) {
    std::cout << fmt::format("coverage {:.2f} % of the samples expected, longest gap {} s\n",
                             *quality.coverage * 100.0, general(quality.longest_gap_s.value_or(0)));
  }
  if (quality.flagged()) {
    std::cout << "FLAGGED: " << fmt::format("{}", fmt::join(quality.reasons, "; ")) << "\n";
  }
  if (!p.coefficients_json.empty()) std::cout << "wrote " << p.coefficients_json << "\n";
  if (!p.c_header.empty()) {
    std::cout << "wrote " << p.c_header << (quality.flagged() ? " (forced: flagged)" : "") << "\n";
  }
  return 0;
}

int cmd_fit(const Parsed& p) { return for_each_stream(p, RunsNeeded::kRequired, fit_one); }

// ---------------------------------------------------------------- compare

json compensated_json(const std::optional<analysis::CompensatedStats>& s) {
  if (!s) return nullptr;
  return {{"n", s->n}, {"mean_dph", num(s->mean_dph)}, {"std_dph", num(s->std_dph)}};
}

int compare_one(const Parsed& p, Input& input, const calibration::AnalysedAxis* stream,
                json& json_out) {
  Input* in = &input;
  const RunConfig cfg = first_run_config(*in);
  analysis::ComparisonOptions options;
  options.max_order = p.max_order;
  options.g_order = p.g_order;
  options.r_order = p.r_order;
  auto form = analysis::parse_drift_model_form(p.form);
  if (!form) return fail("--form: " + form.error().message, kExitInput);
  options.form = *form;
  auto fo = fit_options(p, cfg);
  if (!fo) return fail(fo.error().message, kExitInput);
  options.fit = *fo;
  const int smooth = p.smooth_points.value_or(
      cfg.compare_smooth_points.value_or(static_cast<int>(options.smooth_points)));
  if (smooth < 1) return fail(fmt::format("--smooth-points {}: must be >= 1", smooth), kExitInput);
  options.smooth_points = static_cast<std::size_t>(smooth);
  std::string why;
  if (!options.is_valid(&why)) return fail(as_option(why), kExitInput);
  const auto bin = bin_s_of(p, cfg);
  if (!bin) return fail(bin.error().message, kExitInput);
  const double bin_s = *bin;
  auto set = load_series(*in, bin_s, stream);
  if (!set) return fail(set.error().message, kExitFailed);
  auto cmp = analysis::compare_models(set->series, options);
  if (!cmp) return fail("comparison: " + cmp.error().message, kExitFailed);

  json inputs = set->inputs;
  inputs["derivative_window_s"] = options.fit.derivative_window_s;
  inputs["l0_window_s"] = options.fit.l0_window_s;
  inputs["smooth_points"] = options.smooth_points;
  json cells = json::array();
  for (const auto& c : cmp->cells) {
    cells.push_back({{"terms", analysis::to_string(c.terms)},
                     {"order", c.order},
                     {"model", analysis::to_string(c.spec)},
                     {"in_sample", compensated_json(c.in_sample)},
                     {"in_sample_error", c.in_sample ? json(nullptr) : json(c.in_sample_error)},
                     {"cross_validated", compensated_json(c.cross_validated)},
                     {"cross_validated_error",
                      c.cross_validated ? json(nullptr) : json(c.cross_validated_error)}});
  }
  const json out = {{"runs", cmp->runs},
                    {"form", analysis::to_string(options.form)},
                    {"smooth_points", options.smooth_points},
                    {"smoothing", analysis::smoothing_label(options.smooth_points)},
                    {"max_order", options.max_order},
                    {"g_order", options.g_order},
                    {"r_order", options.r_order},
                    {"none", compensated_json(cmp->none)},
                    {"cells", cells},
                    {"inputs", inputs}};
  json_out = out;
  if (p.json) return 0;
  std::cout << fmt::format(
      "Compensated gyro output, {} form, {} {} ({:g} s bins), std {}. in-sample: one fit on "
      "all, applied to all (the paper); LORO: each run compensated by a fit on the others.\n",
      analysis::to_string(options.form), cmp->runs,
      in->db ? (cmp->runs == 1 ? "run" : "runs") : (cmp->runs == 1 ? "file" : "files"), bin_s,
      analysis::smoothing_label(options.smooth_points));
  const std::pair<analysis::TermSet, const char*> sets[] = {
      {analysis::TermSet::kT, "Table II — temperature T"},
      {analysis::TermSet::kTG, "Table III — T + gradient ΔT"},
      {analysis::TermSet::kTGR, "Table IV — T + ΔT + rate dT/dt"}};
  const std::string none_mean = fixed(cmp->none.mean_dph, 4),
                    none_std = fixed(cmp->none.std_dph, 4);
  std::string loro_single_run;
  for (const auto& [terms, title] : sets) {
    std::vector<std::vector<std::string>> rows;
    rows.push_back({"none", "", none_mean, none_std, none_mean, none_std});
    std::vector<std::string> notes;
    for (const auto& c : cmp->cells) {
      if (c.terms != terms) continue;
      const std::string label = c.order == 1 ? "linear" : fmt::format("{} order", c.order);
      auto cell = [&](const std::optional<analysis::CompensatedStats>& s, const std::string& err,
                      const char* kind) -> std::pair<std::string, std::string> {
        if (s) return {fixed(s->mean_dph, 4), fixed(s->std_dph, 4)};
        if (cmp->runs < 2 && std::string_view(kind) == "LORO") {
          loro_single_run = err;  // the same reason for every cell: said once below
        } else {
          notes.push_back(fmt::format("  {} {}: {}", analysis::to_string(c.spec), kind, err));
        }
        return {kDash, kDash};
      };
      const auto [im, is] = cell(c.in_sample, c.in_sample_error, "in-sample");
      const auto [cm, cs] = cell(c.cross_validated, c.cross_validated_error, "LORO");
      rows.push_back({label, analysis::to_string(c.spec), im, is, cm, cs});
    }
    std::cout << "\n" << title << "\n";
    std::cout << table({"method", "model", "mean °/h", "std °/h", "LORO mean °/h", "LORO std °/h"},
                       rows, 2);
    for (const auto& n : notes) std::cout << n << "\n";
  }
  if (!loro_single_run.empty()) std::cout << "\nLORO: " << loro_single_run << "\n";
  return 0;
}

int cmd_compare(const Parsed& p) { return for_each_stream(p, RunsNeeded::kRequired, compare_one); }

// ---------------------------------------------------------------- start-model

int start_model_one(const Parsed& p, Input& input, const calibration::AnalysedAxis* stream,
                    json& json_out) {
  Input* in = &input;
  const RunConfig cfg = first_run_config(*in);
  analysis::StartTemperatureOptions options;
  if (p.model || cfg.model) {
    auto spec = model_spec(p, cfg);
    if (!spec) return fail(spec.error().message, kExitInput);
    options.spec = *spec;
  }
  auto form = analysis::parse_drift_model_form(p.form);
  if (!form) return fail("--form: " + form.error().message, kExitInput);
  options.form = *form;
  auto fo = fit_options(p, cfg);
  if (!fo) return fail(fo.error().message, kExitInput);
  options.fit = *fo;
  if (p.t0_window_s) options.t0_window_s = *p.t0_window_s;
  std::string why;
  if (!options.is_valid(&why)) return fail(as_option(why), kExitInput);
  if (p.t0_c && !std::isfinite(*p.t0_c)) return fail("--t0: must be a finite °C", kExitInput);
  const auto bin = bin_s_of(p, cfg);
  if (!bin) return fail(bin.error().message, kExitInput);
  const double bin_s = *bin;
  auto set = load_series(*in, bin_s, stream);
  if (!set) return fail(set.error().message, kExitFailed);
  auto model = analysis::fit_start_temperature_model(set->series, options);
  if (!model) return fail(model.error().message, kExitFailed);
  std::optional<analysis::StartTemperatureCoefficients> at;
  if (p.t0_c) {
    auto c = analysis::coefficients_at(*model, *p.t0_c);
    if (!c)
      return fail(fmt::format("at T0 = {:g} °C: {}", *p.t0_c, c.error().message), kExitFailed);
    at = std::move(*c);
  }

  json inputs = set->inputs;
  inputs["derivative_window_s"] = model->derivative_window_s;
  inputs["l0_window_s"] = model->l0_window_s;
  inputs["t0_window_s"] = model->t0_window_s;
  json runs = json::array();
  for (std::size_t i = 0; i < model->t0_c.size(); ++i) {
    json r = in->db ? json{{"run_id", in->db->runs.at(i).id}} : json{{"source", set->names.at(i)}};
    r["t0_c"] = num(model->t0_c[i]);
    r["coefficients"] =
        i < model->run_coefficients.size() ? coefficient_map(model->run_coefficients[i]) : json();
    runs.push_back(std::move(r));
  }
  json cubic = json::object(), resid = json::object();
  for (const auto& [k, a] : model->cubic) {
    cubic[k] = {num(a[0]), num(a[1]), num(a[2]), num(a[3])};
  }
  for (const auto& [k, s] : model->cubic_residual_std) resid[k] = num(s);
  json out = {{"model", analysis::to_string(model->spec)},
              {"form", analysis::to_string(model->form)},
              {"runs", runs},
              {"cubic", cubic},
              {"cubic_residual_std", resid},
              {"inputs", inputs}};
  if (at) {
    out["at_t0"] = {{"t0_c", num(at->t0_c)},
                    {"extrapolated", at->extrapolated},
                    {"coefficients", coefficient_map(at->fit.coefficients)}};
  }

  const auto info = export_info(*in, cfg, model->l0_window_s, stream);
  if (int code = write_exports(
          p, [&] { return analysis::start_model_json(*model, info); },
          [&] { return analysis::start_model_c_header(*model, info); });
      code != 0) {
    return code;
  }
  json_out = out;
  if (p.json) return 0;
  std::cout << fmt::format(
      "start-temperature model (paper eq. 3), {} {} form, from {} {}: each coefficient "
      "a(T0) = A0 + A1·T0 + A2·T0² + A3·T0³\n",
      analysis::to_string(model->spec), analysis::to_string(model->form), model->t0_c.size(),
      in->db ? "runs" : "files");
  std::vector<std::vector<std::string>> rows;
  for (std::size_t i = 0; i < model->t0_c.size(); ++i) {
    rows.push_back({set->names.at(i), fixed(model->t0_c[i], 2)});
  }
  std::cout << table({"input", "T0 °C"}, rows, 1);
  rows.clear();
  for (const auto& k : ordered_keys(model->cubic)) {
    const auto& a = model->cubic.at(k);
    const auto r = model->cubic_residual_std.find(k);
    rows.push_back({k, sci(a[0]), sci(a[1]), sci(a[2]), sci(a[3]),
                    r == model->cubic_residual_std.end() ? kDash : sci(r->second)});
  }
  std::cout << table({"term", "A0", "A1 /°C", "A2 /°C²", "A3 /°C³", "resid std"}, rows, 1);
  if (at) {
    std::cout << fmt::format(
        "coefficients at T0 = {:g} °C{}:\n", at->t0_c,
        at->extrapolated ? " (extrapolated: outside the fitted T0 range)" : "");
    rows.clear();
    for (const auto& k : ordered_keys(at->fit.coefficients)) {
      rows.push_back({k, analysis::coefficient_unit(k), sci(at->fit.coefficients.at(k))});
    }
    std::cout << table({"term", "unit", "coefficient"}, rows, 2, "  ");
  }
  if (!p.coefficients_json.empty()) std::cout << "wrote " << p.coefficients_json << "\n";
  if (!p.c_header.empty()) std::cout << "wrote " << p.c_header << "\n";
  return 0;
}

int cmd_start_model(const Parsed& p) {
  return for_each_stream(p, RunsNeeded::kRequired, start_model_one);
}

// ---------------------------------------------------------------- scale-factor

// The points of one temperature (all of them when the file has no
// temperature_c column), with their file lines.
struct SfGroup {
  std::optional<double> temperature_c;
  std::vector<analysis::RatePoint> points;
  std::vector<std::size_t> lines;
};

json sf_fit_json(const SfGroup& g, const analysis::ScaleFactorFit& f) {
  json residuals = json::array();
  for (std::size_t i = 0; i < g.points.size(); ++i) {
    const auto& pt = g.points[i];
    const double r = f.residuals_dps[i];
    residuals.push_back(
        {{"line", g.lines[i]},
         {"rate_dps", num(pt.rate_dps)},
         {"output_dps", num(pt.output_dps)},
         {"repetition", pt.repetition},
         {"residual_dps", num(r)},
         {"residual_ppm",
          pt.rate_dps == 0 ? json(nullptr) : num(r / std::fabs(f.k * pt.rate_dps) * 1e6)}});
  }
  json reps = json::array();
  for (const auto& r : f.repetitions) {
    reps.push_back({{"repetition", r.repetition},
                    {"points", r.points},
                    {"k", num(r.k)},
                    {"bias_dps", num(r.bias_dps)}});
  }
  return {{"temperature_c", g.temperature_c ? num(*g.temperature_c) : json(nullptr)},
          {"points", f.points},
          {"distinct_rates", f.distinct_rates},
          {"full_scale_dps", num(f.full_scale_dps)},
          {"k", num(f.k)},
          {"k_std_error", num(f.k_std_error)},
          {"bias_dps", num(f.bias_dps)},
          {"bias_std_error_dps", num(f.bias_std_error_dps)},
          {"bias_dph", num(f.bias_dph)},
          {"bias_std_error_dph", num(f.bias_std_error_dph)},
          {"residual_std_dps", num(f.residual_std_dps)},
          {"nonlinearity_ppm", num(f.nonlinearity_ppm)},
          {"nonlinearity_rate_dps", num(g.points[f.nonlinearity_point].rate_dps)},
          {"nonlinearity_line", g.lines[f.nonlinearity_point]},
          {"nonlinearity_fs_ppm", num(f.nonlinearity_fs_ppm)},
          {"k_positive", num(f.k_positive)},
          {"k_negative", num(f.k_negative)},
          {"asymmetry_bias_dps", num(f.asymmetry_bias_dps)},
          {"asymmetry_ppm", num(f.asymmetry_ppm)},
          {"repeatability_ppm", num(f.repeatability_ppm)},
          {"repetitions", reps},
          {"residuals", residuals}};
}

std::string sf_fit_text(const SfGroup& g, const analysis::ScaleFactorFit& f) {
  std::string t;
  t += fmt::format("K  {} ± {} (standard error)\n", fixed(f.k, 9), sci(f.k_std_error));
  t += fmt::format("B  {} °/s ± {} = {} °/h ± {}\n", fixed(f.bias_dps, 6),
                   fixed(f.bias_std_error_dps, 6), fixed(f.bias_dph, 3),
                   fixed(f.bias_std_error_dph, 3));
  t += fmt::format("residual std {} °/s\n", sci(f.residual_std_dps));
  t += fmt::format(
      "nonlinearity {} ppm of K·Ω (largest at {:g} °/s, line {}); {} ppm of full scale "
      "({:g} °/s)\n",
      fixed(f.nonlinearity_ppm, 1), g.points[f.nonlinearity_point].rate_dps,
      g.lines[f.nonlinearity_point], fixed(f.nonlinearity_fs_ppm, 1), f.full_scale_dps);
  if (f.asymmetry_ppm) {
    t += fmt::format("asymmetry {} ppm (K+ {}, K- {}, bias {} °/s)\n", fixed(*f.asymmetry_ppm, 1),
                     fixed(f.k_positive.value_or(NAN), 9), fixed(f.k_negative.value_or(NAN), 9),
                     fixed(f.asymmetry_bias_dps.value_or(NAN), 6));
  } else {
    t += fmt::format("asymmetry {} (needs rates in both directions and 3 distinct rates)\n", kDash);
  }
  if (f.repeatability_ppm) {
    std::vector<std::string> ks;
    for (const auto& r : f.repetitions)
      ks.push_back(fmt::format("{}: {}", r.repetition, fixed(r.k, 9)));
    t += fmt::format("repeatability {} ppm over {} repetitions (K {})\n",
                     fixed(*f.repeatability_ppm, 2), f.repetitions.size(), fmt::join(ks, ", "));
  } else {
    t += fmt::format("repeatability {} (needs 2 repetitions with 2 distinct rates each)\n", kDash);
  }
  std::vector<std::vector<std::string>> rows;
  for (std::size_t i = 0; i < g.points.size(); ++i) {
    const auto& pt = g.points[i];
    const double r = f.residuals_dps[i];
    rows.push_back({std::to_string(g.lines[i]), general(pt.rate_dps), fixed(pt.output_dps, 6),
                    std::to_string(pt.repetition), sci(r),
                    pt.rate_dps == 0 ? kDash : fixed(r / std::fabs(f.k * pt.rate_dps) * 1e6, 1)});
  }
  t +=
      table({"line", "rate °/s", "output °/s", "rep", "residual °/s", "ppm of K·Ω"}, rows, 0, "  ");
  return t;
}

int cmd_scale_factor(const Parsed& p) {
  if (p.sf_order != 1 && p.sf_order != 2) {
    return fail(fmt::format("--order {}: must be 1 or 2", p.sf_order), kExitInput);
  }
  auto csv = analysis::read_rate_points_csv(p.sf_csv);
  if (!csv) return fail(csv.error().message, kExitInput);

  // One group per distinct temperature_c value, in increasing temperature.
  std::vector<SfGroup> groups;
  if (csv->has_temperature) {
    std::map<double, SfGroup> by_t;
    for (std::size_t i = 0; i < csv->points.size(); ++i) {
      SfGroup& g = by_t[csv->points[i].temperature_c];
      g.temperature_c = csv->points[i].temperature_c;
      g.points.push_back(csv->points[i]);
      g.lines.push_back(csv->lines[i]);
    }
    for (auto& [t, g] : by_t) groups.push_back(std::move(g));
  } else {
    groups.push_back({std::nullopt, csv->points, csv->lines});
  }

  json fits = json::array();
  std::string text = fmt::format(
      "scale factor from {}: {} points{}\n", csv->source, csv->points.size(),
      groups.size() > 1 ? fmt::format(" at {} temperatures", groups.size()) : std::string());
  std::vector<analysis::ScaleFactorAtTemperature> plateaus;
  for (const SfGroup& g : groups) {
    auto fit = analysis::fit_scale_factor(g.points);
    const std::string where =
        g.temperature_c ? fmt::format("{} at {:g} °C", csv->source, *g.temperature_c) : csv->source;
    if (!fit) return fail(fmt::format("{}: {}", where, fit.error().message), kExitFailed);
    fits.push_back(sf_fit_json(g, *fit));
    text += "\n";
    text += g.temperature_c ? fmt::format("at {:g} °C: ", *g.temperature_c) : std::string();
    text += fmt::format("{} points, {} distinct rates, full scale {:g} °/s\n", fit->points,
                        fit->distinct_rates, fit->full_scale_dps);
    text += sf_fit_text(g, *fit);
    if (g.temperature_c) plateaus.push_back({*g.temperature_c, fit->k, fit->bias_dph});
  }

  json over = nullptr;
  if (plateaus.size() > 1) {
    auto tf = analysis::fit_scale_factor_over_temperature(plateaus, p.sf_order);
    if (!tf) {
      return fail(fmt::format("{}: {}", csv->source, tf.error().message), kExitFailed);
    }
    json plateau_rows = json::array();
    std::vector<std::vector<std::string>> rows;
    for (std::size_t i = 0; i < plateaus.size(); ++i) {
      plateau_rows.push_back({{"temperature_c", num(plateaus[i].temperature_c)},
                              {"k", num(plateaus[i].k)},
                              {"bias_dph", num(plateaus[i].bias_dph)},
                              {"k_residual", num(tf->k_residuals[i])},
                              {"bias_residual_dph", num(tf->bias_residuals_dph[i])}});
      rows.push_back({general(plateaus[i].temperature_c), fixed(plateaus[i].k, 9),
                      fixed(plateaus[i].bias_dph, 3), sci(tf->k_residuals[i]),
                      sci(tf->bias_residuals_dph[i])});
    }
    json kc = json::array(), bc = json::array();
    for (double c : tf->k_coefficients) kc.push_back(num(c));
    for (double c : tf->bias_coefficients_dph) bc.push_back(num(c));
    over = {
        {"order", tf->order},
        {"temperature_mean_c", num(tf->temperature_mean_c)},
        {"k_coefficients", kc},
        {"bias_coefficients_dph", bc},
        {"k_at_mean", num(tf->k_at_mean)},
        {"sf_temperature_coefficient_ppm_per_c", num(tf->sf_temperature_coefficient_ppm_per_c)},
        {"bias_temperature_coefficient_dph_per_c", num(tf->bias_temperature_coefficient_dph_per_c)},
        {"plateaus", plateau_rows}};
    std::vector<std::string> kcs, bcs;
    for (double c : tf->k_coefficients) kcs.push_back(sci(c));
    for (double c : tf->bias_coefficients_dph) bcs.push_back(sci(c));
    text += fmt::format("\nover temperature: order {} in T − T̄, T̄ = {:g} °C\n", tf->order,
                        tf->temperature_mean_c);
    text +=
        fmt::format("K(T̄) {}, scale-factor temperature coefficient {} ppm/°C\n",
                    fixed(tf->k_at_mean, 9), fixed(tf->sf_temperature_coefficient_ppm_per_c, 3));
    text += fmt::format("B(T̄) {} °/h, bias temperature coefficient {} (°/h)/°C\n",
                        fixed(tf->bias_coefficients_dph[0], 3),
                        fixed(tf->bias_temperature_coefficient_dph_per_c, 4));
    text += fmt::format("K coefficients (per °C^j) {}; B coefficients (°/h per °C^j) {}\n",
                        fmt::join(kcs, ", "), fmt::join(bcs, ", "));
    text += table({"T °C", "K", "B °/h", "K residual", "B residual °/h"}, rows, 0, "  ");
  }

  if (p.json) {
    const json out = {{"source", csv->source},
                      {"points", csv->points.size()},
                      {"fits", fits},
                      {"over_temperature", over}};
    std::cout << out.dump(2) << "\n";
  } else {
    std::cout << text;
  }
  return 0;
}

}  // namespace

struct AnalysisCommands::Parsed : Args {};

// ---------------------------------------------------------------- registration

AnalysisCommands::AnalysisCommands(CLI::App& app) : parsed_(std::make_unique<Parsed>()) {
  Parsed& p = *parsed_;
  auto input = [&p](CLI::App* cmd, bool several_csv) {
    auto* db = cmd->add_option("--db", p.db_path, "station database file");
    cmd->add_option("--config", p.config_path,
                    "station config: its [storage] db is the database (instead of --db)")
        ->excludes(db);
    cmd->add_option("--run", p.run, "one run id");
    cmd->add_option("--runs", p.runs, "run ids: \"1,2,5\", ranges \"3-7\"");
    cmd->add_option("--csv", p.csv,
                    several_csv ? "CSV file(s), one run each" : "CSV file(s), one window each");
    cmd->add_flag("--json", p.json, "JSON output");
    cmd->add_option("--dut", p.duts,
                    "serial of a DUT to analyse (repeat for more; default: every DUT of the runs)")
        ->allow_extra_args(false);
    cmd->add_option("--axis", p.axes,
                    "axis to analyse, x, y or z (repeat for more; default: every analysed axis)")
        ->allow_extra_args(false);
    return cmd;
  };
  auto fit_opts = [&p](CLI::App* cmd) {
    cmd->add_option("--form", p.form,
                    "centered (intercept, unbiased; the default) or paper (the paper's form: "
                    "y = L - L0, no intercept; biased when runs start away from 0 °C)")
        ->capture_default_str();
    cmd->add_option("--derivative-window-s", p.derivative_window_s,
                    "smoothing-derivative window, s (default: the run's config, else 60)");
    cmd->add_option("--l0-window-s", p.l0_window_s,
                    "L0 = mean rate over the first this many s (default: config, else 120)");
    cmd->add_option("--bin-s", p.bin_s, "analysis bin, s (default: config, else 1)");
  };
  auto exports = [&p](CLI::App* cmd) {
    cmd->add_option("--coefficients-json", p.coefficients_json, "write the coefficients as JSON");
    cmd->add_option("--c-header", p.c_header, "write the coefficients as a C header");
  };

  p.stats = input(app.add_subcommand("stats", "Table I rows per soak window (or CSV file)"), false);
  p.stats->add_option("--bin-s", p.bin_s, "analysis bin, s (default: the run's config, else 1)");
  p.stats->add_option("--ma-window", p.ma_window,
                      "moving-average points (default: config, else 101)");
  p.stats->add_option("--earth-rate-dph", p.earth_rate_dph, "Earth rate to remove, °/h");
  p.stats->add_option("--latitude", p.latitude_deg, "latitude, degrees (default: the run's)");
  p.stats->add_option("--orientation", p.orientation, "axis: up, down or horizontal");
  p.stats
      ->add_option("--heading-deg", p.heading_deg,
                   "a horizontal axis's azimuth, degrees clockwise from true north (Earth "
                   "rate Ω·cos φ·cos h; without it 0, the axis taken as east-west)")
      ->check(CLI::Range(-360.0, 360.0));
  p.stats->add_flag("--stored", p.stored, "print the rows the daemon stored (no recomputation)");
  p.stats->add_flag("--by-setpoint", p.by_setpoint,
                    "one row per set point: mean and std of each column over its repetitions");

  p.allan = input(app.add_subcommand("allan", "Allan deviation and noise terms per soak"), false);
  p.allan->add_option("--taus", p.taus, "octave, decade or all (default: config, else octave)");

  p.fit = input(app.add_subcommand("fit", "drift-model fit (paper eq. 1)"), true);
  p.fit->add_option("--model", p.model, "e.g. T4+R1+G1 (default: the run's config, else that)");
  fit_opts(p.fit);
  exports(p.fit);
  p.fit->add_flag("--force", p.force,
                  "write the C header even when the fit is flagged (docs/analysis.md \"Result "
                  "quality\"); the header then says so and why");

  p.compare =
      input(app.add_subcommand("compare", "the paper's Tables II-IV, in-sample and LORO"), true);
  p.compare->add_option("--max-order", p.max_order, "T orders 1..N")->capture_default_str();
  p.compare->add_option("--g-order", p.g_order, "order of the gradient ΔT")->capture_default_str();
  p.compare->add_option("--r-order", p.r_order, "order of dT/dt")->capture_default_str();
  p.compare->add_option("--smooth-points", p.smooth_points,
                        "std after this many points' centred moving average, odd; 1 = raw bins "
                        "(default: config compare_smooth_points, else 101)");
  fit_opts(p.compare);

  p.start_model =
      input(app.add_subcommand("start-model",
                               "start-temperature model (paper eq. 3), coefficient export"),
            true);
  p.start_model->add_option("--model", p.model, "e.g. T4+R1+G1 (default: config, else that)");
  p.start_model->add_option("--t0", p.t0_c,
                            "print the coefficients for this start temperature, °C");
  p.start_model->add_option("--t0-window-s", p.t0_window_s, "T0 = mean over the first s (120)");
  fit_opts(p.start_model);
  exports(p.start_model);

  p.scale_factor = app.add_subcommand(
      "scale-factor",
      "scale factor, bias, nonlinearity, asymmetry, repeatability from rate points");
  p.scale_factor
      ->add_option("--csv", p.sf_csv,
                   "CSV: rate_dps,output_dps[,repetition][,temperature_c], one row per dwell")
      ->required();
  p.scale_factor->add_flag("--json", p.json, "JSON output");
  p.scale_factor
      ->add_option("--order", p.sf_order,
                   "order of K(T) and B(T) with several temperatures: 1 or 2")
      ->capture_default_str();
}

AnalysisCommands::~AnalysisCommands() = default;

std::optional<int> AnalysisCommands::run(bool json) {
  Parsed& p = *parsed_;
  p.json = p.json || json;
  if (!p.config_path.empty()) {
    auto db = choose_database(p.db_path, p.config_path);
    if (!db) return fail(db.error().message, kExitInput);
    p.db_path = db->path;
  }
  try {
    if (*p.stats) return cmd_stats(p);
    if (*p.allan) return cmd_allan(p);
    if (*p.fit) return cmd_fit(p);
    if (*p.compare) return cmd_compare(p);
    if (*p.start_model) return cmd_start_model(p);
    if (*p.scale_factor) return cmd_scale_factor(p);
  } catch (const std::exception& e) {
    return fail(e.what(), kExitFailed);
  }
  return std::nullopt;
}

}  // namespace gyrotherm::cli
