#include "lab.h"

#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <system_error>

#include "control.h"
#include "gyrotherm/core/clock.h"
#include "gyrotherm/lab/central.h"
#include "gyrotherm/lab/pg.h"
#include "output.h"

namespace gyrotherm::cli {

using nlohmann::json;

namespace {

constexpr const char* kDash = "—";
constexpr std::string_view kWho = "gyrotherm lab";
constexpr double kConnectTimeoutS = 10;

// ---------------------------------------------------------------- JSON access

const json& field(const json& j, const char* key) {
  static const json kNull;
  if (!j.is_object()) return kNull;
  const auto it = j.find(key);
  return it == j.end() ? kNull : *it;
}

std::optional<double> number(const json& v) {
  if (!v.is_number()) return std::nullopt;
  const double d = v.get<double>();
  return std::isfinite(d) ? std::optional<double>(d) : std::nullopt;
}

std::string text(const json& v) {
  if (v.is_string()) return v.get<std::string>().empty() ? kDash : v.get<std::string>();
  if (v.is_number_integer()) return v.dump();
  if (v.is_number()) return fmt::format("{:g}", v.get<double>());
  if (v.is_null()) return kDash;
  return v.dump();
}

std::string fixed(const json& v, int decimals, double factor = 1) {
  const auto d = number(v);
  return d ? fmt::format("{:.{}f}", *d * factor, decimals) : std::string(kDash);
}

std::string general(const json& v) {
  const auto d = number(v);
  return d ? fmt::format("{:.4g}", *d) : std::string(kDash);
}

std::string listed(const json& items) {
  if (!items.is_array() || items.empty()) return kDash;
  std::string out;
  for (const auto& i : items) out += (out.empty() ? "" : ", ") + text(i);
  return out;
}

std::string listed(const std::vector<std::string>& items) {
  if (items.empty()) return kDash;
  std::string out;
  for (const auto& i : items) out += (out.empty() ? "" : ", ") + i;
  return out;
}

std::string labelled(std::string_view label, std::string_view value) {
  return fmt::format("{:<12}{}\n", label, value);
}

// "2026-11-21T05:38:43.120Z" -> "2026-11-21 05:38:43"; "—" for none.
std::string utc(std::string_view s) {
  if (s.size() >= 19 && s[10] == 'T') {
    return std::string(s.substr(0, 10)) + " " + std::string(s.substr(11, 8));
  }
  return s.empty() ? kDash : std::string(s);
}

std::string serial_text(const json& serial) {
  return serial.is_string() && serial.get<std::string>().empty() ? "(no serial)" : text(serial);
}

// A step index (from 0) as people count it (from 1).
std::string step_text(const json& index) {
  const auto i = number(index);
  return i ? std::to_string(static_cast<int64_t>(*i) + 1) : kDash;
}

// The axis of a result row; '' is the DUT's primary axis.
std::string axis_text(const json& row) {
  const json& a = field(row, "axis");
  return a.is_string() && !a.get<std::string>().empty() ? a.get<std::string>() : "primary";
}

// "17-0042  KVH 1750, axes x y z (primary z), 1000 Hz" of a lab.run_duts row.
std::string dut_line(const json& d) {
  std::string line = serial_text(field(d, "dut_serial"));
  if (text(field(d, "model")) != kDash) line += "  " + text(field(d, "model"));
  std::string axes;
  for (const auto& a : field(d, "axes").is_array() ? field(d, "axes") : json::array()) {
    axes += (axes.empty() ? "" : " ") + text(a);
  }
  if (!axes.empty())
    line += fmt::format(", axes {} (primary {})", axes, text(field(d, "primary_axis")));
  if (const auto hz = number(field(d, "rate_hz"))) line += fmt::format(", {:g} Hz", *hz);
  return line;
}

std::string comment_text(const json& comment) {
  if (!comment.is_string() || comment.get<std::string>().empty()) return kDash;
  std::string c = comment.get<std::string>();
  for (auto pos = c.find('\n'); pos != std::string::npos; pos = c.find('\n', pos + 1)) {
    c.insert(pos + 1, std::string(12, ' '));
  }
  return c;
}

// ---------------------------------------------------------------- URLs and passwords

std::string percent_decoded(std::string_view s) {
  std::string out;
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '%' && i + 2 < s.size() && std::isxdigit(static_cast<unsigned char>(s[i + 1])) &&
        std::isxdigit(static_cast<unsigned char>(s[i + 2]))) {
      out += static_cast<char>(std::stoi(std::string(s.substr(i + 1, 2)), nullptr, 16));
      i += 2;
    } else {
      out += s[i];
    }
  }
  return out;
}

