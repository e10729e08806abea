// The simulated rate table's controller, as an Acutronic ACUTROL3000 speaks
// it: ACL (Acutrol Command Language, Acutronic TM-8004) over TCP on
// loopback (docs/simulator.md, "The rate table").
//
// Three layers, kept apart as in the control socket (control_server.h):
//   parse_acl()      one request line -> the commands of its chain (pure)
//   execute_acl()    the commands -> one reply, on a RateTableModel: every
//                    command of a chain runs in the same controller frame,
//                    all or none (a chain with an error changes nothing)
//   frame_acl_reply() reply -> bytes, by [simulator.table] reply_header
//   TableServer      the TCP socket: clients, lines, the hang and
//                    disconnect faults
// This parser is written from the manual, independently of the station's
// driver: the simulator is the peer the driver is tested against.
//
// Grammar (TM-8004 §2, §2.1-2.3): a request is a line ending "\r\n" or
// "\n"; ';' separates the commands of a chain; a command is a header and
// comma-separated arguments after white space. Headers are case-insensitive
// and any leading part of a mnemonic is accepted (":Demand:Rate",
// ":Dem:Rate", ":D:R"). A header starting with ':' starts at the root; one
// without (after ';') stays in the previous command's subsystem (§2.2.2:
// ":Mode:Position 1;Rate 2", ":I:C 1;C 2"). The first argument is the axis:
// only axis 1 exists (ALL is taken for commands, as 1).
//
// Reply codes (the payload is empty unless the code is 0):
//   0 OK; 1 unknown command or bad syntax; 2 no such axis; 3 parameter out
//   of range (a demand or limit beyond the table's); 4 refused in this state
//   (closing the interlock from fault before :I:R); 5 wrong number of
//   arguments or an argument that is not a number.
// ":Q:E? code" answers the code's text.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <thread>
#include <variant>
#include <vector>

#include "gyrotherm/core/result.h"
#include "gyrotherm/sim/rate_table_model.h"

namespace gyrotherm::sim {

enum AclCode : int {
  kAclOk = 0,
  kAclUnknownCommand = 1,
  kAclBadAxis = 2,
  kAclOutOfRange = 3,
  kAclRefused = 4,
  kAclBadArguments = 5,
};
// The text ":Q:E? code" answers ("unknown error code N" for others).
std::string acl_error_text(int code);

inline constexpr const char* kAclIdentity = "Gyrotherm,SIM-ACT3000,0001,1.0";

enum class AclOp {
  kIdn,                // *IDN?
  kStb,                // *STB?
  kLockout,            // :Utility:Lockout ON|OFF   (query: ON|OFF)
  kInterlockQuery,     // :Interlock? a
  kInterlockReset,     // :Interlock:Reset
  kInterlockClose,     // :Interlock:Close a
  kInterlockOpen,      // :Interlock:Open a
  kModeQuery,          // :Mode? a
  kModeRate,           // :Mode:Rate a
  kModePosition,       // :Mode:Position a
  kModeOff,            // :Mode:Off a
  kDemandRate,         // :Demand:Rate a,x   (query: :D:R? a)
  kDemandPosition,     // :Demand:Position a,x
  kReadPosition,       // :Read:Position? a
  kReadRate,           // :Read:Rate? a
  kReadAcceleration,   // :Read:Acceleration? a
  kLimitRate,          // :Limit:Rate m,a,x      (query: m,a)
  kLimitAcceleration,  // :Limit:Acceleration m,a,x
  kLimitVelocityTrip,  // :Limit:VelocityTrip m,a,x (also :L:Vtrip)
  kQueryError,         // :Query:Error? code
};

struct AclCommand {
  AclOp op = AclOp::kIdn;
  bool query = false;
  std::vector<std::string> args;
};

struct AclReply {
  int code = kAclOk;
  std::string payload;
};

// The commands of one request line (without its line end), or the error
// reply (code 1: unknown header or bad syntax; 5: argument count).
std::variant<std::vector<AclCommand>, AclReply> parse_acl(std::string_view line);

// Controller state outside the axis.
struct AclControllerState {
  bool lockout = false;  // :U:L
};

// Runs `commands` on `table` as one frame: all or none. Queries answer
// their values joined by ';' (rates and positions with 6 decimals); a chain
// without a query answers "OK".
AclReply execute_acl(RateTableModel& table, AclControllerState& controller,
                     const std::vector<AclCommand>& commands);

// parse + execute.
AclReply handle_acl_line(RateTableModel& table, AclControllerState& controller,
                         std::string_view line);

// The bytes of `reply` under `header`: "ascii" = 4 ASCII decimal digits of
// code, 4 of payload length, payload; "binary-le"/"binary-be" = code and
// length as 32-bit integers, then the payload; "line" = payload + LF (an
// error answers "ERR <code>" + LF, there being no header to carry it).
std::string frame_acl_reply(const AclReply& reply, std::string_view header);

struct TableServerStats {
  uint64_t connections = 0;
  uint64_t refused_connections = 0;  // while disconnected, or over max_clients
  uint64_t requests = 0;             // lines answered
  uint64_t unanswered = 0;           // lines dropped while hung
};

// A TCP server on a loopback address answering ACL lines through a handler.
class TableServer {
 public:
  // Gets one line (no line end) and returns the framed reply bytes. Runs on
  // the server thread, one line at a time.
  using Handler = std::function<std::string(std::string_view line)>;
  struct Options {
    std::string host = "127.0.0.1";
    int port = 0;  // 0 = any free port
    std::size_t max_line_bytes = 4096;
    std::size_t max_clients = 8;
    Handler handler;
  };
  // Binds, listens and starts the thread. Transient error when the port
  // cannot be bound.
  static Result<std::unique_ptr<TableServer>> start(Options options);
  ~TableServer();  // stop()
  TableServer(const TableServer&) = delete;
  TableServer& operator=(const TableServer&) = delete;
  void stop();  // idempotent

  int port() const { return port_; }
  // Hang: lines are read and dropped unanswered; connections stay open.
  void set_hung(bool hung) { hung_.store(hung); }
  bool hung() const { return hung_.load(); }
  // Disconnected: every client is closed, and new connections are accepted
  // and closed at once, until set false.
  void set_disconnected(bool disconnected);
  bool disconnected() const { return disconnected_.load(); }
  TableServerStats stats() const;

 private:
  struct Client;
  explicit TableServer(Options options);
  void run();
  void wake();

  Options options_;
  int listen_fd_ = -1;
  int wake_fd_ = -1;
  int port_ = 0;
  std::atomic<bool> hung_{false};
  std::atomic<bool> disconnected_{false};
  std::atomic<bool> stopping_{false};
  std::thread thread_;
  std::mutex stop_mu_;
  mutable std::mutex stats_mu_;
  TableServerStats stats_;
};

}  // namespace gyrotherm::sim
