#include "gyrotherm/station/table_control.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>

namespace gyrotherm::station {

namespace {

using schedules::TableDemand;
using schedules::TableDemandMode;

constexpr double kResendWallS = 1.0;  // at most one command per wall second
// Latched faults: station seconds between two resets.
constexpr double kFaultResetSpacingS = 10.0;

bool same_demand(const TableDemand& a, const TableDemand& b) {
  return a.mode == b.mode && a.rate_dps == b.rate_dps && a.position_deg == b.position_deg;
}

bool moving(const TableDemand& d) {
  return d.mode == TableDemandMode::kRate || d.position_deg.has_value();
}

// Not servoed: the drive is off (open), or the controller has switched it
// off (fault).
bool servo_off(const drivers::TableState& s) {
  return s.interlock != drivers::TableInterlock::kClosed;
}

}  // namespace

std::string describe(const TableDemand& demand) {
  switch (demand.mode) {
    case TableDemandMode::kNone:
      return "none";
    case TableDemandMode::kStatic:
      return demand.position_deg ? fmt::format("static at {:g}°", *demand.position_deg)
                                 : std::string("static");
    case TableDemandMode::kRate:
      return fmt::format("rate {:+g} °/s", demand.rate_dps);
  }
  return "?";
}

TableControl::TableControl(drivers::RateTable& table, const config::TableSection& config)
    : table_(table), config_(config) {}

void TableControl::read(double now_s, double wall_s, double min_silent_wall_s,
                        schedules::Readings& r) {
  if (!started_) {
    started_ = true;
    ok_s_ = now_s;
    ok_wall_s_ = wall_s;
  }
  r.table_present = true;
  auto state = table_.read();
  if (state) {
    if (!ok_) spdlog::info("{}: readings back", table_.name());
    ok_ = true;
    state_ = *state;
    moved_since_read_ = false;
    ok_s_ = now_s;
    ok_wall_s_ = wall_s;
    watch_demand();
    r.table_rate_dps = state->rate_dps;
    r.table_position_deg = state->position_deg;
    r.table_fault = state->interlock == drivers::TableInterlock::kFault;
    r.table_fault_text = state->fault;
  } else {
    if (ok_) spdlog::warn("{}", state.error().message);
    ok_ = false;
    last_error_ = state.error().message;
  }
  r.table_silent_s = wall_s - ok_wall_s_ >= min_silent_wall_s ? std::max(0.0, now_s - ok_s_) : 0.0;
}

void TableControl::watch_demand() {
  if (!sent_ || !moving(*sent_) || safing_) {
    matched_ = at_rate_ = false;
    return;
  }
  const drivers::TableState& s = *state_;
  std::string what;
  if (s.interlock == drivers::TableInterlock::kFault) {
    what = fmt::format("the controller faulted the axis{}{}", s.fault.empty() ? "" : ": ", s.fault);
  } else if (matches(*sent_)) {
    matched_ = true;
    if (sent_->mode != TableDemandMode::kRate) return;
    // The rate, for a controller whose mode and interlock say nothing (an
    // Aerosmith): at rate within the at-rate tolerance, off it by ten times
    // that (1 °/s at least).
    const double tolerance_dps =
        std::max(config_.at_rate_tolerance_dps,
                 config_.at_rate_tolerance_ppm * 1e-6 * std::abs(sent_->rate_dps));
    const double off_dps = std::abs(s.rate_dps - sent_->rate_dps);
    if (off_dps <= tolerance_dps) at_rate_ = true;
    if (!at_rate_ || off_dps <= std::max(1.0, 10 * tolerance_dps)) return;
    what = fmt::format("the table left {}: it turns at {:+.3f} °/s", describe(*sent_), s.rate_dps);
  } else if (!matched_) {
    return;  // not there yet: just commanded
  } else {
    what = fmt::format("the table left {}: mode {} ({}), interlock {}, {:+.3f} °/s",
                       describe(*sent_), drivers::to_string(s.mode), s.mode_text,
                       drivers::to_string(s.interlock), s.rate_dps);
  }
  matched_ = at_rate_ = false;
  if (!interruption_) {
    spdlog::warn("{}: {}", table_.name(), what);
    interruption_ = what;
  }
}

std::optional<std::string> TableControl::take_interruption() {
  std::optional<std::string> out;
  out.swap(interruption_);
  return out;
}

void TableControl::begin_run() {
  interruption_.reset();  // one the last run ended without taking
  fault_resets_ = 0;
  last_fault_reset_s_ = -1e9;
  fault_resets_spent_said_ = false;
}

std::optional<std::string> TableControl::reset_latched_fault(double now_s) {
  if (!ok_ || !state_ || state_->interlock != drivers::TableInterlock::kFault) return std::nullopt;
  // A faulted axis coasts: reset once it is at rest, or the servo could
  // close on a spinning table.
  if (std::abs(state_->rate_dps) >= config_.rest_rate_dps) return std::nullopt;
  const std::string fault = state_->fault.empty() ? std::string("no text") : state_->fault;
  if (fault_resets_ >= schedules::kTableFaultResets) {
    if (fault_resets_spent_said_) return std::nullopt;
    fault_resets_spent_said_ = true;
    return fmt::format(
        "{}: the fault stays after {} resets ({}); clear its cause at the table, then run "
        "`gyrotherm table reset` (the run aborts when table_fault_grace_min runs out)",
        table_.name(), fault_resets_, fault);
  }
  if (now_s - last_fault_reset_s_ < kFaultResetSpacingS) return std::nullopt;
  last_fault_reset_s_ = now_s;
  ++fault_resets_;
  const Status st = table_.reset_faults();
  if (!st) {
    return fmt::format("{}: fault reset {} of {} ({}) failed: {}", table_.name(), fault_resets_,
                       schedules::kTableFaultResets, fault, st.error().message);
  }
  return fmt::format(
      "{}: latched fault reset, {} of {} ({}); the run goes on once a reading "
      "shows no fault",
      table_.name(), fault_resets_, schedules::kTableFaultResets, fault);
}

bool TableControl::matches(const TableDemand& demand) const {
  if (!state_) return false;
  const drivers::TableState& s = *state_;
  const bool servoed = s.interlock == drivers::TableInterlock::kClosed;
  switch (demand.mode) {
    case TableDemandMode::kNone:
    case TableDemandMode::kStatic:
      if (demand.position_deg) {
        return servoed && s.mode == drivers::TableMode::kPosition &&
               (sent_ && same_demand(*sent_, demand));
      }
      // Not spinning: off, holding a position, or not servoed at all.
      return s.mode != drivers::TableMode::kRate || !servoed;
    case TableDemandMode::kRate:
      return servoed && s.mode == drivers::TableMode::kRate && sent_ && same_demand(*sent_, demand);
  }
  return false;
}

Status TableControl::send(const TableDemand& demand) {
  switch (demand.mode) {
    case TableDemandMode::kNone:
    case TableDemandMode::kStatic:
      if (demand.position_deg) return table_.set_position(*demand.position_deg);
      return table_.stop();
    case TableDemandMode::kRate:
      return table_.set_rate(demand.rate_dps);
  }
  return Status::Ok();
}

void TableControl::log_failure(const Status& st, const std::string& what) {
  if (st) {
    if (failing_) spdlog::info("{}: commands answered again", table_.name());
    failing_ = false;
    return;
  }
  if (!failing_) spdlog::error("{}: {}: {}", table_.name(), what, st.error().message);
  failing_ = true;
  last_error_ = st.error().message;
}

void TableControl::drive(const TableDemand& demand, double wall_s) {
  demand_ = demand;
  const bool moves = demand.mode == TableDemandMode::kRate || demand.position_deg.has_value();
  if (safing_ && moves) {
    safing_ = false;
    stop_sent_ = false;
  }
  if (safing_) return;
  if (state_ && state_->interlock == drivers::TableInterlock::kFault) return;
  const bool changed = !sent_ || !same_demand(*sent_, demand);
  if (!changed && matches(demand)) return;
  if (!changed && wall_s - last_send_wall_s_ < kResendWallS) return;
  last_send_wall_s_ = wall_s;
  const Status st = send(demand);
  log_failure(st, "commanding " + describe(demand));
  if (st) {
    if (changed) spdlog::info("{}: {}", table_.name(), describe(demand));
    sent_ = demand;
    matched_ = at_rate_ = false;
    if (moving(demand)) {
      safe_reached_ = false;
      moved_since_read_ = true;
    }
  }
}

void TableControl::make_safe(double wall_s) {
  demand_ = TableDemand{TableDemandMode::kStatic, std::nullopt, 0};
  if (safing_ && stop_sent_) return;
  safing_ = true;
  if (state_ && ok_ && servo_off(*state_) && !moved_since_read_) {
    // Not servoed: nothing to stop, nothing to switch off (a faulted axis
    // coasts; its fault is the table_fault interlock's).
    safing_ = false;
    safe_reached_ = true;
    release_panel();
    return;
  }
  last_send_wall_s_ = wall_s;
  const Status st = table_.stop();
  log_failure(st, "stopping");
  stop_sent_ = st.ok();
  if (stop_sent_) moved_since_read_ = true;  // at rest only by a reading taken after it
  if (stop_sent_) {
    spdlog::info("{}: stopping (safe state); servo off once at rest", table_.name());
    sent_ = demand_;
  }
}

void TableControl::finish_safe_state(double wall_s) {
  if (!safing_) return;
  if (!stop_sent_) {
    if (wall_s - last_send_wall_s_ >= kResendWallS) make_safe(wall_s);
    return;
  }
  if (!state_ || !ok_ || moved_since_read_ || std::abs(state_->rate_dps) >= config_.rest_rate_dps) {
    return;
  }
  if (state_->interlock == drivers::TableInterlock::kClosed) {
    const Status st = table_.servo_off();
    log_failure(st, "servo off");
    if (!st) return;
    spdlog::info("{}: at rest, servo off", table_.name());
  }
  safing_ = false;
  stop_sent_ = false;
  safe_reached_ = true;
  sent_.reset();
  release_panel();
}

void TableControl::release_panel() {
  log_failure(table_.release_control(), "handing the operator panel back");
}

bool TableControl::at_rest() const {
  if (!state_) return false;
  return std::abs(state_->rate_dps) < config_.rest_rate_dps &&
         (state_->mode != drivers::TableMode::kRate ||
          state_->interlock != drivers::TableInterlock::kClosed);
}

std::optional<TableSample> TableControl::sample(double t_run_s) const {
  if (!state_ || !ok_) return std::nullopt;
  TableSample s;
  s.t_s = t_run_s;
  s.demand_mode = std::string(schedules::to_string(demand_.mode));
  s.demand_rate_dps = demand_.rate_dps;
  s.demand_position_deg = demand_.position_deg;
  s.rate_dps = state_->rate_dps;
  s.position_deg = state_->position_deg;
  s.mode = std::string(drivers::to_string(state_->mode));
  s.interlock = std::string(drivers::to_string(state_->interlock));
  return s;
}

TableStatus TableControl::status() const {
  TableStatus s;
  s.health = table_.health();
  s.connected = ok_ && state_.has_value();
  s.state = state_;
  s.demand = demand_;
  s.safing = safing_;
  return s;
}

}  // namespace gyrotherm::station
