// AeroPeer: an Ideal Aerosmith AERO-series rate table controller for
// tests, on a real pseudo-terminal (drivers::Pty: the master side is the
// controller, device() the serial line a driver opens), or with
// Options::transport kTcp behind a serial device server on 127.0.0.1
// (port(); peer_end.h). No manual of the
// family is public; the peer follows the one public driver,
// actigraph/RateTableSweepGUI (`RateSweepGUI.py`, class
// IdealAerosmithTable), not our simulator (sim/): a command is a
// three-letter mnemonic and an optional number, ended by CR LF; the answer
// is a line ended by CR, then the prompt `>` and CR; a `?` in the answer is
// a refusal. Known here: JOG<rate> (rate mode, °/s), MOV<deg>, STO (stop),
// PVE (rate), PPO (position), STA (status word, 0 healthy). Anything else
// is refused with `?`.
//
// It logs every command line it receives, in order. Knobs (Options) cover
// what the public code leaves open: whether decimals are taken, truncated
// or refused; an echo of each command line before its answer; JOG answered
// late (on demand) or not at all.
//
// Thread-safe: the peer reads on its own thread; every public method may be
// called from the test's.
#pragma once

#include <atomic>
#include <chrono>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "peer_end.h"

namespace gyrotherm::testing {

class AeroPeer {
 public:
  enum class Decimals {
    kAccept,    // JOG7.5 spins at 7.5 °/s
    kTruncate,  // JOG7.5 spins at 7 °/s, answered as if all were well
    kRefuse,    // JOG7.5 is answered `?`
  };
  struct Options {
    // kPty: device(), the serial line; kTcp: port(), a serial device server.
    PeerEnd::Transport transport = PeerEnd::Transport::kPty;
    Decimals decimals = Decimals::kTruncate;
    bool echo = false;  // each command line comes back before its answer
    // False: JOG and STO answers are held until answer_held() (RateSweepGUI.py
    // does not wait for them).
    bool answer_motion_at_once = true;
    int status = 0;  // what STA answers
  };
  struct State {
    double rate_dps = 0;
    double position_deg = 0;
  };
  struct Entry {
    std::string command;  // the line without its CR LF
    std::chrono::steady_clock::time_point at;
  };

  AeroPeer();
  explicit AeroPeer(Options options);
  ~AeroPeer();
  AeroPeer(const AeroPeer&) = delete;
  AeroPeer& operator=(const AeroPeer&) = delete;

  std::string device() const { return end_->device(); }  // kPty
  int port() const { return end_->port(); }              // kTcp
  int connections() const { return end_->connections(); }
  // kTcp: ends the client's connection, as a device server whose session
  // dropped.
  void hang_up() { end_->hang_up(); }
  std::vector<Entry> log() const;
  std::vector<std::string> commands() const;
  State state() const;
  void set_status(int status);
  // Sends the answers held back (answer_motion_at_once false); how many.
  int answer_held();

 private:
  void run();
  std::string answer(const std::string& command);  // text before the prompt
  void send(const std::string& bytes);

  Options options_;
  std::unique_ptr<PeerEnd> end_;
  std::atomic<bool> stop_{false};
  mutable std::mutex mu_;  // below
  State state_;
  std::vector<Entry> log_;
  std::vector<std::string> held_;
  std::thread thread_;
};

}  // namespace gyrotherm::testing
