#include "plant_io.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <cmath>
#include <utility>

namespace gyrotherm::station {

PlantIo::PlantIo(std::unique_ptr<drivers::Chamber> chamber,
                 std::unique_ptr<drivers::ShellProbes> probes, Links links)
    : chamber_(std::move(chamber)), probes_(std::move(probes)), links_(std::move(links)) {}

void PlantIo::prepare(double now_s, double wall_s) {
  chamber_ok_s_ = probes_ok_s_ = now_s;
  chamber_ok_wall_s_ = probes_ok_wall_s_ = wall_s;
}

void PlantIo::read(schedules::Readings& r) {
  // A reading `v` of `dev`; `ok` follows whether it answers, logged on change.
  auto read = [](const drivers::PolledDevice& dev, const auto& v, bool& ok, auto& out) {
    if (v) {
      out = *v;
      if (!ok) spdlog::info("{}: readings back", dev.name());
      ok = true;
    } else {
      if (ok) spdlog::warn("{}", v.error().message);
      ok = false;
    }
  };
  if (chamber_units_known()) {
    read(*chamber_, chamber_->process_value(), chamber_ok_, r.chamber_c);
    if (r.chamber_c) {
      r.chamber_c = drivers::to_celsius(*r.chamber_c, *chamber_unit_);
    } else {
      chamber_unit_.reset();  // read again once the chamber answers
    }
  }
  if (r.chamber_c && chamber_->has_alarm()) {
    std::optional<bool> alarm;
    read(*chamber_, chamber_->alarm(), chamber_ok_, alarm);
    r.chamber_alarm = alarm.value_or(false);
  }
  read(*probes_, probes_->top_c(), probes_ok_, r.top_c);
  if (r.top_c) read(*probes_, probes_->side_c(), probes_ok_, r.side_c);
}

void PlantIo::record_silence(
    double now_s, double wall_s,
    const std::function<double(double since_s, double since_wall_s)>& silent,
    schedules::Readings& r) {
  if (r.chamber_c) {
    chamber_ok_s_ = now_s;
    chamber_ok_wall_s_ = wall_s;
  }
  if (r.top_c && r.side_c) {
    probes_ok_s_ = now_s;
    probes_ok_wall_s_ = wall_s;
  }
  r.chamber_silent_s = silent(chamber_ok_s_, chamber_ok_wall_s_);
  r.probes_silent_s = silent(probes_ok_s_, probes_ok_wall_s_);
  // For status(), which never waits on a device.
  drivers::DeviceHealth chamber_health = chamber_->health();
  drivers::DeviceHealth probes_health = probes_->health();
  std::lock_guard lock(links_.status_mu);
  links_.snapshot.chamber = std::move(chamber_health);
  links_.snapshot.probes = std::move(probes_health);
}

void PlantIo::note_links(double now_s) {
  note_link(*chamber_, chamber_ok_, chamber_lost_s_, now_s);
  note_link(*probes_, probes_ok_, probes_lost_s_, now_s);
}

void PlantIo::note_link(const drivers::PolledDevice& device, bool ok,
                        std::optional<double>& lost_since_s, double now_s) {
  if (!ok && !lost_since_s) {
    lost_since_s = now_s;
    links_.add_event("device", fmt::format("{}: no answer ({}); its readings are missing from now",
                                           device.name(), device.health().last_error));
  } else if (ok && lost_since_s) {
    links_.add_event(
        "device", fmt::format("{}: answers again after {:.1f} s of station time without readings",
                              device.name(), now_s - *lost_since_s));
    lost_since_s.reset();
  }
}

bool PlantIo::chamber_units_known() {
  // A controller without a units register serves °C (nothing is read).
  auto v = chamber_->units();
  if (!v) {
    if (chamber_ok_) spdlog::warn("{}", v.error().message);
    chamber_ok_ = false;
    chamber_unit_.reset();
    return false;
  }
  if (!v->unit) {
    if (refused_units_code_ != v->code) {
      spdlog::error("chamber: {}; the chamber's readings and set point are not used until it does",
                    v->note);
      refused_units_code_ = v->code;
    }
    chamber_unit_.reset();
    return false;
  }
  refused_units_code_.reset();
  const drivers::TemperatureUnit unit = *v->unit;
  if (chamber_unit_ != unit && !v->note.empty()) {
    spdlog::info("chamber: serves {} ({}){}", drivers::unit_symbol(unit), v->note,
                 unit == drivers::TemperatureUnit::kCelsius
                     ? ""
                     : "; readings and set points are converted to and from °C");
  }
  chamber_unit_ = unit;
  return true;
}

Status PlantIo::write_setpoint(double setpoint_c, bool force, uint64_t tick) {
  if (setpoint_attempt_tick_ == tick && setpoint_attempt_c_ == setpoint_c) {
    return setpoint_attempt_status_;  // tried in this tick already
  }
  ++ticks_since_setpoint_write_;
  const bool changed =
      !last_written_setpoint_c_ || std::abs(*last_written_setpoint_c_ - setpoint_c) > 1e-4;
  // Re-assert the set point now and then: a controller that was power-cycled
  // or changed by hand comes back to the schedule.
  if (!force && !changed && ticks_since_setpoint_write_ < 30) return Status::Ok();
  ticks_since_setpoint_write_ = 0;
  setpoint_attempt_tick_ = tick;
  setpoint_attempt_c_ = setpoint_c;
  Status st;
  if (!chamber_unit_ && !chamber_units_known()) {
    st = Error::Transient(
        "chamber: the unit it serves is not known (no answer, or its units register holds "
        "neither °C nor °F)");
  } else {
    st = chamber_->write_setpoint(drivers::from_celsius(setpoint_c, *chamber_unit_));
  }
  setpoint_attempt_status_ = st;
  const double now_s = links_.clock.now_s();
  if (st) {
    last_written_setpoint_c_ = setpoint_c;
    if (setpoint_failures_ > 0) {
      const std::string message =
          fmt::format("chamber: set point {:g} °C taken after {} failed write{} over {:.0f} s",
                      setpoint_c, setpoint_failures_, setpoint_failures_ == 1 ? "" : "s",
                      now_s - setpoint_failing_since_s_);
      spdlog::info("{}", message);
      links_.add_event("device", message);
    }
    setpoint_failures_ = 0;
    return st;
  }
  last_written_setpoint_c_.reset();  // retry next tick
  if (setpoint_failures_++ == 0) {
    setpoint_failing_since_s_ = now_s;
    const std::string message = fmt::format(
        "chamber: set point {:g} °C not written ({}); written again every control "
        "tick until the chamber takes it",
        setpoint_c, st.error().message);
    spdlog::warn("{}", message);
    links_.add_event("device", message);
  }
  return st;
}

void PlantIo::keep_safe(double safe_setpoint_c, uint64_t tick) {
  if (safe_setpoint_owed_ && write_setpoint(safe_setpoint_c, true, tick)) {
    safe_setpoint_owed_ = false;
  }
}

}  // namespace gyrotherm::station
