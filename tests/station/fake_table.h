// A fake rate table for the station's unit tests: one axis whose rate moves
// towards its demand at a fixed acceleration as the rig's clock advances,
// with a latched fault and a log of the commands it was sent (and, through
// `on_command`, their order relative to the chamber's set point writes),
// and the operator panel's lockout as a motion command takes it.
// `aero` makes it read as an Aerosmith does through AeroTable: always
// servoed (STA 0) unless faulted, in the mode last commanded, servo off
// being a stop; `panel_jog_dps` turns it from its front panel whatever
// the mode reads.
#pragma once

#include <algorithm>
#include <cmath>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "gyrotherm/drivers/rate_table.h"

namespace gyrotherm::testing {

class FakeTable final : public drivers::RateTable {
 public:
  struct State {
    drivers::TableMode mode = drivers::TableMode::kOff;
    drivers::TableInterlock interlock = drivers::TableInterlock::kOpen;
    double rate_dps = 0;
    double position_deg = 0;
    double demand_rate_dps = 0;
    double demand_position_deg = 0;
    bool silent = false;
    bool remote = false;  // the panel locked out by a motion command
    bool aero = false;
    bool sticky_fault = false;  // reset_faults() does not clear it (its cause stays)
    std::optional<double> panel_jog_dps;
  };

  explicit FakeTable(double accel_dps2 = 100.0) : accel_dps2_(accel_dps2) {}

  // Moves the axis on by dt_s station seconds.
  void advance(double dt_s) {
    std::lock_guard lock(mu_);
    double target = 0;
    if (s_.interlock == drivers::TableInterlock::kClosed && s_.mode == drivers::TableMode::kRate) {
      target = s_.demand_rate_dps;
    }
    if (s_.panel_jog_dps) target = *s_.panel_jog_dps;
    const double step = accel_dps2_ * dt_s;
    const double before = s_.rate_dps;
    s_.rate_dps = before + std::clamp(target - before, -step, step);
    s_.position_deg = std::fmod(s_.position_deg + 0.5 * (before + s_.rate_dps) * dt_s, 360.0);
    if (s_.position_deg < 0) s_.position_deg += 360.0;
    if (s_.interlock == drivers::TableInterlock::kClosed &&
        s_.mode == drivers::TableMode::kPosition && s_.rate_dps == 0) {
      s_.position_deg = s_.demand_position_deg;
    }
  }
  // The controller faults the axis (an over-speed, a safety input): it
  // coasts down and the fault stays until reset_faults().
  void fault() {
    std::lock_guard lock(mu_);
    s_.interlock = drivers::TableInterlock::kFault;
    s_.mode = drivers::TableMode::kOff;
  }
  template <class F>
  void change(F&& f) {
    std::lock_guard lock(mu_);
    f(s_);
  }
  State state() const {
    std::lock_guard lock(mu_);
    return s_;
  }
  std::vector<std::string> commands() const {
    std::lock_guard lock(mu_);
    return commands_;
  }
  // Called with each command's name ("rate +10", "stop", "servo off", ...).
  std::function<void(const std::string&)> on_command;

  const std::string& name() const override { return name_; }
  Status connect() override { return Status::Ok(); }
  drivers::DeviceHealth health() const override { return {}; }
  Result<drivers::TableState> read() override {
    std::lock_guard lock(mu_);
    if (s_.silent) return Error::Transient("table: no answer (fake)");
    drivers::TableState t;
    t.mode = s_.mode;
    t.mode_text = std::string(drivers::to_string(s_.mode));
    t.interlock = s_.interlock;
    t.rate_dps = s_.rate_dps;
    t.position_deg = s_.position_deg;
    t.fault = s_.interlock == drivers::TableInterlock::kFault ? "fake fault" : "";
    return t;
  }
  Status set_rate(double rate_dps) override {
    return command("rate " + std::to_string(rate_dps), [&](State& s) {
      s.remote = true;
      if (s.interlock == drivers::TableInterlock::kFault) return false;
      s.interlock = drivers::TableInterlock::kClosed;
      s.mode = drivers::TableMode::kRate;
      s.demand_rate_dps = rate_dps;
      return true;
    });
  }
  Status set_position(double position_deg) override {
    return command("position " + std::to_string(position_deg), [&](State& s) {
      s.remote = true;
      if (s.interlock == drivers::TableInterlock::kFault) return false;
      s.interlock = drivers::TableInterlock::kClosed;
      s.mode = drivers::TableMode::kPosition;
      s.demand_position_deg = position_deg;
      return true;
    });
  }
  Status stop() override {
    return command("stop", [](State& s) {
      if (s.interlock != drivers::TableInterlock::kFault) s.mode = drivers::TableMode::kOff;
      return true;
    });
  }
  Status servo_off() override {
    return command("servo off", [](State& s) {
      if (s.aero) {
        s.mode = drivers::TableMode::kOff;  // AeroTable: STO
      } else if (s.interlock == drivers::TableInterlock::kClosed) {
        s.interlock = drivers::TableInterlock::kOpen;
      }
      return true;
    });
  }
  Status reset_faults() override {
    return command("reset", [](State& s) {
      if (s.interlock == drivers::TableInterlock::kFault && !s.sticky_fault) {
        s.interlock = s.aero ? drivers::TableInterlock::kClosed : drivers::TableInterlock::kOpen;
      }
      return true;
    });
  }
  Result<drivers::TableLimits> limits() override {
    return drivers::TableLimits{1000.0, accel_dps2_, 1100.0};
  }
  // As AcutrolTable: only what a motion command took is handed back.
  Status release_control() override {
    {
      std::lock_guard lock(mu_);
      if (!s_.remote) return Status::Ok();
    }
    return command("release", [](State& s) {
      s.remote = false;
      return true;
    });
  }

 private:
  template <class F>
  Status command(const std::string& what, F&& apply) {
    bool ok = false;
    {
      std::lock_guard lock(mu_);
      if (s_.silent) return Error::Transient("table: no answer (fake)");
      ok = apply(s_);
      commands_.push_back(what);
    }
    if (on_command) on_command(what);
    if (!ok) return Error::Transient("table: " + what + " refused: interlock in fault (fake)");
    return Status::Ok();
  }

  double accel_dps2_;
  std::string name_ = "table";
  mutable std::mutex mu_;
  State s_;
  std::vector<std::string> commands_;
};

// What the station owns: a handle on the rig's FakeTable, which outlives
// the station (a restart finds the table as the last station left it).
class FakeTableHandle final : public drivers::RateTable {
 public:
  explicit FakeTableHandle(FakeTable& table) : t_(table) {}
  const std::string& name() const override { return t_.name(); }
  Status connect() override { return t_.connect(); }
  drivers::DeviceHealth health() const override { return t_.health(); }
  Result<drivers::TableState> read() override { return t_.read(); }
  Status set_rate(double rate_dps) override { return t_.set_rate(rate_dps); }
  Status set_position(double position_deg) override { return t_.set_position(position_deg); }
  Status stop() override { return t_.stop(); }
  Status servo_off() override { return t_.servo_off(); }
  Status reset_faults() override { return t_.reset_faults(); }
  Result<drivers::TableLimits> limits() override { return t_.limits(); }
  Status release_control() override { return t_.release_control(); }

 private:
  FakeTable& t_;
};

}  // namespace gyrotherm::testing