void add_secret(std::vector<std::string>& out, std::string_view raw) {
  if (raw.empty()) return;
  out.emplace_back(raw);
  const std::string decoded = percent_decoded(raw);
  if (decoded != raw) out.push_back(decoded);
}

}  // namespace

std::vector<std::string> conninfo_passwords(std::string_view c) {
  std::vector<std::string> out;
  const bool uri = c.rfind("postgresql://", 0) == 0 || c.rfind("postgres://", 0) == 0;
  if (uri) {
    const std::size_t start = c.find("://") + 3;
    const std::size_t end = std::min(c.find_first_of("/?", start), c.size());
    const std::string_view authority = c.substr(start, end - start);
    if (const auto at = authority.rfind('@'); at != std::string_view::npos) {
      const std::string_view user_info = authority.substr(0, at);
      if (const auto colon = user_info.find(':'); colon != std::string_view::npos) {
        add_secret(out, user_info.substr(colon + 1));
      }
    }
    // ?password=... among the parameters.
    for (std::size_t q = c.find('?'); q != std::string_view::npos; q = c.find('&', q + 1)) {
      const std::string_view param = c.substr(q + 1);
      if (param.rfind("password=", 0) == 0) {
        add_secret(
            out, param.substr(9, param.find('&') == std::string_view::npos ? std::string_view::npos
                                                                           : param.find('&') - 9));
      }
    }
    return out;
  }
  // keyword = value pairs; values may be single-quoted with \ escapes.
  std::size_t i = 0;
  while (i < c.size()) {
    while (i < c.size() && std::isspace(static_cast<unsigned char>(c[i]))) ++i;
    const std::size_t key_start = i;
    while (i < c.size() && c[i] != '=' && !std::isspace(static_cast<unsigned char>(c[i]))) ++i;
    const std::string_view key = c.substr(key_start, i - key_start);
    while (i < c.size() && std::isspace(static_cast<unsigned char>(c[i]))) ++i;
    if (i >= c.size() || c[i] != '=') {
      if (i == key_start) ++i;
      continue;
    }
    ++i;
    while (i < c.size() && std::isspace(static_cast<unsigned char>(c[i]))) ++i;
    std::string value;
    std::string raw;
    if (i < c.size() && c[i] == '\'') {
      const std::size_t raw_start = ++i;
      while (i < c.size() && c[i] != '\'') {
        if (c[i] == '\\' && i + 1 < c.size()) ++i;
        value += c[i++];
      }
      raw = std::string(c.substr(raw_start, i - raw_start));
      if (i < c.size()) ++i;
    } else {
      while (i < c.size() && !std::isspace(static_cast<unsigned char>(c[i]))) {
        if (c[i] == '\\' && i + 1 < c.size()) ++i;
        value += c[i++];
      }
      raw = value;
    }
    if (key == "password") {
      add_secret(out, value);
      if (raw != value) add_secret(out, raw);
    }
  }
  return out;
}

std::string redact_lab_passwords(std::string text, const std::vector<std::string>& args) {
  std::vector<std::string> secrets;
  if (const char* env = std::getenv(kLabUrlEnv); env && *env) {
    for (auto& s : conninfo_passwords(env)) secrets.push_back(std::move(s));
  }
  for (std::size_t i = 0; i < args.size(); ++i) {
    std::string value;
    if (args[i].rfind("--pg=", 0) == 0) {
      value = args[i].substr(5);
    } else if (args[i] == "--pg" && i + 1 < args.size()) {
      value = args[i + 1];
    } else {
      continue;
    }
    for (auto& s : conninfo_passwords(value)) secrets.push_back(std::move(s));
  }
  for (const auto& secret : secrets) {
    for (auto pos = text.find(secret); pos != std::string::npos; pos = text.find(secret, pos)) {
      text.replace(pos, secret.size(), "***");
      pos += 3;
    }
  }
  return text;
}

