// AeroTable: an Ideal Aerosmith AERO-series rate table controller, speaking
// the mnemonic grammar of aero.h over a ByteLink (byte_link.h): by default
// its serial line (9600 8N1), or ([table] transport = "tcp") a serial
// device server that carries that line over TCP.
//
// Operations: read() sends PVE (rate, °/s), PPO (position, °) and STA
// (status word: 0 is taken as healthy, anything else as a fault whose text
// is "STA <n>"; the public code does not document its bits). set_rate sends
// JOG<rate>, set_position MOV<deg>, stop STO. JOG and MOV take whole numbers
// (aero::whole_argument): a rate or position that is not one is refused
// before anything is sent, naming it. A controller that echoes each command
// line before its answer is understood (aero::strip_echo). No servo-off command is known:
// servo_off() stops the table (and says so once on stderr). No fault reset
// is known: reset_faults() does nothing and succeeds. limits() is not
// queryable: it returns the limits given at construction (the station's
// [table] max_rate_dps / max_accel_dps2).
//
// The public driver (RateSweepGUI.py) sends JOG (and STO) without waiting
// for the answer and swallows it later; here a JOG/STO answer that has not
// come within the timeout is not an error: it is awaited (and checked for
// `?`) before the next command is sent. Reconnect, backoff and health as
// AcutrolTable (acutrol_table.h). Thread-safe.
#pragma once

#include <chrono>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/drivers/aero.h"
#include "gyrotherm/drivers/byte_link.h"
#include "gyrotherm/drivers/rate_table.h"

namespace gyrotherm::drivers {

class LinkHealth;

class AeroTable final : public RateTable {
 public:
  AeroTable(TableConnection connection, TableLimits declared, std::string name = "table",
            const WallClock& clock = system_wall_clock());
  ~AeroTable() override;

  const std::string& name() const override { return name_; }
  Status connect() override;  // opens the link now
  DeviceHealth health() const override;

  Result<TableState> read() override;
  // JOG<rate>; refused beyond limits or when not a whole number.
  Status set_rate(double rate_dps) override;
  Status set_position(double position_deg) override;  // MOV<deg>; whole degrees only
  Status stop() override;                             // STO
  Status servo_off() override;                        // STO (no servo-off known)
  Status reset_faults() override;                     // nothing known: ok
  Result<TableLimits> limits() override;              // the declared limits

 private:
  using Steady = std::chrono::steady_clock;

  // All below: mu_ held.
  Steady::time_point deadline() const;  // timeout_s from now
  std::string where() const;            // "name (address)", for messages
  Status ensure_open(bool ignore_backoff);
  void drop(const std::string& why);
  // Sends `mnemonic[number]` and waits for its reply. `late_ok`: no reply in
  // time is not an error, it is awaited before the next command.
  Result<std::string> request(const std::string& mnemonic, std::optional<double> number,
                              bool late_ok = false);
  // Waits for one reply (up to the timeout). nullopt: none in time.
  Result<std::optional<std::string>> await_reply(const std::string& command);
  Error named(const std::string& command, const Error& e) const;

  TableConnection connection_;
  TableLimits declared_;
  std::string name_;
  mutable std::mutex mu_;
  std::optional<Error> config_error_;
  std::unique_ptr<ByteLink> link_;  // null: config_error_ says why
  std::unique_ptr<LinkHealth> health_;
  aero::ReplyDecoder decoder_;
  std::optional<std::string> pending_;  // a command whose reply may still come
  TableMode last_mode_ = TableMode::kUnknown;
  bool servo_off_noted_ = false;
};

}  // namespace gyrotherm::drivers
