// Fault injection on command: the simulator's control socket
// ([simulator] control_socket, docs/simulator.md).
//
// A Unix-domain stream socket taking one text command per line and answering
// each with one line: "ok", "ok <json>" or "error <message>". Three layers,
// kept apart as in Beast's example servers:
//   parse_control_command()  line -> ControlCommand or an error (pure)
//   execute_control_command() ControlCommand -> reply, on a Simulator
//   ControlServer            the socket: clients, lines, limits
// plus send_control_command(), the client side (gyrotherm-sim ctl, tests).
#pragma once

#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "gyrotherm/core/result.h"
#include "gyrotherm/sim/simulator.h"

namespace gyrotherm::sim {

struct ControlCommand {
  enum class Kind {
    kModbusDown,   // modbus down
    kModbusUp,     // modbus up
    kModbusDelay,  // modbus delay WALL_S         value = wall seconds
    // The gyro-line commands take an optional serial: `pty close [SN]`,
    // `frames corrupt P [SN]`, or as `gyro close [SN]`, `gyro corrupt [SN] P`.
    kPtyClose,         // pty close
    kPtyReopen,        // pty reopen
    kPtyHold,          // pty hold
    kPtyRelease,       // pty release
    kFramesCorrupt,    // frames corrupt P            value = probability
    kFramesDrop,       // frames drop P               value = probability
    kProbeStall,       // probe stall top|side [SN]   probe (SN: that DUT's own)
    kProbeRelease,     // probe release top|side [SN] probe
    kChamberAlarmOn,   // chamber alarm on
    kChamberAlarmOff,  // chamber alarm off
    kChamberForce,     // chamber force TEMP_C        value = °C
    kChamberRelease,   // chamber release
    kChamberUnitsC,    // chamber units c
    kChamberUnitsF,    // chamber units f
    kTableFault,       // table fault
    kTableHang,        // table hang
    kTableDisconnect,  // table disconnect
    kTableConnect,     // table connect
    kTableClear,       // table clear
    kTableStatus,      // table status
    kStatus,           // status
    kHelp,             // help
  };
  Kind kind = Kind::kHelp;
  double value = 0;
  ProbeRole probe = ProbeRole::kTop;
  // The DUT a gyro-line command (pty ..., frames ..., gyro ...) is for, by
  // serial; not given: the first DUT. For probe ...: the DUT whose own probe
  // it is; not given: the station's probe.
  std::string dut{};
  bool dut_given = false;
};

// Ranges the parser accepts.
inline constexpr double kMaxModbusDelayS = 600.0;  // wall seconds
inline constexpr double kMinForcedChamberC = -100.0;
inline constexpr double kMaxForcedChamberC = 200.0;

// One command line (without its newline; a trailing '\r' and surrounding
// blanks are ignored; words are separated by spaces or tabs; lower case).
// Permanent error naming what was wrong: the unknown word, the missing or
// extra argument, the value that is not a number or out of range.
Result<ControlCommand> parse_control_command(std::string_view line);

// Runs `command` on `sim` and returns the reply line (no newline): "ok",
// "ok <json>" (status, help, pty reopen) or "error <message>".
std::string execute_control_command(Simulator& sim, const ControlCommand& command);

// parse + execute: the reply to one line.
std::string handle_control_line(Simulator& sim, std::string_view line);

// The status as one line of JSON (the "status" reply without "ok "); with a
// table served it has a "table" object (table_status_json()).
std::string status_json(const SimulatorStatus& status);
// The table's part: mode, interlock, rate, position, demand, limits, faults.
std::string table_status_json(const TableStatus& table);

// Every command with a one-line description, in help order.
struct ControlCommandHelp {
  const char* usage;
  const char* description;
};
const std::vector<ControlCommandHelp>& control_commands();

struct ControlServerStats {
  uint64_t connections = 0;  // accepted, total
  uint64_t active_connections = 0;
  uint64_t refused_connections = 0;  // over max_clients
  uint64_t lines = 0;                // command lines answered
  uint64_t oversize_lines = 0;       // lines over max_line_bytes (client disconnected)
};

class ControlServer {
 public:
  // Gets one line (no newline, at most max_line_bytes) and returns the reply
  // line (no newline). Runs on the server thread, one line at a time.
  using Handler = std::function<std::string(std::string_view line)>;
  struct Options {
    std::string path;  // relative paths are relative to the working directory
    std::size_t max_line_bytes = 4096;
    std::size_t max_clients = 16;
    // A client that leaves more than this many reply bytes unread is dropped.
    std::size_t max_pending_reply_bytes = 1 << 16;
  };

  // Creates the parent directory, replaces a stale socket file (one nobody
  // listens on), binds (mode 0600) and listens; clients wait in the backlog
  // until serve(). Permanent error when the path is too long or is another
  // kind of file, transient when a live process listens on it or the socket
  // cannot be bound.
  static Result<std::unique_ptr<ControlServer>> open(Options options);
  ~ControlServer();  // stop()
  ControlServer(const ControlServer&) = delete;
  ControlServer& operator=(const ControlServer&) = delete;

  // Starts the server thread (once). A line longer than max_line_bytes gets
  // "error line longer than N bytes" and the client is disconnected; a
  // client's last line without a newline is answered when it shuts down its
  // side. Over max_clients, a new client gets "error too many control
  // connections" and is closed.
  void serve(Handler handler);
  // Idempotent: closes every connection, joins the thread and removes the
  // socket file (unless someone replaced it).
  void stop();

  const std::string& path() const { return options_.path; }
  ControlServerStats stats() const;

 private:
  struct Client;
  explicit ControlServer(Options options);
  void run();
  void accept_clients();
  // Reads what the client sent and answers complete lines; false = drop it.
  bool read_client(Client& client);
  bool flush_client(Client& client);
  void answer(Client& client, std::string_view line);
  void wake();

  Options options_;
  Handler handler_;
  int listen_fd_ = -1;
  int wake_fd_ = -1;  // eventfd
  uint64_t socket_dev_ = 0;
  uint64_t socket_ino_ = 0;
  std::vector<Client> clients_;  // server thread only
  std::thread thread_;
  std::atomic<bool> stopping_{false};
  std::mutex stop_mu_;
  mutable std::mutex stats_mu_;
  ControlServerStats stats_;
};

// Client: connects to `socket_path`, sends `command` and a newline, and
// returns the reply line (without its newline). Transient error when the
// socket cannot be reached or no full reply comes within `timeout` (wall);
// permanent when `command` holds a newline.
Result<std::string> send_control_command(
    const std::string& socket_path, std::string_view command,
    std::chrono::milliseconds timeout = std::chrono::seconds(5));

}  // namespace gyrotherm::sim
