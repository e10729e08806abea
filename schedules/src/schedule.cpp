#include "gyrotherm/schedules/schedule.h"

#include <fmt/format.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <set>
#include <utility>

#include "gyrotherm/core/toml_reader.h"

namespace gyrotherm::schedules {
namespace {

using Keys = std::vector<std::string_view>;

const Keys kTopKeys{"name", "description", "step"};
const Keys kSoakKeys{
    "type",        "setpoint_c",          "acquire_min",          "acquire",
    "tolerance_c", "stability_c_per_min", "stability_window_min", "settle_timeout_min",
    "table",       "table_rate_dps"};
const Keys kRampKeys{"type", "target_c", "rate_c_per_min", "table", "table_rate_dps"};
const Keys kHoldKeys{"type", "setpoint_c", "duration_min", "table", "table_rate_dps"};
const Keys kScaleFactorKeys{"type",  "setpoint_c",  "rates_dps",   "directions",
                            "turns", "min_dwell_s", "repetitions", "order"};
const Keys kRepeatKeys{"type", "count", "steps"};
// The inline table of a step's `table = { ... }`.
const Keys kTableKeys{"mode", "position_deg", "rate_dps"};
// The inline table of an adaptive soak's `acquire = { ... }`.
const Keys kAcquireKeys{"target_u95_dph", "min_min", "max_min"};

struct KindKeys {
  std::string_view kind;
  const Keys* keys;
};
const KindKeys kKinds[] = {{"soak", &kSoakKeys},
                           {"ramp", &kRampKeys},
                           {"hold", &kHoldKeys},
                           {"scale_factor", &kScaleFactorKeys},
                           {"repeat", &kRepeatKeys}};

bool contains(const Keys& keys, std::string_view key) {
  return std::find(keys.begin(), keys.end(), key) != keys.end();
}

Keys all_step_keys() {
  Keys all;
  for (const auto& k : kKinds) {
    for (std::string_view key : *k.keys) {
      if (!contains(all, key)) all.push_back(key);
    }
  }
  return all;
}

std::size_t edit_distance(std::string_view a, std::string_view b) {
  std::vector<std::size_t> row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    std::size_t diag = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diag + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diag = up;
    }
  }
  return row[b.size()];
}

std::string format_c(double c) { return fmt::format("{:g} °C", c); }

// An angle in [0, 360).
double normalise_deg(double deg) {
  double d = std::fmod(deg, 360.0);
  if (d < 0) d += 360.0;
  if (d >= 360.0) d = 0;  // -1e-20 + 360 rounds to 360
  return d + 0.0;         // no -0
}

// What a demand asks of the table, for messages.
std::string describe(const TableDemand& d) {
  switch (d.mode) {
    case TableDemandMode::kRate:
      return fmt::format("the step asks for the table turning at {:+g} °/s", d.rate_dps);
    case TableDemandMode::kStatic:
      return d.position_deg
                 ? fmt::format("the step asks for the table at rest at {:g}°", *d.position_deg)
                 : std::string("the step asks for the table at rest");
    case TableDemandMode::kNone:
      break;
  }
  return "the step asks nothing of the table";
}

// "43200 min (30 days)", "1440 min (24 h)", "5 min".
std::string format_min(double min) {
  if (min >= 2 * 24 * 60 && std::fmod(min, 24 * 60) == 0) {
    return fmt::format("{:g} min ({:g} days)", min, min / (24 * 60));
  }
  if (min >= 60 && std::fmod(min, 60) == 0) return fmt::format("{:g} min ({:g} h)", min, min / 60);
  return fmt::format("{:g} min", min);
}

// "step[0].steps[2]" -> "step.steps": the [[...]] header of an array of tables.
std::string header_of(std::string_view path) {
  std::string out;
  bool in_index = false;
  for (char c : path) {
    if (c == '[') in_index = true;
    if (!in_index) out += c;
    if (c == ']') in_index = false;
  }
  return out;
}

// A step of the expanded plan and where it came from, for the checks that
// need its neighbours.
struct Expanded {
  PlanStep step;
  std::string path;  // "step[1].steps[0]"
  int target_line = 0;
  int rate_line = 0;
  bool valid = true;  // no error was reported in its table
  // A placeholder for what could not be read or expanded (a bad step, a
  // repeat of bad steps), standing for `weight` plan steps, so that no check
  // takes the steps around it for neighbours.
  bool placeholder = false;
  std::size_t weight = 1;
  // The first rate point of a scale_factor step's expansion: a new
  // sequence starts here (each pass of a repeat is a sequence of its own).
  bool sf_first = false;
};

Expanded placeholder(std::size_t weight) {
  Expanded e;
  e.valid = false;
  e.placeholder = true;
  e.weight = weight;
  return e;
}