Result<std::string> lab_url(const std::string& given) {
  std::string url = given;
  if (url.empty()) {
    const char* env = std::getenv(kLabUrlEnv);
    if (env == nullptr || *env == '\0') {
      return Error::Permanent(fmt::format(
          "no lab database given: --pg URL, --pg @FILE (the URL in a file), or the environment "
          "variable {}",
          kLabUrlEnv));
    }
    url = env;
  }
  if (url.front() == '@') {
    const std::string path = url.substr(1);
    std::ifstream in(path);
    if (!in) return Error::Permanent(fmt::format("--pg @{}: cannot read the file", path));
    std::string line;
    std::getline(in, line);
    const auto first = line.find_first_not_of(" \t\r");
    const auto last = line.find_last_not_of(" \t\r");
    if (first == std::string::npos) {
      return Error::Permanent(fmt::format("--pg @{}: the file's first line is empty", path));
    }
    url = line.substr(first, last - first + 1);
  }
  return url;
}

// ---------------------------------------------------------------- formatters

std::string format_lab_stations(const std::vector<lab::LabStation>& stations) {
  if (stations.empty()) return "no stations registered\n";
  std::vector<std::vector<std::string>> rows;
  for (const auto& s : stations) {
    rows.push_back({s.station_id, s.db_role, s.description.empty() ? kDash : s.description,
                    utc(s.registered_utc), s.last_batch_utc ? utc(*s.last_batch_utc) : "never",
                    std::to_string(s.last_seq), std::to_string(s.records), std::to_string(s.runs)});
  }
  return table({"station", "role", "description", "registered (UTC)", "last batch (UTC)",
                "last seq", "records", "runs"},
               rows, 5);
}

std::string format_lab_runs(const std::vector<lab::LabRun>& runs) {
  if (runs.empty()) return "no runs\n";
  std::vector<std::vector<std::string>> rows;
  for (const auto& r : runs) {
    rows.push_back({r.station_id, std::to_string(r.local_run_id), r.schedule_name, r.state,
                    utc(r.started_utc), utc(r.ended_utc),
                    r.operator_name.empty() ? kDash : r.operator_name, listed(r.dut_serials),
                    listed(r.tags), r.run_uuid});
  }
  return table({"station", "run", "schedule", "state", "started (UTC)", "ended (UTC)", "operator",
                "DUTs", "tags", "uuid"},
               {Align::kLeft, Align::kRight, Align::kLeft, Align::kLeft, Align::kLeft, Align::kLeft,
                Align::kLeft, Align::kLeft, Align::kLeft, Align::kLeft},
               rows);
}

namespace {

// "station-3/12, station-3/14" of a station's run ids.
std::string run_refs(const std::string& station, const json& ids) {
  if (!ids.is_array() || ids.empty()) return kDash;
  std::string out;
  for (const auto& id : ids)
    out += fmt::format("{}{}/{}", out.empty() ? "" : ", ", station, text(id));
  return out;
}

// The Allan noise terms of result rows, with a run column (the rows'
// "run") and a DUT column when asked.
std::string allan_table(const json& rows, bool with_run, bool with_dut) {
  std::vector<std::vector<std::string>> out;
  for (const auto& a : rows) {
    std::vector<std::string> row;
    if (with_run) row.push_back(text(field(a, "run")));
    if (with_dut) row.push_back(serial_text(field(a, "dut_serial")));
    for (auto& c : std::vector<std::string>{
             axis_text(a), step_text(field(a, "segment_index")), text(field(a, "taus")),
             text(field(a, "n_samples")), general(field(a, "angle_random_walk_dprh")),
             general(field(a, "bias_instability_dph")), general(field(a, "bias_instability_tau_s")),
             general(field(a, "rate_random_walk_dphprh"))}) {
      row.push_back(std::move(c));
    }
    out.push_back(std::move(row));
  }
  std::vector<std::string> header;
  if (with_run) header.emplace_back("run");
  if (with_dut) header.emplace_back("DUT");
  for (const char* h :
       {"axis", "#", "taus", "samples", "ARW °/√h", "BI °/h", "BI τ s", "RRW °/h/√h"}) {
    header.emplace_back(h);
  }
  return table(header, out, header.size() - 5, "  ");
}

}  // namespace

