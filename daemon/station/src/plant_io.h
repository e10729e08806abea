// PlantIo: the station's chamber and shell probes, the plant the run
// controls. It owns both devices and what the station knows of them live:
// the unit the chamber serves, whether each answers and since when, their
// silence for the interlocks, their health for the status, their gaps in the
// event log, and the chamber's set point as last written, with the retry
// accounting of a failing write and the safe set point the idle station
// still owes.
//
// Threads: everything runs on the control thread (or, before start() and
// after the control thread is joined, on the thread that stops the
// station). The status lock (Links::status_mu, the Station's mu_) is taken
// only to publish the devices' health into the snapshot; read() takes no
// other lock and is called without the run lock. note_links() and
// write_setpoint() add events to the journal, so their caller holds the run
// lock (the Station's run_mu_).
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/drivers/devices.h"
#include "gyrotherm/schedules/sequencer.h"
#include "gyrotherm/station/status.h"

namespace gyrotherm::station {

class PlantIo {
 public:
  // What the plant shares with the rest of the station.
  struct Links {
    const Clock& clock;  // station time: a failing spell's start
    // The station's status lock and the snapshot it guards: the chamber's
    // and probes' health are published there (status() never waits on a
    // device: their drivers hold their lock through a Modbus request).
    std::mutex& status_mu;
    StatusSnapshot& snapshot;
    // An event in the journal, now (the run lock held).
    std::function<void(const std::string& kind, const std::string& message)> add_event;
  };

  PlantIo(std::unique_ptr<drivers::Chamber> chamber, std::unique_ptr<drivers::ShellProbes> probes,
          Links links);

  drivers::Chamber& chamber() { return *chamber_; }
  drivers::ShellProbes& probes() { return *probes_; }

  // At start(): both count as heard at `now_s` (wall `wall_s`).
  void prepare(double now_s, double wall_s);

  // One control tick's readings: the chamber's process value in °C (when
  // its unit is known) and alarm, the probes' two temperatures.
  void read(schedules::Readings& r);
  // After read(), with the wall time taken after it: when each device was
  // last heard, its silence in `r` (`silent(since_s, since_wall_s)`: the
  // silence in station time of a device last heard then), and their health
  // published for the status.
  void record_silence(double now_s, double wall_s,
                      const std::function<double(double since_s, double since_wall_s)>& silent,
                      schedules::Readings& r);
  // A device's gap in the event log: when it stopped answering and, once
  // it answers again, how long its readings were missing. The run lock held.
  void note_links(double now_s);

  // Sends `setpoint_c` to the chamber when it differs from the last one
  // written, when `force`, or every 30th call (re-asserted: a controller
  // changed by hand comes back); never twice in control tick `tick`. Ok
  // when the chamber took it (now or before), else the write's error (the
  // next call tries again). A failing spell is logged and an event when it
  // starts and when a write takes again. The run lock held.
  Status write_setpoint(double setpoint_c, bool force, uint64_t tick);
  // The set point the chamber last took; nullopt before the first write,
  // after a failed one, and after forget_setpoint().
  std::optional<double> last_written_setpoint_c() const { return last_written_setpoint_c_; }
  // The next write_setpoint() writes, whatever was written before (a
  // resumed run asserts its own set point).
  void forget_setpoint() { last_written_setpoint_c_.reset(); }

  // A run ended without the chamber taking the safe set point: each idle
  // tick writes it again (keep_safe) until the chamber takes it.
  void owe_safe_setpoint(bool owed) { safe_setpoint_owed_ = owed; }
  void keep_safe(double safe_setpoint_c, uint64_t tick);

 private:
  // Reads the chamber's units register (every tick: the units can be
  // changed at the controller, and a set point written in the wrong unit
  // would move the chamber far off). False while it does not answer or
  // serves neither °C nor °F.
  bool chamber_units_known();
  void note_link(const drivers::PolledDevice& device, bool ok, std::optional<double>& lost_since_s,
                 double now_s);

  std::unique_ptr<drivers::Chamber> chamber_;
  std::unique_ptr<drivers::ShellProbes> probes_;
  Links links_;

  bool chamber_ok_ = true, probes_ok_ = true;
  // The unit the chamber serves temperatures in, from its units register
  // (ChamberMap::units, read every tick; °C without one). Unknown until
  // read, after a failed chamber read, and while the register holds neither
  // °C nor °F (then the chamber is not used: no readings, no set point
  // writes).
  std::optional<drivers::TemperatureUnit> chamber_unit_;
  std::optional<double> refused_units_code_;  // logged once per value
  // Station and wall (monotonic) time of the last good reading.
  double chamber_ok_s_ = 0, probes_ok_s_ = 0;
  double chamber_ok_wall_s_ = 0, probes_ok_wall_s_ = 0;
  // Station time a device stopped answering (its gap, in the event log).
  std::optional<double> chamber_lost_s_, probes_lost_s_;

  std::optional<double> last_written_setpoint_c_;
  int ticks_since_setpoint_write_ = 0;
  // The value and result of the last attempt, and its control tick: a set
  // point is written at most once in each.
  uint64_t setpoint_attempt_tick_ = 0;
  double setpoint_attempt_c_ = 0;
  Status setpoint_attempt_status_;
  // Failed writes in a row, since when (station time).
  int setpoint_failures_ = 0;
  double setpoint_failing_since_s_ = 0;
  bool safe_setpoint_owed_ = false;
};

}  // namespace gyrotherm::station