// Steps of the plan `steps` will expand to.
std::size_t plan_size(const std::vector<Expanded>& steps) {
  std::size_t n = 0;
  for (const Expanded& e : steps) n += e.weight;
  return n;
}

// A number read from a table: absent, reported as bad, or a value.
struct Number {
  bool present = false;
  std::optional<double> value;
  bool bad() const { return present && !value; }
};

class ScheduleReader {
 public:
  ScheduleReader(TomlErrors& errors, const StationLimits& limits)
      : errors_(errors), limits_(limits) {}

  // Reads the array of step tables under `key` of `parent`, expanding
  // repeats into `out`. `owner` names what needs the steps, for messages.
  void read_steps(TableReader& parent, std::string_view key, std::string_view owner, int depth,
                  std::vector<Expanded>& out) {
    parent.skip(key);
    const std::string header = header_of(parent.key_path(key));
    const toml::node* node = parent.raw().get(key);
    if (!node) {
      parent.error(key, fmt::format("missing: {} needs at least one [[{}]]", owner, header));
      return;
    }
    const toml::array* steps = node->as_array();
    if (!steps) {
      if (node->is_table()) {
        parent.error(
            key, fmt::format("must be an array of tables: write [[{}]], not [{}]", header, header));
      } else {
        parent.error(key, fmt::format("expected an array of [[{}]] tables, got {}", header,
                                      toml_type_name(*node)));
      }
      return;
    }
    if (steps->empty()) {
      parent.error(key, fmt::format("is empty: {} needs at least one step", owner));
      return;
    }
    int i = 0;
    for (const toml::node& n : *steps) {
      const std::string path = fmt::format("{}[{}]", parent.key_path(key), i++);
      const toml::table* t = n.as_table();
      if (!t) {
        errors_.add(static_cast<int>(n.source().begin.line), path,
                    fmt::format("expected a step table, got {}", toml_type_name(n)));
        out.push_back(placeholder(0));
        continue;
      }
      TableReader step(*t, path, errors_);
      read_step(step, depth, out);
    }
  }

  // Reports the keys of `t` that are not in `keys`, with a hint where one
  // is likely: a key of another step type, a misspelling, or the keys that
  // belong here.
  // `inline_table`: the keys of a value table inside a step (`table = {...}`).
  void unknown_keys(const TableReader& t, const Keys& keys, std::string_view what, bool is_step,
                    bool inline_table = false) {
    static const Keys step_keys = all_step_keys();
    for (const auto& [k, node] : t.raw()) {
      const std::string_view key = k.str();
      if (contains(keys, key)) continue;
      std::string message;
      std::vector<std::string_view> owners;
      if (is_step) {
        for (const auto& kind : kKinds) {
          if (contains(*kind.keys, key)) owners.push_back(kind.kind);
        }
      }
      // A misspelling (edit distance <= 2) or the key without its unit.
      std::string_view nearest;
      std::size_t best = 3;
      for (std::string_view candidate : keys) {
        const std::size_t d = edit_distance(key, candidate);
        if (d < best) {
          best = d;
          nearest = candidate;
        }
        if (nearest.empty() && candidate.size() > key.size() + 1 &&
            candidate.substr(0, key.size()) == key && candidate[key.size()] == '_') {
          nearest = candidate;
        }
      }
      if (!owners.empty()) {
        const std::string_view last = owners.back();
        owners.pop_back();
        message = fmt::format("unknown key for {} (only {}{}{} steps take it)", what,
                              fmt::join(owners, ", "), owners.empty() ? "" : " and ", last);
      } else if (!nearest.empty()) {
        message = fmt::format("unknown key: did you mean {}?", nearest);
      } else if (!is_step && !inline_table && contains(step_keys, key)) {
        message = "unknown key at the top level: is a [[step]] header missing above it?";
      } else if (what == "a step") {
        message = "unknown key: no step type takes it";
      } else {
        message = fmt::format("unknown key; {} takes: {}", what, fmt::join(keys, ", "));
      }
      errors_.add(static_cast<int>(node.source().begin.line), t.key_path(key), message);
    }
  }

 private:
  Number number(TableReader& t, std::string_view key) {
    Number n;
    n.present = t.raw().contains(key);
    n.value = t.number(key);
    return n;
  }

  // A required value: reports "missing" with its unit when absent.
  Number required(TableReader& t, std::string_view key, std::string_view unit) {
    Number n = number(t, key);
    if (!n.present) t.error(key, fmt::format("missing (required, {})", unit));
    return n;
  }

  // Checks lo < v (lo_open) or lo <= v, and v <= hi; reports and clears the
  // value otherwise.
  void check_range(TableReader& t, std::string_view key, Number& n, std::string_view unit,
                   double lo, bool lo_open, std::string_view hi_text, double hi) {
    if (!n.value) return;
    const double v = *n.value;
    if ((lo_open ? v > lo : v >= lo) && v <= hi) return;
    t.error(key, fmt::format("{:g} {} is out of range: must be {} {:g} and <= {}", v, unit,
                             lo_open ? ">" : ">=", lo, hi_text));
    n.value.reset();
  }

