// AcutrolTable: an Acutronic ACUTROL3000 / ACT2000 axis over TCP, speaking
// ACL (acl.h) to the controller's Ethernet port (TM-9384C, port 9878) or to
// a serial-to-TCP bridge on its RS-232 port (TM-9411).
//
// Each operation is one or a few request/reply exchanges under a mutex, so
// calls may come from several threads. A lost link, a reply that does not
// come within TableConnection::timeout_s, or a malformed reply drops the
// connection; later calls reconnect by themselves, no sooner than a backoff
// (0.5 s, doubling to 10 s, measured on the WallClock's monotonic seconds,
// reset by a success) and return a transient error meanwhile. A reply with
// a non-zero error code is a permanent error naming the command, the code
// and the controller's text for it (`:Q:E? <code>`). Errors start with the
// device's name. docs/table.md lists the commands each operation sends.
#pragma once

#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/drivers/acl.h"
#include "gyrotherm/drivers/rate_table.h"

namespace gyrotherm::drivers {

class TableLink;

class AcutrolTable final : public RateTable {
 public:
  // Does not connect (connect() or the first call does). `clock` times the
  // reconnect backoff; it must outlive the table. A bad connection
  // (reply_header unknown, axis < 1, port out of range) makes every call
  // fail with a permanent error naming it.
  AcutrolTable(TableConnection connection, std::string name = "table",
               const WallClock& clock = system_wall_clock());
  ~AcutrolTable() override;

  const std::string& name() const override { return name_; }
  // Connects now (ignoring a pending backoff) and takes remote control
  // (`:U:L ON`).
  Status connect() override;
  DeviceHealth health() const override;

  Result<TableState> read() override;
  // Refuses |rate| beyond limits() before sending; closes the interlock
  // first when it is open (`:I? a`, `:I:C a`); then `:D:R a,r;:M:R a`.
  Status set_rate(double rate_dps) override;
  Status set_position(double position_deg) override;  // `:D:P a,p;:M:P a`
  Status stop() override;                             // `:M:O a`
  Status servo_off() override;                        // `:I:O a`
  Status reset_faults() override;                     // `:I:R`
  // `:L:R? R,a;:L:A? R,a;:L:V? R,a`; cached after the first success.
  Result<TableLimits> limits() override;

 private:
  // All below: mu_ held.
  Status ensure_connected(bool ignore_backoff);
  Status open_socket();
  void drop(const std::string& why);
  // One request/reply. A non-zero code: permanent error with the
  // controller's text; link trouble: transient, connection dropped.
  Result<std::string> exchange(const std::string& command);
  Result<acl::Reply> roundtrip(const std::string& command);
  Result<TableLimits> limits_locked();
  Status servo_on_locked();
  Status simple_command(const std::string& command);
  Error named(const std::string& command, const Error& e) const;

  TableConnection connection_;
  std::string name_;
  std::optional<Error> config_error_;
  acl::ReplyDecoder decoder_;
  mutable std::mutex mu_;
  std::unique_ptr<TableLink> link_;
  int fd_ = -1;
  std::optional<TableLimits> limits_;
};

}  // namespace gyrotherm::drivers
