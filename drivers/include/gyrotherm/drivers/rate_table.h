// The rate table (turntable) as the station sees it: one servoed axis that
// holds a position or spins at a rate, with the controller's safety
// interlock and its limits.
//
// The real ones are AcutrolTable (acutrol_table.h: Acutronic ACUTROL3000 /
// ACT2000 "ACL", by default over TCP to the controller's Ethernet port) and
// AeroTable (aero_table.h: Ideal Aerosmith AERO-series mnemonics, by default
// on RS-232), each over a TCP or serial ByteLink (byte_link.h); the
// station's unit tests hand the station a fake. Angles are degrees,
// rates °/s, accelerations °/s², positive counter-clockwise seen from above
// (the controller's own sign convention: see docs/table.md).
#pragma once

#include <optional>
#include <string>
#include <string_view>

#include "gyrotherm/core/result.h"
#include "gyrotherm/drivers/devices.h"

namespace gyrotherm::drivers {

// The servo mode the controller reports.
enum class TableMode {
  kOff,       // servo holds zero rate (ACL :M:O; AERO STO) or the axis is not servoed
  kRate,      // holds a demanded rate
  kPosition,  // holds (or moves to) a demanded position
  kUnknown,   // an answer we do not know: named in TableState::mode_text
};
std::string_view to_string(TableMode mode);

// The axis' safety interlock (ACL :I? a answers Open, Closed or Fault).
enum class TableInterlock {
  kOpen,    // not servoed: the drive is off
  kClosed,  // servoed
  kFault,   // tripped (over-speed, tracking error, a safety input); latched
            // until reset_faults()
};
std::string_view to_string(TableInterlock state);

// One reading of the axis.
struct TableState {
  TableMode mode = TableMode::kUnknown;
  std::string mode_text;  // as the controller said it, for the log
  TableInterlock interlock = TableInterlock::kOpen;
  double rate_dps = 0;      // measured rate
  double position_deg = 0;  // measured position, [0, 360) for a continuous axis
  // Whatever the controller says about a fault (ACL: its error queue text,
  // AERO: the status word); "" when none.
  std::string fault;
};

// The controller's working limits for rate mode.
struct TableLimits {
  double max_rate_dps = 0;
  double max_accel_dps2 = 0;
  // Velocity trip: beyond it the controller faults the axis; nullopt where
  // the controller does not tell.
  std::optional<double> trip_rate_dps;
};

// How to reach the controller ([table] in station.toml; docs/table.md).
// The protocol (profile) and the transport under it (transport: a
// ByteLink, byte_link.h) are separate choices.
struct TableConnection {
  // "acutrol": ACL (TM-8004), by default over TCP to the controller
  // (TM-9384C: port 9878). "aero": Ideal Aerosmith mnemonics, by default on
  // a serial line (9600 8N1).
  std::string profile = "acutrol";
  // "tcp" (host, port) or "serial" (device, baud, 8N1); "" = the profile's
  // (acutrol: tcp; aero: serial). ACL on a serial line is TM-9411's RS-232
  // interface; AERO over TCP is a serial device server in front of the
  // controller's RS-232 port.
  std::string transport;
  std::string host = "192.168.53.1";  // tcp (the ACUTROL3000's address, TM-9384C)
  int port = 9878;                    // tcp
  // acutrol: how each reply is framed. The manual (TM-8004 §2) says every
  // reply on a non-GPIB interface is prefixed by an error code and a message
  // length, without the layout; public drivers skip 8 bytes. "ascii": four
  // ASCII decimal digits of error code, four of payload length, then the
  // payload. "binary-le" / "binary-be": two 32-bit integers (code, length)
  // then the payload. "line": no header, a reply is a line ending in LF (a
  // bridge that passes the GPIB-style answers). The first reply of each
  // connection (`*IDN?`) is checked against it: a controller that frames
  // otherwise is refused with the framing it uses (docs/table.md).
  std::string reply_header = "ascii";
  std::string device;      // serial: the device path
  int baud = 9600;         // serial
  int axis = 1;            // acutrol: the axis number commands name
  double timeout_s = 1.0;  // per request, wall seconds (and to connect)
};

// The transport `connection` names: its `transport`, or when that is empty
// its profile's (acutrol: "tcp", TM-9384C; aero: "serial").
std::string table_transport(const TableConnection& connection);

class RateTable : public PolledDevice {
 public:
  // Reads mode, interlock, rate and position in one exchange where the
  // protocol allows it (ACL chains the queries into one controller frame).
  virtual Result<TableState> read() = 0;
  // Servo on (closing the interlock if open) and spin at `rate_dps`,
  // profiled by the controller's acceleration and jerk limits. A rate
  // beyond limits() is refused here, before anything is sent.
  virtual Status set_rate(double rate_dps) = 0;
  // Servo on and move to `position_deg`, then hold it.
  virtual Status set_position(double position_deg) = 0;
  // Decelerates to rest (ACL :M:O; AERO STO). The axis stays servoed.
  virtual Status stop() = 0;
  // Opens the interlock (servo off). Only at rest: the station stops first
  // and waits for the rate to fall.
  virtual Status servo_off() = 0;
  // Clears latched faults (ACL :I:R), so the interlock can close again.
  virtual Status reset_faults() = 0;
  virtual Result<TableLimits> limits() = 0;
  // Hands the controller back to its operator panel: ACL `:U:L OFF`
  // (TM-8004 §4.14.2), when set_rate / set_position took remote control
  // (`:U:L ON`) and it was not handed back since; the next of them takes it
  // again. The station calls it once the table has reached its safe state
  // (after servo_off) and at shutdown. Default: no lockout to release
  // (AERO: none is known).
  virtual Status release_control() { return Status::Ok(); }
};

}  // namespace gyrotherm::drivers