  // A duration key in minutes, (0, max_min].
  Number minutes(TableReader& t, std::string_view key, bool is_required, double max_min) {
    Number n = is_required ? required(t, key, "minutes") : number(t, key);
    check_range(t, key, n, "min", 0, true, format_min(max_min), max_min);
    return n;
  }

  Number temperature(TableReader& t, std::string_view key) {
    Number n = required(t, key, "°C");
    if (n.value && (*n.value < limits_.min_temp_c || *n.value > limits_.max_temp_c)) {
      t.error(key, fmt::format("{} is outside the station's limits [{}, {}]", format_c(*n.value),
                               format_c(limits_.min_temp_c), format_c(limits_.max_temp_c)));
      n.value.reset();
    }
    return n;
  }

  // Checks a table rate (either sign) against the sanity bound and the
  // station's table; reports at `key` of `t` and returns false when refused.
  bool check_table_rate(TableReader& t, std::string_view key, double rate_dps) {
    if (std::abs(rate_dps) > kMaxTableRateDps) {
      t.error(key, fmt::format("{:g} °/s is out of range: must be >= {:g} and <= {:g} °/s",
                               rate_dps, -kMaxTableRateDps, kMaxTableRateDps));
      return false;
    }
    if (limits_.table && std::abs(rate_dps) > limits_.table->max_rate_dps) {
      t.error(key, fmt::format("{:g} °/s is faster than the station's max table rate {:g} °/s "
                               "([table] max_rate_dps)",
                               rate_dps, limits_.table->max_rate_dps));
      return false;
    }
    if (const std::string why = not_whole(rate_dps, "°/s"); !why.empty()) {
      t.error(key, why);
      return false;
    }
    return true;
  }

  // "" or why the station's table cannot be sent `value` (Table::whole_numbers).
  std::string not_whole(double value, std::string_view unit) const {
    if (!limits_.table || !limits_.table->whole_numbers || value == std::round(value)) return {};
    return fmt::format(
        "{:g} {} is not a whole number, and the station's table takes whole {} only ([table] "
        "profile \"aero\": JOG and MOV send whole numbers, docs/table.md)",
        value, unit, unit);
  }

  // `table = { mode = "static", position_deg = P }` or
  // `table = { mode = "rate", rate_dps = R }`.
  void read_inline_table(TableReader& tt, TableDemand& out) {
    std::optional<std::string> mode;
    if (!tt.raw().contains("mode")) {
      tt.error("mode", "missing: \"static\" or \"rate\"");
    } else {
      mode = tt.choice("mode", {"static", "rate"}, std::nullopt);
    }
    const Number position = number(tt, "position_deg");  // finite, any value
    const Number rate = number(tt, "rate_dps");
    if (mode == "static") {
      if (rate.present) {
        tt.error("rate_dps", "only mode = \"rate\" takes it (a static table does not turn)");
      }
      out.mode = TableDemandMode::kStatic;
      if (position.value) {
        if (const std::string why = not_whole(*position.value, "°"); !why.empty()) {
          tt.error("position_deg", why);
        }
        out.position_deg = normalise_deg(*position.value);
      }
    } else if (mode == "rate") {
      if (position.present) {
        tt.error("position_deg",
                 "only mode = \"static\" takes it (a turning table holds no position)");
      }
      if (!rate.present) {
        tt.error("rate_dps", "missing (required for mode = \"rate\", °/s)");
      } else if (rate.value && *rate.value == 0) {
        tt.error("rate_dps",
                 "0 °/s: a rate demand must be non-zero (mode = \"static\" stops the table)");
      } else if (rate.value && check_table_rate(tt, "rate_dps", *rate.value)) {
        out.mode = TableDemandMode::kRate;
        out.rate_dps = *rate.value;
      }
    }
    unknown_keys(tt, kTableKeys, "a table demand", false, true);
  }