std::string format_lab_run(const json& j) {
  const json& run = field(j, "run");
  std::string out = fmt::format("run {}/{}  {}  {}\n", text(field(run, "station_id")),
                                text(field(run, "local_run_id")), text(field(run, "schedule_name")),
                                text(field(run, "state")));
  out += labelled("uuid", text(field(run, "run_uuid")));
  out += labelled("started", field(run, "started_utc").is_string()
                                 ? utc(field(run, "started_utc").get<std::string>()) + " UTC"
                                 : kDash);
  out += labelled("ended", field(run, "ended_utc").is_string() &&
                                   !field(run, "ended_utc").get<std::string>().empty()
                               ? utc(field(run, "ended_utc").get<std::string>()) + " UTC"
                               : kDash);
  out += labelled("time scale", text(field(run, "time_scale")) + "×");
  out += labelled("operator", text(field(run, "operator")));
  out += labelled("comment", comment_text(field(run, "comment")));
  out += labelled("tags", listed(field(run, "tags")));
  const json& duts = field(j, "duts");
  if (duts.is_array() && !duts.empty()) {
    bool first = true;
    for (const auto& d : duts) {
      out += labelled(first ? "DUTs" : "", dut_line(d));
      first = false;
    }
  } else {
    out += labelled("DUTs", listed(field(run, "dut_serials")));
  }

  out += "\nsegments (times: station h:mm:ss since the run started)\n";
  const json& segments = field(j, "segments");
  if (!segments.is_array() || segments.empty()) {
    out += "  none\n";
  } else {
    std::vector<std::vector<std::string>> rows;
    for (const auto& s : segments) {
      std::string table_demand = text(field(s, "table_mode"));
      if (const auto rate = number(field(s, "table_rate_dps"))) {
        table_demand += fmt::format(" {:g} °/s", *rate);
      }
      rows.push_back({step_text(field(s, "idx")), text(field(s, "kind")), text(field(s, "label")),
                      fixed(field(s, "setpoint_c"), 2), format_station_time(field(s, "t_start_s")),
                      format_station_time(field(s, "t_end_s")), table_demand,
                      text(field(s, "state"))});
    }
    out += table({"#", "kind", "label", "set °C", "start", "end", "table", "state"},
                 {Align::kRight, Align::kLeft, Align::kLeft, Align::kRight, Align::kRight,
                  Align::kRight, Align::kLeft, Align::kLeft},
                 rows, "  ");
  }

  if (const json& t1 = field(j, "table1"); t1.is_array() && !t1.empty()) {
    std::vector<std::vector<std::string>> rows;
    for (const auto& r : t1) {
      rows.push_back(
          {serial_text(field(r, "dut_serial")), axis_text(r), step_text(field(r, "segment_index")),
           fixed(field(r, "setpoint_c"), 2), fixed(field(r, "temp_mean_c"), 2), text(field(r, "n")),
           fixed(field(r, "bias_mean_dph"), 4), fixed(field(r, "bias_u_expanded_dph"), 4),
           fixed(field(r, "bias_std_dph"), 4), fixed(field(r, "bias_std_ma_dph"), 4),
           fixed(field(r, "bias_mean_earth_removed_dph"), 4)});
    }
    out += "\nTable I (± U95: the 95 % interval of the bias mean)\n";
    out += table({"DUT", "axis", "#", "set °C", "T mean °C", "n", "bias °/h", "± U95 °/h", "σ °/h",
                  "σ MA °/h", "bias−Earth °/h"},
                 rows, 2, "  ");
  }

  if (const json& allan = field(j, "allan"); allan.is_array() && !allan.empty()) {
    out += "\nAllan noise terms\n" + allan_table(allan, false, true);
  }

  if (const json& fits = field(j, "fits"); fits.is_array() && !fits.empty()) {
    // A fit's runs are its station's: named STATION/ID like this one.
    const std::string station = text(field(run, "station_id"));
    std::vector<std::vector<std::string>> rows;
    for (const auto& f : fits) {
      std::string coefficients;
      const json& c = field(f, "coefficients");
      if (c.is_object()) {
        for (const auto& [name, v] : c.items()) {
          coefficients += fmt::format("{}{}={}", coefficients.empty() ? "" : " ", name, general(v));
        }
      }
      rows.push_back({text(field(f, "fit_local_id")), serial_text(field(f, "dut_serial")),
                      axis_text(f), text(field(f, "model")), text(field(f, "form")),
                      run_refs(station, field(f, "run_ids")),
                      fixed(field(f, "residual_std_dph"), 4), fixed(field(f, "r_squared"), 4),
                      coefficients.empty() ? std::string(kDash) : coefficients});
    }
    out += "\ndrift fits\n";
    out +=
        table({"id", "DUT", "axis", "model", "form", "runs", "residual °/h", "R²", "coefficients"},
              {Align::kRight, Align::kLeft, Align::kLeft, Align::kLeft, Align::kLeft, Align::kLeft,
               Align::kRight, Align::kRight, Align::kLeft},
              rows, "  ");
  }

  if (const json& sf = field(j, "scale_factor_fits"); sf.is_array() && !sf.empty()) {
    std::vector<std::vector<std::string>> rows;
    for (const auto& f : sf) {
      rows.push_back({serial_text(field(f, "dut_serial")), axis_text(f),
                      text(field(f, "sf_sequence")), fixed(field(f, "temperature_c"), 2),
                      fixed(field(f, "k"), 7), fixed(field(f, "nonlinearity_ppm"), 1),
                      fixed(field(f, "asymmetry_ppm"), 1), fixed(field(f, "repeatability_ppm"), 1),
                      fixed(field(f, "bias_dps"), 3, 3600.0)});
    }
    out += "\nscale factor\n";
    out += table(
        {"DUT", "axis", "seq", "T °C", "K", "nonlin ppm", "asym ppm", "repeat ppm", "bias °/h"},
        rows, 2, "  ");
  }

  if (const json& sft = field(j, "scale_factor_temperature_fits"); sft.is_array() && !sft.empty()) {
    std::vector<std::vector<std::string>> rows;
    for (const auto& f : sft) {
      rows.push_back({serial_text(field(f, "dut_serial")), axis_text(f),
                      text(field(f, "poly_order")), fixed(field(f, "t_centre_c"), 2),
                      fixed(field(f, "k_ppm_per_c"), 3), fixed(field(f, "bias_dph_per_c"), 4)});
    }
    out += "\nscale factor against temperature\n";
    out += table({"DUT", "axis", "order", "centre °C", "K ppm/°C", "bias °/h/°C"}, rows, 2, "  ");
  }

  out += "\nevents\n";
  return out + format_events(field(j, "events"), "  ");
}

