// AcutrolTable: an Acutronic ACUTROL3000 / ACT2000 axis, speaking ACL
// (acl.h) over a ByteLink (byte_link.h). By default TCP to the controller's
// Ethernet port (TM-9384C: 192.168.53.1, port 9878); or a serial line
// ([table] transport = "serial"): TM-9411's RS-232 interface, a box that
// takes ACL on RS-232 (9600 8N1 by default) and carries it to that same
// Ethernet port, for a host that only has RS-232.
//
// Each connection (each opening of the link) starts with `*IDN?`, whose
// reply shows how replies are framed (acl::detect_first_reply): a framing
// other than reply_header's is refused, naming the one seen and what was
// received. Remote control
// (`:U:L ON`, TM-8004 §4.14.2: the operator panel is locked out) is taken
// before the first motion command (set_rate, set_position) of a connection
// and handed back by release_control() (`:U:L OFF`), which the station
// calls in the safe state; the destructor hands it back too when it is
// still held on a live connection.
//
// Each operation is one or a few request/reply exchanges under a mutex, so
// calls may come from several threads. A lost link, a reply that does not
// come within TableConnection::timeout_s, or a malformed reply drops the
// connection; later calls reconnect by themselves, no sooner than a backoff
// (0.5 s, doubling to 10 s, measured on the WallClock's monotonic seconds,
// reset by a success) and return a transient error meanwhile. A reply with
// a non-zero error code is a permanent error naming the command, the code
// and the controller's text for it (`:Q:E? <code>`); when that query goes
// unanswered the error still names the code, the connection is reopened at
// once (not as a link failure) and the query is not asked again. Errors
// start with the device's name. docs/table.md lists the commands each
// operation sends.
#pragma once

#include <chrono>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/drivers/acl.h"
#include "gyrotherm/drivers/byte_link.h"
#include "gyrotherm/drivers/rate_table.h"

namespace gyrotherm::drivers {

class LinkHealth;

class AcutrolTable final : public RateTable {
 public:
  // Does not connect (connect() or the first call does). `clock` times the
  // reconnect backoff; it must outlive the table. A bad connection
  // (reply_header unknown, axis < 1, a link make_table_link() refuses: a
  // port out of range, no serial device) makes every call fail with a
  // permanent error naming it.
  AcutrolTable(TableConnection connection, std::string name = "table",
               const WallClock& clock = system_wall_clock());
  ~AcutrolTable() override;

  const std::string& name() const override { return name_; }
  // Connects now (ignoring a pending backoff) and identifies the controller
  // (`*IDN?`, checking the reply framing).
  Status connect() override;
  DeviceHealth health() const override;
  // The controller's answer to `*IDN?` ("" before the first connection).
  std::string identity() const;

  Result<TableState> read() override;
  // Refuses |rate| beyond limits() before sending; takes remote control
  // (`:U:L ON`) unless this connection has it; closes the interlock first
  // when it is open (`:I? a`, `:I:C a`); then `:D:R a,r;:M:R a`.
  Status set_rate(double rate_dps) override;
  Status set_position(double position_deg) override;  // as set_rate; `:D:P a,p;:M:P a`
  Status stop() override;                             // `:M:O a`
  Status servo_off() override;                        // `:I:O a`
  Status reset_faults() override;                     // `:I:R`
  // `:L:R? R,a;:L:A? R,a;:L:V? R,a`; cached after the first success.
  Result<TableLimits> limits() override;
  // `:U:L OFF` when remote control was taken and not handed back yet
  // (reconnecting if need be, as any call); else nothing is sent.
  Status release_control() override;

 private:
  using Steady = std::chrono::steady_clock;

  // All below: mu_ held.
  bool is_open() const;
  Steady::time_point deadline() const;  // timeout_s from now
  std::string where() const;            // "name (address)", for messages
  Status ensure_connected(bool ignore_backoff);
  // `*IDN?` on a new connection; checks the framing of its reply.
  Status first_contact();
  void close_link();
  void drop(const std::string& why);  // close_link() + a link failure
  // Sends `command` and its line end; the reason when it cannot.
  std::optional<std::string> send_line(const std::string& command, Steady::time_point deadline);
  // Appends what arrives (one read) to `into`; the reason when nothing does.
  std::optional<std::string> receive(Steady::time_point deadline, std::string& into);
  // One request/reply. A non-zero code: permanent error with the
  // controller's text; link trouble: transient, connection dropped.
  Result<std::string> exchange(const std::string& command);
  // Link trouble drops the connection as a link failure, or with
  // `failure_is_link_failure` false, closes it for a reconnect at once.
  Result<acl::Reply> roundtrip(const std::string& command, bool failure_is_link_failure = true);
  Status take_remote_locked();
  Result<TableLimits> limits_locked();
  Status servo_on_locked();
  Status simple_command(const std::string& command);
  Error named(const std::string& command, const Error& e) const;

  TableConnection connection_;
  std::string name_;
  std::optional<Error> config_error_;
  acl::ReplyFraming framing_ = acl::ReplyFraming::kAscii;  // reply_header
  acl::ReplyDecoder decoder_;
  mutable std::mutex mu_;
  std::unique_ptr<ByteLink> link_;  // null: config_error_ says why
  std::unique_ptr<LinkHealth> health_;
  std::optional<TableLimits> limits_;
  std::string identity_;
  bool remote_on_connection_ = false;   // `:U:L ON` answered on this connection
  bool remote_held_ = false;            // taken and not handed back (across reconnects)
  bool error_text_unanswered_ = false;  // `:Q:E?` got no answer once: not asked again
};

}  // namespace gyrotherm::drivers