  // A soak's acquisition: a fixed `acquire_min`, or an adaptive `acquire =
  // { target_u95_dph, min_min, max_min }` (it ends when the bias is known to
  // the target; max_min caps it and is what a plan counts).
  void read_acquisition(TableReader& t, PlanStep& s) {
    const bool fixed = t.raw().contains("acquire_min");
    const bool adaptive = t.raw().contains("acquire");
    if (fixed && adaptive) {
      t.error("acquire",
              "give the acquisition once: acquire_min = M (fixed) or acquire = { target_u95_dph "
              "= U, min_min = A, max_min = B } (adaptive)");
      t.skip("acquire");
      t.skip("acquire_min");
      return;
    }
    if (!adaptive) {
      Number acquire = minutes(t, "acquire_min", true, kMaxAcquireMin);
      s.acquire_s = acquire.value.value_or(0) * 60.0;
      return;
    }
    if (const toml::node* node = t.raw().get("acquire"); node && !node->is_table()) {
      t.error("acquire",
              "expected an adaptive acquisition { target_u95_dph = U, min_min = A, "
              "max_min = B }; a fixed one is acquire_min = M");
      t.skip("acquire");
      return;
    }
    std::optional<TableReader> at = t.table("acquire");
    if (!at) return;
    const std::size_t errors_before = errors_.messages().size();
    Number target = required(*at, "target_u95_dph", "°/h");
    if (target.value && !(*target.value > 0)) {
      at->error("target_u95_dph", fmt::format("{:g} °/h: must be > 0", *target.value));
    }
    // Required: how long is enough to see the gyro's slow noises is the
    // lab's knowledge, not the data's (docs/schedules.md, "Adaptive soaks").
    Number min = required(*at, "min_min", "minutes");
    check_range(*at, "min_min", min, "min", 0, false, format_min(kMaxAcquireMin), kMaxAcquireMin);
    Number max = minutes(*at, "max_min", true, kMaxAcquireMin);
    if (max.value && !(*max.value > 0)) {
      at->error("max_min",
                fmt::format("{:g} min: must be > 0 (the cap of the acquisition)", *max.value));
    }
    if (min.value && max.value && *min.value > *max.value) {
      at->error("min_min",
                fmt::format("{:g} min is longer than max_min ({:g} min)", *min.value, *max.value));
    }
    unknown_keys(*at, kAcquireKeys, "an adaptive acquisition", false, true);
    if (errors_.messages().size() != errors_before) return;
    s.adaptive = analysis::AcquisitionTarget{.target_u95_dph = target.value.value_or(0),
                                             .min_s = min.value.value_or(0) * 60.0,
                                             .max_s = max.value.value_or(0) * 60.0};
    s.acquire_s = s.adaptive->max_s;
  }

  // The step's table demand, `table = {...}` or its short form
  // `table_rate_dps = R` (0: static). Refused on a station without a table.
  void read_table_demand(TableReader& t, TableDemand& out) {
    const bool has_inline = t.raw().contains("table");
    const bool has_short = t.raw().contains("table_rate_dps");
    if (has_inline && has_short) {
      t.error("table_rate_dps",
              "give the table's demand once: table_rate_dps = R is the short form of table = { "
              "mode = \"rate\", rate_dps = R }");
      return;
    }
    std::string_view key;
    const std::size_t errors_before = errors_.messages().size();
    if (has_short) {
      key = "table_rate_dps";
      Number rate = number(t, key);
      if (!rate.value || !check_table_rate(t, key, *rate.value)) return;
      if (*rate.value == 0) {
        out.mode = TableDemandMode::kStatic;
      } else {
        out.mode = TableDemandMode::kRate;
        out.rate_dps = *rate.value;
      }
    } else if (has_inline) {
      key = "table";
      std::optional<TableReader> tt = t.table(key);
      if (!tt) return;
      read_inline_table(*tt, out);
    } else {
      return;
    }
    if (errors_.messages().size() != errors_before) {
      out = TableDemand{};
      return;
    }
    if (!limits_.table) {
      t.error(key, fmt::format("the station has no [table]: {}", describe(out)));
      out = TableDemand{};
    }
  }