std::string format_lab_dut(const json& h) {
  // The shape `gyrotherm dut` prints (format_dut_history), each run and
  // fit named STATION/LOCAL_ID.
  json history = {{"serial", field(h, "serial")},
                  {"model", field(h, "model")},
                  {"first_seen_utc", field(h, "first_seen_utc")},
                  {"runs", json::array()},
                  {"fits", json::array()}};
  json allan = json::array();
  for (const auto& entry : field(h, "runs").is_array() ? field(h, "runs") : json::array()) {
    const json& run = field(entry, "run");
    const std::string ref =
        fmt::format("{}/{}", text(field(entry, "station_id")), text(field(run, "local_run_id")));
    json dut = field(entry, "dut");
    if (dut.is_object()) dut["serial"] = field(h, "serial");
    json segments = json::array();
    for (const auto& s :
         field(entry, "segments").is_array() ? field(entry, "segments") : json::array()) {
      json seg = s;
      seg["index"] = field(s, "idx");
      segments.push_back(std::move(seg));
    }
    json sf = json::array();
    for (const auto& f : field(entry, "scale_factor_fits").is_array()
                             ? field(entry, "scale_factor_fits")
                             : json::array()) {
      json row = f;
      if (const auto b = number(field(f, "bias_dps"))) row["bias_dph"] = *b * 3600.0;
      sf.push_back(std::move(row));
    }
    for (const auto& a : field(entry, "allan").is_array() ? field(entry, "allan") : json::array()) {
      json row = a;
      row["run"] = ref;
      allan.push_back(std::move(row));
    }
    history["runs"].push_back({{"id", ref},
                               {"schedule_name", field(run, "schedule_name")},
                               {"state", field(run, "state")},
                               {"started_utc", field(run, "started_utc")},
                               {"metadata",
                                {{"operator", field(run, "operator")},
                                 {"comment", field(run, "comment")},
                                 {"tags", field(run, "tags")}}},
                               {"dut", std::move(dut)},
                               {"segments", std::move(segments)},
                               {"stats", field(entry, "table1")},
                               {"scale_factor", std::move(sf)}});
  }
  for (const auto& f : field(h, "fits").is_array() ? field(h, "fits") : json::array()) {
    json fit = f;
    const std::string station = text(field(f, "station_id"));
    fit["id"] = fmt::format("{}/{}", station, text(field(f, "fit_local_id")));
    json runs = json::array();
    for (const auto& id : field(f, "run_ids").is_array() ? field(f, "run_ids") : json::array()) {
      runs.push_back(fmt::format("{}/{}", station, text(id)));
    }
    fit["run_ids"] = std::move(runs);
    history["fits"].push_back(std::move(fit));
  }
  std::string out = format_dut_history(history);
  // The stations, under the count of runs.
  if (const auto runs_line = out.find("\nruns "); runs_line != std::string::npos) {
    const auto end = out.find('\n', runs_line + 1);
    out.insert(end == std::string::npos ? out.size() : end + 1,
               labelled("stations", listed(field(h, "stations"))));
  }
  if (!allan.empty()) out += "\nAllan noise terms\n" + allan_table(allan, true, false);
  return out;
}

