// The simulated rate table reached the way an Ideal Aerosmith AERO-series
// controller is: three-letter mnemonics on a serial line, here the master of
// a pseudo-terminal (drivers::Pty) whose slave path the station opens as it
// would a UART (docs/simulator.md, "The rate table").
//
// No manual was found; the grammar follows the public script
// actigraph/RateTableSweepGUI (RateSweepGUI.py, class IdealAerosmithTable):
// a request is MNEMONIC[number] ending "\r\n" (or "\r" or "\n"); every
// request is answered by a reply line ending "\r" and then the prompt line
// ">\r"; a reply of "?" means an error (unknown mnemonic, missing or extra
// number, a demand beyond the limits, a motion command while the interlock
// is in fault).
//   PVE       measured rate, °/s          PPO      position, °, [0, 360)
//   STA       status: 0 healthy; bit 0 = interlock fault, bit 1 = not servoed
//   JOG±n     servo on, rate mode at n °/s         MOV n   servo on, move to n °
//   STO       stop (off mode: decelerate, stay servoed)
//   ACL n     acceleration limit, °/s²             VEL n   rate limit, °/s
//   HOM       servo on, move to 0 °
//   RST       clear a latched fault (the simulator's own: no public source)
// Commands without a value answer an empty reply line. RateSweepGUI.py does
// not read a reply after JOG (it sends STA and discards two lines); a
// client that does the same stays in step, as every request here gets
// exactly one reply and one prompt.
#pragma once

#include <atomic>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <thread>

#include "gyrotherm/core/result.h"
#include "gyrotherm/drivers/pty.h"
#include "gyrotherm/sim/rate_table_model.h"

namespace gyrotherm::sim {

// The reply to one request line (without its line end), framed: the reply
// line + "\r" + ">\r". All or none on `table`.
std::string handle_aero_line(RateTableModel& table, std::string_view line);

class AeroServer {
 public:
  // Gets one request line and returns the framed reply. Runs on the
  // server's thread.
  using Handler = std::function<std::string(std::string_view line)>;
  // Opens a pty and starts the thread. Transient error when no pty can be
  // allocated.
  static Result<std::unique_ptr<AeroServer>> start(Handler handler);
  ~AeroServer();  // stop()
  AeroServer(const AeroServer&) = delete;
  AeroServer& operator=(const AeroServer&) = delete;
  void stop();  // idempotent; hang-up for the reader

  const std::string& device() const { return pty_.slave_path(); }
  // Silent: requests are read and dropped unanswered (the table's hang and
  // disconnect faults: a serial line cannot be refused).
  void set_silent(bool silent) { silent_.store(silent); }
  uint64_t requests() const { return requests_.load(); }

 private:
  AeroServer(drivers::Pty pty, Handler handler);
  void run();

  drivers::Pty pty_;
  Handler handler_;
  int wake_fd_ = -1;
  std::atomic<bool> silent_{false};
  std::atomic<bool> stopping_{false};
  std::atomic<uint64_t> requests_{0};
  std::mutex stop_mu_;
  std::thread thread_;
};

}  // namespace gyrotherm::sim