  // A scale_factor step: expands into one kRate point per rate, direction
  // and repetition, each dwelling over a whole number of turns.
  void read_scale_factor(TableReader& t, std::size_t errors_before, std::vector<Expanded>& out) {
    const int line = static_cast<int>(t.raw().source().begin.line);
    const std::string path = t.key_path("");
    if (!limits_.table) {
      t.error("type",
              "the station has no [table]: a scale_factor step turns the table through its rates");
    }
    const double setpoint_c = temperature(t, "setpoint_c").value.value_or(0);

    // rates_dps: positive magnitudes, each once.
    struct Rate {
      double dps;
      int line;
      std::string key;  // rates_dps[i]
    };
    std::vector<Rate> rates;
    t.skip("rates_dps");
    if (const toml::node* node = t.raw().get("rates_dps"); !node) {
      t.error("rates_dps", "missing (required, array of rates in °/s)");
    } else if (const toml::array* a = node->as_array(); !a) {
      t.error("rates_dps",
              fmt::format("expected an array of rates in °/s, got {}", toml_type_name(*node)));
    } else if (a->empty()) {
      t.error("rates_dps", "is empty: give at least one rate");
    } else {
      std::size_t i = 0;
      for (const toml::node& n : *a) {
        const std::string key = fmt::format("rates_dps[{}]", i++);
        const int n_line = static_cast<int>(n.source().begin.line);
        auto report = [&](const std::string& message) {
          errors_.add(n_line, t.key_path(key), message);
        };
        std::optional<double> v;
        if (auto x = n.value_exact<int64_t>()) {
          v = static_cast<double>(*x);
        } else if (auto y = n.value_exact<double>()) {
          v = *y;
        } else {
          report(fmt::format("expected a number, got {}", toml_type_name(n)));
          continue;
        }
        if (!std::isfinite(*v)) {
          report("must be a finite number");
        } else if (!(*v > 0)) {
          report(fmt::format("{:g} °/s: give magnitudes (> 0); directions sets the signs", *v));
        } else if (*v > kMaxTableRateDps) {
          report(fmt::format("{:g} °/s is out of range: must be > 0 and <= {:g} °/s", *v,
                             kMaxTableRateDps));
        } else if (limits_.table && *v > limits_.table->max_rate_dps) {
          report(
              fmt::format("{:g} °/s is faster than the station's max table rate {:g} °/s ([table] "
                          "max_rate_dps)",
                          *v, limits_.table->max_rate_dps));
        } else if (const std::string why = not_whole(*v, "°/s"); !why.empty()) {
          report(why);
        } else if (std::any_of(rates.begin(), rates.end(),
                               [&](const Rate& r) { return r.dps == *v; })) {
          report(fmt::format("{:g} °/s is listed twice", *v));
        } else {
          rates.push_back({*v, n_line, key});
        }
      }
    }

    const auto directions = t.choice("directions", {"both", "positive", "negative"}, "both");
    auto integer_in = [&](std::string_view key, int64_t default_value, int64_t max) {
      std::optional<int64_t> v = t.raw().contains(key) ? t.integer(key) : default_value;
      if (v && (*v < 1 || *v > max)) {
        t.error(key, fmt::format("{} is out of range: must be in [1, {}]", *v, max));
        v.reset();
      }
      return v;
    };
    const auto turns = integer_in("turns", 1, kMaxTurnsPerPoint);
    Number min_dwell = number(t, "min_dwell_s");
    check_range(t, "min_dwell_s", min_dwell, "s", 0, true, fmt::format("{:g} s", kMaxMinDwellS),
                kMaxMinDwellS);
    if (!min_dwell.present) min_dwell.value = 10.0;
    const auto repetitions = integer_in("repetitions", 1, kMaxScaleFactorRepetitions);
    const auto order = t.choice("order", {"ascending", "descending"}, "ascending");
    unknown_keys(t, kScaleFactorKeys, "a scale_factor step", true);

    // Turns and dwell per magnitude; a point dwells at most kMaxRateDwellMin.
    struct Point {
      double rate_dps;
      int turns;
      double dwell_s;
    };
    std::vector<Point> points;
    if (turns && min_dwell.value) {
      for (const Rate& rate : rates) {
        const double rate_dps = rate.dps;
        // ceil, forgiving the rounding of an exact quotient (10 s at 36 °/s: 1 turn).
        const double needed = std::ceil(*min_dwell.value * rate_dps / 360.0 - 1e-9);
        const double n = std::max(static_cast<double>(*turns), needed);
        const double dwell_s = n * 360.0 / rate_dps;
        if (dwell_s > kMaxRateDwellMin * 60) {
          errors_.add(rate.line, t.key_path(rate.key),
                      fmt::format("at {:g} °/s, {:g} turns take {:.1f} h; a rate point may "
                                  "dwell at most {:g} h",
                                  rate_dps, n, dwell_s / 3600, kMaxRateDwellMin / 60));
          continue;
        }
        points.push_back({rate_dps, static_cast<int>(n), dwell_s});
      }
    }
    const std::size_t signs = directions == "both" ? 2 : 1;
    if (repetitions && !points.empty()) {
      const std::size_t count = points.size() * signs * static_cast<std::size_t>(*repetitions);
      if (plan_size(out) + count > kMaxPlanSteps) {
        t.error("repetitions",
                fmt::format("{} repetitions of {} rate points would make the plan {} steps "
                            "long; the limit is {}",
                            *repetitions, points.size() * signs, plan_size(out) + count,
                            kMaxPlanSteps));
      }
    }
    if (errors_.messages().size() != errors_before || !directions || !order || !repetitions) {
      out.push_back(placeholder(0));
      return;
    }

    std::stable_sort(points.begin(), points.end(), [&](const Point& a, const Point& b) {
      return *order == "ascending" ? a.rate_dps < b.rate_dps : a.rate_dps > b.rate_dps;
    });
    std::vector<double> sign_list;
    if (*directions != "negative") sign_list.push_back(1.0);
    if (*directions != "positive") sign_list.push_back(-1.0);
    bool first = true;
    for (int64_t rep = 1; rep <= *repetitions; ++rep) {
      for (const Point& p : points) {
        for (double sign : sign_list) {
          Expanded e;
          e.path = path;
          e.sf_first = first;
          first = false;
          PlanStep& s = e.step;
          s.kind = StepKind::kRate;
          s.source_line = line;
          s.setpoint_c = setpoint_c;
          s.table.mode = TableDemandMode::kRate;
          s.table.rate_dps = sign * p.rate_dps;
          s.turns = p.turns;
          s.dwell_s = p.dwell_s;
          s.sf_repetition = static_cast<int>(rep);
          s.label = fmt::format("SF {:+g} °/s, rep {} ({} turn{})", s.table.rate_dps, rep, p.turns,
                                p.turns == 1 ? "" : "s");
          out.push_back(std::move(e));
        }
      }
    }
  }

