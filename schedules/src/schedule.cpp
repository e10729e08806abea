#include "gyrotherm/schedules/schedule.h"

#include <fmt/format.h>

#include "gyrotherm/core/toml_reader.h"

namespace gyrotherm::schedules {
namespace {

constexpr int kMaxRepeatDepth = 4;
constexpr std::size_t kMaxSteps = 100000;

std::string format_c(double c) { return fmt::format("{:g} °C", c); }

class ScheduleReader {
 public:
  ScheduleReader(TomlErrors& errors, const StationLimits& limits)
      : errors_(errors), limits_(limits) {}

  void read_steps(TableReader& parent, std::string_view key, int depth,
                  std::vector<PlanStep>& out) {
    const toml::array* steps = parent.array(key);
    if (!steps) {
      if (!parent.raw().contains(key))
        parent.error(key, "missing: a schedule needs at least one [[step]]");
      return;
    }
    if (steps->empty()) parent.error(key, "is empty: a schedule needs at least one step");
    int i = 0;
    for (const toml::node& node : *steps) {
      const std::string path = fmt::format("{}[{}]", parent.key_path(key), i++);
      const toml::table* t = node.as_table();
      if (!t) {
        errors_.add(static_cast<int>(node.source().begin.line), path,
                    fmt::format("expected a table, got {}", toml_type_name(node)));
        continue;
      }
      TableReader step(*t, path, errors_);
      read_step(step, depth, out);
    }
  }

 private:
  // A positive duration in minutes, converted to station seconds.
  double minutes(TableReader& t, std::string_view key, std::optional<double> default_min,
                 double max_min) {
    auto v = t.number(key);
    if (!v) {
      if (!default_min) {
        if (!t.raw().contains(key)) t.error(key, "missing (required, minutes)");
        return 0;
      }
      return *default_min * 60.0;
    }
    if (!(*v > 0) || *v > max_min) {
      t.error(key, fmt::format("{} min is out of range: must be > 0 and <= {} min", *v, max_min));
      return 0;
    }
    return *v * 60.0;
  }

  double temperature(TableReader& t, std::string_view key) {
    auto v = t.required_number(key);
    if (!v) return 0;
    if (*v < limits_.min_temp_c || *v > limits_.max_temp_c) {
      t.error(key, fmt::format("{} is outside the station's limits [{}, {}]", format_c(*v),
                               format_c(limits_.min_temp_c), format_c(limits_.max_temp_c)));
    }
    return *v;
  }

  void read_step(TableReader& t, int depth, std::vector<PlanStep>& out) {
    auto type = t.choice("type", {"soak", "ramp", "hold", "repeat"}, std::nullopt);
    if (!type) {
      if (!t.raw().contains("type")) t.error("type", "missing: one of soak, ramp, hold, repeat");
      return;
    }
    PlanStep s;
    s.source_line = static_cast<int>(t.raw().source().begin.line);
    if (*type == "repeat") {
      auto count = t.integer("count");
      if (!count) {
        if (!t.raw().contains("count")) t.error("count", "missing (required integer)");
      } else if (*count < 1 || *count > 1000) {
        t.error("count", fmt::format("{} is out of range: must be in [1, 1000]", *count));
      }
      if (depth >= kMaxRepeatDepth) {
        t.error("steps", fmt::format("repeats nested deeper than {}", kMaxRepeatDepth));
        t.skip("steps");
      } else {
        std::vector<PlanStep> body;
        read_steps(t, "steps", depth + 1, body);
        for (int64_t k = 0; count && k < *count && out.size() < kMaxSteps; ++k) {
          for (const PlanStep& b : body) {
            PlanStep copy = b;
            copy.label = fmt::format("{} (repeat {}/{})", b.label, k + 1, *count);
            out.push_back(std::move(copy));
          }
        }
        if (out.size() >= kMaxSteps) t.error("count", "expands to too many steps");
      }
      t.finish();
      return;
    }
    if (auto r = t.number("table_rate_dps")) {
      if (std::abs(*r) > 1000.0)
        t.error("table_rate_dps", "must be within ±1000 °/s");
      else
        s.table_rate_dps = *r;
    }
    if (*type == "soak") {
      s.kind = StepKind::kSoak;
      s.setpoint_c = temperature(t, "setpoint_c");
      s.tolerance_c = t.number_in("tolerance_c", s.tolerance_c, 0.01, 10.0);
      s.stability_c_per_min = t.number_in("stability_c_per_min", s.stability_c_per_min, 1e-4, 10.0);
      s.stability_window_s = minutes(t, "stability_window_min", 10.0, 24 * 60);
      s.settle_timeout_s = minutes(t, "settle_timeout_min", 180.0, 7 * 24 * 60);
      s.acquire_s = minutes(t, "acquire_min", std::nullopt, 7 * 24 * 60);
      if (s.stability_window_s > s.settle_timeout_s) {
        t.error("stability_window_min",
                "is longer than settle_timeout_min: the gate could never hold");
      }
      s.label = fmt::format("soak {}", format_c(s.setpoint_c));
    } else if (*type == "ramp") {
      s.kind = StepKind::kRamp;
      s.setpoint_c = temperature(t, "target_c");
      auto rate = t.required_number("rate_c_per_min");
      if (rate) {
        if (!(*rate > 0)) {
          t.error("rate_c_per_min", fmt::format("{} °C/min: must be > 0", *rate));
        } else if (*rate > limits_.max_ramp_c_per_min) {
          t.error("rate_c_per_min",
                  fmt::format("{} °C/min exceeds the station's max ramp rate {} °C/min", *rate,
                              limits_.max_ramp_c_per_min));
        } else {
          s.rate_c_per_min = *rate;
        }
      }
      s.label = fmt::format("ramp to {} at {:g} °C/min", format_c(s.setpoint_c), s.rate_c_per_min);
    } else {
      s.kind = StepKind::kHold;
      s.setpoint_c = temperature(t, "setpoint_c");
      s.hold_s = minutes(t, "duration_min", std::nullopt, 7 * 24 * 60);
      s.label = fmt::format("hold {}", format_c(s.setpoint_c));
    }
    t.finish();
    out.push_back(std::move(s));
  }

  TomlErrors& errors_;
  const StationLimits& limits_;
};

Result<Plan> build_plan(std::optional<toml::table> root, TomlErrors& errors,
                        const std::string& source, const StationLimits& limits) {
  if (!root) return Error::Permanent(errors.joined());
  Plan plan;
  plan.source_path = source;
  TableReader top(*root, "", errors);
  if (auto n = top.string("name")) plan.name = *n;
  if (auto d = top.string("description")) plan.description = *d;
  ScheduleReader reader(errors, limits);
  reader.read_steps(top, "step", 0, plan.steps);
  top.finish();
  if (plan.name.empty()) {
    const auto slash = source.find_last_of('/');
    plan.name = source.substr(slash == std::string::npos ? 0 : slash + 1);
  }
  if (!errors.empty()) return Error::Permanent(errors.joined());
  for (std::size_t i = 0; i < plan.steps.size(); ++i) {
    plan.steps[i].label = fmt::format("step {}: {}", i + 1, plan.steps[i].label);
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
  }
  return "?";
}

double Plan::nominal_duration_s() const {
  double total = 0;
  for (const auto& s : steps) total += s.acquire_s + s.hold_s;
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