// ---------------------------------------------------------------- commands

struct LabCommands::Parsed {
  CLI::App* lab = nullptr;
  CLI::App* stations = nullptr;
  CLI::App* runs = nullptr;
  CLI::App* run = nullptr;
  CLI::App* dut = nullptr;
  CLI::App* summary = nullptr;
  CLI::App* migrate = nullptr;
  CLI::App* add_station = nullptr;
  CLI::App* add_reader = nullptr;
  std::string pg;
  bool json = false;
  lab::LabRunFilter filter;
  std::string run_ref, serial, out_path;
  std::string station_id, role, description;
};

LabCommands::LabCommands(CLI::App& app) : parsed_(std::make_unique<Parsed>()) {
  Parsed& p = *parsed_;
  p.lab = app.add_subcommand(
      "lab", "the lab database (PostgreSQL): every station's runs and results (docs/cli.md)");
  p.lab->require_subcommand(1);
  const std::string pg_help =
      fmt::format("lab database: a libpq URL or conninfo, or @FILE to read it from a file (env {})",
                  kLabUrlEnv);
  auto common = [&](CLI::App* cmd, bool with_json) {
    cmd->add_option("--pg", p.pg, pg_help);
    if (with_json) cmd->add_flag("--json", p.json, "machine-readable output");
    return cmd;
  };
  p.stations =
      common(p.lab->add_subcommand("stations", "the stations and their relay progress"), true);
  p.runs =
      common(p.lab->add_subcommand("runs", "runs relayed by every station, newest first"), true);
  p.runs->add_option("--station", p.filter.station_id, "one station's runs");
  p.runs->add_option("--dut", p.filter.dut_serial, "runs of one DUT (serial)");
  p.runs->add_option("--since", p.filter.since_utc,
                     "runs started at or after DATE (ISO-8601; UTC unless an offset is given)");
  p.runs->add_option("--limit", p.filter.limit, "at most N runs (0: all; default 200)")
      ->check(CLI::NonNegativeNumber);
  p.run = common(p.lab->add_subcommand("run", "one run with everything relayed for it"), true);
  p.run->add_option("run", p.run_ref, "the run: its UUID, or STATION/LOCAL_ID (e.g. station-3/12)")
      ->required();
  p.dut = common(p.lab->add_subcommand("dut", "one DUT's history across stations"), true);
  p.dut->add_option("serial", p.serial, "the DUT's serial number")->required();
  p.summary = common(
      p.lab->add_subcommand("summary", "the lab summary page (HTML) across stations and DUTs"),
      false);
  p.summary->add_option("--since", p.filter.since_utc,
                        "runs started at or after DATE (ISO-8601; UTC unless an offset is given)");
  p.summary->add_option("-o,--out", p.out_path, "write the page to FILE (default: stdout)");
  p.migrate = common(
      p.lab->add_subcommand("migrate", "create or update the lab schema (administrator)"), false);
  p.add_station = common(
      p.lab->add_subcommand("add-station", "register a station and its login role (administrator)"),
      false);
  p.add_station->add_option("id", p.station_id, "the station's id ([lab] station_id)")->required();
  p.add_station->add_option("--role", p.role, "the PostgreSQL login role it connects as")
      ->required();
  p.add_station->add_option("--description", p.description, "what and where the station is");
  p.add_reader =
      common(p.lab->add_subcommand("add-reader",
                                   "make a login role that may read the lab (administrator)"),
             false);
  p.add_reader->add_option("role", p.role, "the PostgreSQL login role")->required();
}