  void read_step(TableReader& t, int depth, std::vector<Expanded>& out) {
    const std::size_t errors_before = errors_.messages().size();
    std::optional<std::string> type;
    if (!t.raw().contains("type")) {
      t.error("type", "missing: one of soak, ramp, hold, scale_factor, repeat");
    } else {
      type = t.choice("type", {"soak", "ramp", "hold", "scale_factor", "repeat"}, std::nullopt);
    }
    if (!type) {
      static const Keys any_step = all_step_keys();
      unknown_keys(t, any_step, "a step", true);
      out.push_back(placeholder(0));
      return;
    }
    if (*type == "repeat") {
      read_repeat(t, depth, out);
      return;
    }
    if (*type == "scale_factor") {
      read_scale_factor(t, errors_before, out);
      return;
    }

    Expanded e;
    e.path = t.key_path("");
    PlanStep& s = e.step;
    s.source_line = static_cast<int>(t.raw().source().begin.line);
    if (*type == "soak") {
      s.kind = StepKind::kSoak;
      s.setpoint_c = temperature(t, "setpoint_c").value.value_or(0);
      read_acquisition(t, s);
      Number tolerance = number(t, "tolerance_c");
      check_range(t, "tolerance_c", tolerance, "°C", kMinToleranceC, false,
                  fmt::format("{:g} °C", kMaxToleranceC), kMaxToleranceC);
      s.tolerance_c = tolerance.value.value_or(s.tolerance_c);
      Number stability = number(t, "stability_c_per_min");
      check_range(t, "stability_c_per_min", stability, "°C/min", 0, true,
                  fmt::format("{:g} °C/min", kMaxStabilityCPerMin), kMaxStabilityCPerMin);
      s.stability_c_per_min = stability.value.value_or(s.stability_c_per_min);
      Number window = number(t, "stability_window_min");
      check_range(t, "stability_window_min", window, "min", kMinStabilityWindowMin, false,
                  format_min(kMaxStabilityWindowMin), kMaxStabilityWindowMin);
      Number timeout = minutes(t, "settle_timeout_min", false, kMaxSettleTimeoutMin);
      if (!window.bad() && !timeout.bad()) {
        const double window_min = window.value.value_or(s.stability_window_s / 60.0);
        const double timeout_min = timeout.value.value_or(s.settle_timeout_s / 60.0);
        if (window_min > timeout_min) {
          if (window.present) {
            t.error("stability_window_min",
                    fmt::format("{:g} min is longer than settle_timeout_min ({:g} min{}): the "
                                "gate could never hold",
                                window_min, timeout_min, timeout.present ? "" : ", the default"));
          } else {
            t.error("settle_timeout_min",
                    fmt::format("{:g} min is shorter than the stability window ({:g} min, the "
                                "default): the gate could never hold",
                                timeout_min, window_min));
          }
        }
      }
      s.stability_window_s = window.value.value_or(s.stability_window_s / 60.0) * 60.0;
      s.settle_timeout_s = timeout.value.value_or(s.settle_timeout_s / 60.0) * 60.0;
      s.label = fmt::format("soak {}", format_c(s.setpoint_c));
    } else if (*type == "ramp") {
      s.kind = StepKind::kRamp;
      s.setpoint_c = temperature(t, "target_c").value.value_or(0);
      e.target_line = t.line_of("target_c");
      Number rate = required(t, "rate_c_per_min", "°C/min");
      e.rate_line = t.line_of("rate_c_per_min");
      if (rate.value) {
        if (!(*rate.value > 0)) {
          t.error("rate_c_per_min", fmt::format("{:g} °C/min: must be > 0", *rate.value));
        } else if (*rate.value > limits_.max_ramp_c_per_min) {
          t.error("rate_c_per_min",
                  fmt::format("{:g} °C/min exceeds the station's max ramp rate {:g} °C/min",
                              *rate.value, limits_.max_ramp_c_per_min));
        } else {
          s.rate_c_per_min = *rate.value;
        }
      }
      s.label = fmt::format("ramp to {} at {:g} °C/min", format_c(s.setpoint_c), s.rate_c_per_min);
    } else {
      s.kind = StepKind::kHold;
      s.setpoint_c = temperature(t, "setpoint_c").value.value_or(0);
      s.hold_s = minutes(t, "duration_min", true, kMaxHoldMin).value.value_or(0) * 60.0;
      s.label = fmt::format("hold {}", format_c(s.setpoint_c));
    }
    read_table_demand(t, s.table);

    const Keys& keys = s.kind == StepKind::kSoak   ? kSoakKeys
                       : s.kind == StepKind::kRamp ? kRampKeys
                                                   : kHoldKeys;
    unknown_keys(t, keys, fmt::format("a {} step", *type), true);
    e.valid = errors_.messages().size() == errors_before;
    out.push_back(std::move(e));
  }

