// AclPeer: an Acutronic ACUTROL3000 axis controller for tests, written from
// the public manuals, not from our simulator (sim/): TM-8004 "ACUTROL3000
// Command Language" (command tree and short forms §2.1, `*IDN?` §3.4,
// interlock §4.5 with its state {Close|Open|Fault} §4.5.3, limits §4.6,
// modes §4.7 with `:M? 1` answering `P`, `:Q:E?` §4.9.1, read §4.10,
// `:U:L {ON|OFF}` §4.14.2), TM-9384C (TCP port) and TM-9389 (release
// notes: commands without data answer CR/LF). It listens on 127.0.0.1, port
// chosen by the system, one client at a time (a new connection replaces the
// old one), or with Options::transport kPty answers on a pseudo-terminal
// (TM-9411: ACL on RS-232; peer_end.h), and logs every command it receives,
// in order.
//
// What the manuals leave open is a knob (Options): the reply framing, the
// word for a closed interlock, the mode words, what a command without data
// answers, whether `:Q:E?` is answered at all. Error codes are the peer's
// own (the manual's error queue section is "TBD"): kUnknownCommand, or what
// refuse() sets.
//
// Thread-safe: the server runs on its own thread; every public method may
// be called from the test's.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "peer_end.h"

namespace gyrotherm::testing {

class AclPeer {
 public:
  enum class Framing {
    kAscii,     // 4 ASCII digits of error code, 4 of length, the payload
    kBinaryLe,  // uint32 code, uint32 length, little-endian, the payload
    kBinaryBe,  // the same, big-endian
    kLine,      // the payload and CR LF, no header, no error code
  };
  enum class CommandAnswer {
    kCrLf,   // CR LF as the payload (TM-9389, build 1848)
    kOk,     // "OK" (what AcutronicRobotics/acutrol's ac117.json expects)
    kEmpty,  // an empty payload
  };
  enum class Interlock { kOpen, kClosed, kFault };
  enum class Mode { kOff, kRate, kPosition };

  struct Options {
    // kTcp: port(); kPty: device(), a serial line.
    PeerEnd::Transport transport = PeerEnd::Transport::kTcp;
    Framing framing = Framing::kAscii;
    // How `:I? a` says closed: "Close" (TM-8004 §4.5.3) or "Closed".
    std::string closed_word = "Close";
    // `:M? a`: "P"/"R"/"O" as the manual's example, or "Position"/"Rate"/"Off".
    bool long_mode_words = false;
    CommandAnswer command_answer = CommandAnswer::kCrLf;
    // False: a line with `:Q:E?` in it gets no reply at all.
    bool answer_error_query = true;
    // Replaces the whole framed reply to `*IDN?` (e.g. an unknown framing).
    std::optional<std::string> idn_reply_bytes;
    std::string idn = "Acutronic R&D USA,Acutrol3000,0,A8800-001-01.000-a";  // §3.4's example
    int axes = 1;
    // Rate mode limits answered by `:L:R? R,a`, `:L:A? R,a`, `:L:V? R,a`.
    double rate_limit_dps = 500.0;
    double accel_limit_dps2 = 1000.0;
    double trip_rate_dps = 550.0;
  };

  struct State {
    bool lockout = false;  // `:U:L ON` / `OFF`
    Interlock interlock = Interlock::kOpen;
    Mode mode = Mode::kOff;
    double demand_rate_dps = 0;
    double demand_position_deg = 0;
    // What `:R:R?` / `:R:P?` answer: the demand once in that mode (the peer
    // has no dynamics), 0 rate otherwise; set_state() to change.
    double rate_dps = 0;
    double position_deg = 0;
  };

  struct Entry {
    std::string command;  // one ';'-separated command, as received, trimmed
    int connection = 0;   // 1 for the first connection accepted, ...
    std::chrono::steady_clock::time_point at;
  };

  static constexpr uint32_t kUnknownCommand = 100;  // the peer's own code
  static constexpr uint32_t kBadAxis = 101;
  static constexpr uint32_t kFaulted = 102;  // closing a faulted interlock

  AclPeer();
  explicit AclPeer(Options options);
  ~AclPeer();
  AclPeer(const AclPeer&) = delete;
  AclPeer& operator=(const AclPeer&) = delete;

  int port() const { return end_->port(); }              // kTcp
  std::string device() const { return end_->device(); }  // kPty
  // TCP connections accepted so far (a pty: 1).
  int connections() const { return end_->connections(); }

  // Every command received so far, in order.
  std::vector<Entry> log() const;
  std::vector<std::string> commands() const;
  // Commands of connection `n` (from 1).
  std::vector<std::string> commands_of(int connection) const;
  void clear_log();

  State state() const;
  void set_state(const State& state);
  // Commands whose text starts with `prefix` (case-insensitive) are refused
  // with `code`; `:Q:E? code` answers `text`.
  void refuse(std::string prefix, uint32_t code, std::string text);

 private:
  struct Refusal {
    std::string prefix;
    uint32_t code;
    std::string text;
  };
  struct Outcome {
    uint32_t code = 0;
    std::optional<std::string> value;  // a query's answer
  };

  void run();
  // The framed reply to one line, or nullopt for none.
  std::optional<std::string> answer_line(const std::string& line, int connection);
  Outcome execute(const std::string& path, bool query, const std::vector<std::string>& args);
  std::string frame(uint32_t code, const std::string& payload) const;

  Options options_;
  std::unique_ptr<PeerEnd> end_;
  std::atomic<bool> stop_{false};
  mutable std::mutex mu_;  // below
  State state_;
  std::vector<Entry> log_;
  std::vector<Refusal> refusals_;
  std::thread thread_;
};

}  // namespace gyrotherm::testing