LabCommands::~LabCommands() = default;

namespace {

// Writes `text` to `path` through a temporary file beside it (a reader
// never sees half a page).
Status write_file_atomically(const std::string& path, const std::string& text) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) return Error::Permanent(fmt::format("{}: cannot write", tmp));
    out << text;
    out.flush();
    if (!out) return Error::Permanent(fmt::format("{}: cannot write", tmp));
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::filesystem::remove(tmp, ec);
    return Error::Permanent(fmt::format("{}: cannot write", path));
  }
  return Status::Ok();
}

}  // namespace

std::optional<int> LabCommands::run(bool json_flag) {
  Parsed& p = *parsed_;
  if (!*p.lab) return std::nullopt;
  const bool as_json = p.json || json_flag;
  if (!p.filter.since_utc.empty()) {
    // Refused before connecting: a typo is not the server's problem.
    if (auto since = parse_utc_iso(p.filter.since_utc); !since) {
      return fail(fmt::format("--since: {}", since.error().message), kExitInput, kWho);
    }
  }
  auto url = lab_url(p.pg);
  if (!url)
    return fail(redact_lab_passwords(url.error().message, {"--pg", p.pg}), kExitInput, kWho);
  // Every message goes through this: no password of the URL reaches the
  // terminal, whatever a library put in its error.
  const std::vector<std::string> url_args = {"--pg", p.pg, "--pg", *url};
  auto fail_with = [&](const Error& e) {
    return fail(redact_lab_passwords(e.message, url_args), kExitFailed, kWho);
  };

  auto pg = lab::PgConnection::connect(*url, kConnectTimeoutS);
  // The library's message names the server (host, port, database, user)
  // and never the password.
  // A connection string libpq cannot parse is the user's to fix (exit 2);
  // a server that cannot be reached or refuses the login is 1.
  if (!pg) {
    return fail(redact_lab_passwords(pg.error().message, url_args),
                pg.error().transient ? kExitFailed : kExitInput, kWho);
  }

  if (*p.stations) {
    auto stations = lab::lab_stations(*pg);
    if (!stations) return fail_with(stations.error());
    if (as_json) {
      json out = json::array();
      for (const auto& s : *stations) {
        out.push_back({{"station_id", s.station_id},
                       {"db_role", s.db_role},
                       {"description", s.description},
                       {"registered_utc", s.registered_utc},
                       {"last_batch_utc", s.last_batch_utc ? json(*s.last_batch_utc) : json()},
                       {"last_seq", s.last_seq},
                       {"records", s.records},
                       {"runs", s.runs}});
      }
      std::cout << out.dump(2) << "\n";
    } else {
      std::cout << format_lab_stations(*stations);
    }
    return 0;
  }
  if (*p.runs) {
    // One run more than asked for tells whether the list was cut.
    lab::LabRunFilter filter = p.filter;
    if (filter.limit > 0) ++filter.limit;
    auto runs = lab::lab_runs(*pg, filter);
    if (!runs) return fail_with(runs.error());
    const bool cut = p.filter.limit > 0 && runs->size() > static_cast<std::size_t>(p.filter.limit);
    if (cut) runs->resize(static_cast<std::size_t>(p.filter.limit));
    if (as_json) {
      json out = json::array();
      for (const auto& r : *runs) {
        out.push_back({{"station_id", r.station_id},
                       {"run_uuid", r.run_uuid},
                       {"local_run_id", r.local_run_id},
                       {"schedule_name", r.schedule_name},
                       {"state", r.state},
                       {"started_utc", r.started_utc},
                       {"ended_utc", r.ended_utc.empty() ? json() : json(r.ended_utc)},
                       {"operator", r.operator_name},
                       {"comment", r.comment},
                       {"tags", r.tags},
                       {"dut_serials", r.dut_serials}});
      }
      std::cout << out.dump(2) << "\n";
    } else {
      std::cout << format_lab_runs(*runs);
      if (cut) {
        std::cout << fmt::format("(the newest {}: --limit N or --since DATE for others)\n",
                                 p.filter.limit);
      }
    }
    return 0;
  }
  if (*p.run || *p.dut) {
    auto answer = *p.run ? lab::lab_run_json(*pg, p.run_ref) : lab::lab_dut_json(*pg, p.serial);
    if (!answer) return fail_with(answer.error());
    const json j = json::parse(*answer, nullptr, false);
    if (as_json) {
      std::cout << j.dump(2) << "\n";
    } else {
      std::cout << (*p.run ? format_lab_run(j) : format_lab_dut(j));
    }
    return 0;
  }
  if (*p.summary) {
    lab::LabSummaryOptions options;
    options.since_utc = p.filter.since_utc;
    options.server = pg->server();
    auto page = lab::lab_summary_html(*pg, options);
    if (!page) return fail_with(page.error());
    if (p.out_path.empty()) {
      std::cout << *page;
      return 0;
    }
    if (auto written = write_file_atomically(p.out_path, *page); !written) {
      return fail_with(written.error());
    }
    std::cout << fmt::format("lab summary written to {}\n", p.out_path);
    return 0;
  }
  if (*p.migrate) {
    auto before = lab::central_schema_version(*pg);
    if (!before) return fail_with(before.error());
    auto after = lab::migrate_central(*pg);
    if (!after) return fail_with(after.error());
    if (*after == *before) {
      std::cout << fmt::format("lab schema at version {} (nothing to do)\n", *after);
    } else {
      std::cout << fmt::format("lab schema migrated from version {} to {}\n", *before, *after);
    }
    return 0;
  }
  if (*p.add_station) {
    if (auto added = lab::add_station(*pg, p.station_id, p.role, p.description); !added) {
      return fail_with(added.error());
    }
    std::cout << fmt::format(
        "station {} registered: login role {} may write its rows (set the role's password or "
        "certificate, then [lab] in the station's config)\n",
        p.station_id, p.role);
    return 0;
  }
  if (*p.add_reader) {
    if (auto added = lab::add_reader(*pg, p.role); !added) return fail_with(added.error());
    std::cout << fmt::format("login role {} may read the lab (member of gyrotherm_reader)\n",
                             p.role);
    return 0;
  }
  return std::nullopt;
}

}  // namespace gyrotherm::cli