  void read_repeat(TableReader& t, int depth, std::vector<Expanded>& out) {
    std::optional<int64_t> count;
    if (!t.raw().contains("count")) {
      t.error("count", fmt::format("missing (required, integer in [1, {}])", kMaxRepeatCount));
    } else if (auto c = t.integer("count")) {
      if (*c < 1 || *c > kMaxRepeatCount) {
        t.error("count",
                fmt::format("{} is out of range: must be in [1, {}]", *c, kMaxRepeatCount));
      } else {
        count = c;
      }
    }
    std::vector<Expanded> body;
    if (depth >= kMaxRepeatDepth) {
      t.error("steps",
              fmt::format("too deeply nested: repeats nest at most {} deep", kMaxRepeatDepth));
      t.skip("steps");
    } else {
      read_steps(t, "steps", "a repeat", depth + 1, body);
    }
    unknown_keys(t, kRepeatKeys, "a repeat step", true);
    if (!count || body.empty()) {
      out.push_back(placeholder(0));
      return;
    }
    const std::size_t body_size = plan_size(body);
    const std::size_t repeated = body_size * static_cast<std::size_t>(*count);
    const std::size_t total = plan_size(out) + repeated;
    if (total > kMaxPlanSteps) {
      t.error("count",
              fmt::format("{} x {} steps would make the plan {} steps long; the limit is {}",
                          *count, body_size, total, kMaxPlanSteps));
      out.push_back(placeholder(0));
      return;
    }
    // A body with errors is not unrolled (the schedule is refused anyway).
    if (std::any_of(body.begin(), body.end(), [](const Expanded& e) { return e.placeholder; })) {
      out.push_back(placeholder(repeated));
      return;
    }
    for (int64_t k = 0; k < *count; ++k) {
      for (const Expanded& b : body) {
        Expanded copy = b;
        copy.step.label = fmt::format("{} (repeat {}/{})", b.step.label, k + 1, *count);
        out.push_back(std::move(copy));
      }
    }
  }

  TomlErrors& errors_;
  const StationLimits& limits_;
};

// Checks that need a step's predecessor: a ramp starts where the previous
// step left the set point (the first step's start is only known at run time).
void check_ramps(const std::vector<Expanded>& steps, TomlErrors& errors) {
  std::set<std::string> reported;
  for (std::size_t i = 1; i < steps.size(); ++i) {
    const Expanded& e = steps[i];
    const Expanded& prev = steps[i - 1];
    if (e.step.kind != StepKind::kRamp || !e.valid || !prev.valid) continue;
    const double span_c = std::abs(e.step.setpoint_c - prev.step.setpoint_c);
    if (span_c < 1e-9) {
      if (reported.insert(e.path + ".target_c").second) {
        errors.add(e.target_line, e.path + ".target_c",
                   fmt::format("{} is where the previous step leaves the set point: the ramp "
                               "would be empty",
                               format_c(e.step.setpoint_c)));
      }
    } else if (span_c / e.step.rate_c_per_min > kMaxRampMin) {
      if (reported.insert(e.path + ".rate_c_per_min").second) {
        errors.add(
            e.rate_line, e.path + ".rate_c_per_min",
            fmt::format("at {:g} °C/min the ramp from {} to {} takes {:.1f} days; a ramp may "
                        "take at most {:g} days",
                        e.step.rate_c_per_min, format_c(prev.step.setpoint_c),
                        format_c(e.step.setpoint_c), span_c / e.step.rate_c_per_min / (24 * 60),
                        kMaxRampMin / (24 * 60)));
      }
    }
  }
}

// The messages in file order (stable within a line; TomlErrors keeps no
// repeats), at most TomlErrors::kMaxReported of them, then how many more.
std::string sorted_errors(const TomlErrors& errors) {
  const std::string prefix = errors.file() + ":";
  auto line_of = [&](const std::string& m) {
    int line = 0;
    if (m.compare(0, prefix.size(), prefix) == 0) {
      std::from_chars(m.data() + prefix.size(), m.data() + m.size(), line);
    }
    return line;
  };
  std::vector<std::pair<int, const std::string*>> messages;
  messages.reserve(errors.messages().size());
  for (const auto& m : errors.messages()) messages.emplace_back(line_of(m), &m);
  std::stable_sort(messages.begin(), messages.end(),
                   [](const auto& a, const auto& b) { return a.first < b.first; });
  const std::size_t shown = std::min(messages.size(), TomlErrors::kMaxReported);
  std::string out;
  for (std::size_t i = 0; i < shown; ++i) out += *messages[i].second + "\n";
  if (const std::size_t more = messages.size() - shown + errors.dropped(); more > 0) {
    out += more_errors_line(more) + "\n";
  }
  return out;
}

Result<Plan> build_plan(std::optional<toml::table> root, TomlErrors& errors,
                        const std::string& source, const StationLimits& limits) {
  if (!root) return Error::Permanent(errors.joined());
  Plan plan;
  plan.source_path = source;
  TableReader top(*root, "", errors);
  if (auto n = top.string("name")) {
    if (n->find_first_not_of(" \t") == std::string::npos) {
      top.error("name", "must not be empty (leave it out to name the schedule after its file)");
    } else if (has_control_characters(*n)) {
      // The name is printed on terminals and in logs: no escape sequences.
      top.error("name", fmt::format("\"{}\" holds control characters (shown escaped); a name "
                                    "is one line of printable text",
                                    escape_control_characters(*n)));
    }
    plan.name = *n;
  }
  if (auto d = top.string("description")) {
    // Lines and tabs are text; any other control character is not.
    std::string other = *d;
    std::erase_if(other, [](char c) { return c == '\n' || c == '\t'; });
    if (has_control_characters(other)) {
      top.error("description",
                "holds control characters other than new lines and tabs; write plain text");
    }
    plan.description = *d;
  }
  ScheduleReader reader(errors, limits);
  std::vector<Expanded> steps;
  reader.read_steps(top, "step", "a schedule", 0, steps);
  reader.unknown_keys(top, kTopKeys, "a schedule", false);
  if (const std::size_t n = plan_size(steps); n > kMaxPlanSteps) {
    top.error("step", fmt::format("the plan has {} steps; the limit is {}", n, kMaxPlanSteps));
  }
  check_ramps(steps, errors);
  if (!errors.empty()) return Error::Permanent(sorted_errors(errors));

  if (plan.name.empty()) {
    const auto slash = source.find_last_of('/');
    plan.name =
        escape_control_characters(source.substr(slash == std::string::npos ? 0 : slash + 1));
  }
  plan.table_accel_dps2 = limits.table ? limits.table->max_accel_dps2 : 0.0;
  plan.steps.reserve(steps.size());
  int sf_sequence = 0;
  for (std::size_t i = 0; i < steps.size(); ++i) {
    if (steps[i].sf_first) ++sf_sequence;
    PlanStep& s = plan.steps.emplace_back(std::move(steps[i].step));
    if (s.kind == StepKind::kRate) s.sf_sequence = sf_sequence;
    s.label = fmt::format("step {}: {}", i + 1, s.label);
  }
  return plan;
}

}  // namespace

std::string_view to_string(StepKind kind) {
  switch (kind) {
    case StepKind::kSoak:
      return "soak";
    case StepKind::kRamp:
      return "ramp";
    case StepKind::kHold:
      return "hold";
    case StepKind::kRate:
      return "rate";
  }
  return "?";
}

std::string_view to_string(TableDemandMode mode) {
  switch (mode) {
    case TableDemandMode::kNone:
      return "none";
    case TableDemandMode::kStatic:
      return "static";
    case TableDemandMode::kRate:
      return "rate";
  }
  return "?";
}

double Plan::nominal_duration_s() const {
  double total = 0;
  double rate_dps = 0;  // the table's demand before the step
  for (const auto& s : steps) {
    total += s.acquire_s + s.hold_s;
    const double next_dps = s.table.mode == TableDemandMode::kRate ? s.table.rate_dps : 0.0;
    if (s.kind == StepKind::kRate) {
      total += s.dwell_s;
      if (table_accel_dps2 > 0) total += std::abs(next_dps - rate_dps) / table_accel_dps2;
    }
    rate_dps = next_dps;
  }
  return total;
}

Result<Plan> load_schedule(const std::string& path, const StationLimits& limits) {
  TomlErrors errors(path);
  return build_plan(parse_toml_file(path, errors), errors, path, limits);
}

Result<Plan> parse_schedule(std::string_view toml_text, const std::string& source_name,
                            const StationLimits& limits) {
  TomlErrors errors(source_name);
  return build_plan(parse_toml_string(toml_text, errors), errors, source_name, limits);
}

}  // namespace gyrotherm::schedules
