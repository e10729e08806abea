#include "aero_peer.h"

#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdio>

namespace gyrotherm::testing {
namespace {

std::string aero_number(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.4f", v);
  return buf;
}

}  // namespace

AeroPeer::AeroPeer() : AeroPeer(Options{}) {}

AeroPeer::AeroPeer(Options options)
    : options_(options), end_(std::make_unique<PeerEnd>(options_.transport)) {
  state_.rate_dps = 0;
  thread_ = std::thread([this] { run(); });
}

AeroPeer::~AeroPeer() {
  stop_ = true;
  thread_.join();
}

std::vector<AeroPeer::Entry> AeroPeer::log() const {
  std::lock_guard lock(mu_);
  return log_;
}

std::vector<std::string> AeroPeer::commands() const {
  std::vector<std::string> out;
  for (const Entry& e : log()) out.push_back(e.command);
  return out;
}

AeroPeer::State AeroPeer::state() const {
  std::lock_guard lock(mu_);
  return state_;
}

void AeroPeer::set_status(int status) {
  std::lock_guard lock(mu_);
  options_.status = status;
}

int AeroPeer::answer_held() {
  std::vector<std::string> held;
  {
    std::lock_guard lock(mu_);
    held.swap(held_);
  }
  for (const std::string& bytes : held) send(bytes);
  return static_cast<int>(held.size());
}

void AeroPeer::send(const std::string& bytes) { end_->send(bytes); }

void AeroPeer::run() {
  std::string buf;
  while (!stop_) {
    PeerEnd::Received in = end_->receive(10);
    if (in.new_connection) buf.clear();
    buf += in.bytes;
    // A command ends at CR (RateSweepGUI.py sends CR LF); the LF is skipped.
    for (auto end = buf.find_first_of("\r\n"); end != std::string::npos;
         end = buf.find_first_of("\r\n")) {
      const std::string command = buf.substr(0, end);
      buf.erase(0, end + 1);
      if (command.empty()) continue;
      {
        std::lock_guard lock(mu_);
        log_.push_back({command, std::chrono::steady_clock::now()});
      }
      std::string out = options_.echo ? command + "\r\n" : std::string();
      out += answer(command) + "\r>\r";
      const std::string mnemonic = command.substr(0, 3);
      if (!options_.answer_motion_at_once && (mnemonic == "JOG" || mnemonic == "STO")) {
        std::lock_guard lock(mu_);
        held_.push_back(out);
        continue;
      }
      send(out);
    }
  }
}

std::string AeroPeer::answer(const std::string& command) {
  if (command.size() < 3) return "?";
  std::string mnemonic = command.substr(0, 3);
  for (char& c : mnemonic) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  const std::string arg = command.substr(3);
  std::optional<double> number;
  if (!arg.empty()) {
    double v = 0;
    const char* first = arg.data();
    if (*first == '+') ++first;
    const auto [end, ec] = std::from_chars(first, arg.data() + arg.size(), v);
    if (ec != std::errc() || end != arg.data() + arg.size()) return "?";
    if (v != std::trunc(v)) {
      if (options_.decimals == Decimals::kRefuse) return "?";
      if (options_.decimals == Decimals::kTruncate) v = std::trunc(v);
    }
    number = v;
  }
  std::lock_guard lock(mu_);
  if (mnemonic == "JOG" && number) {
    state_.rate_dps = *number;
    return "";
  }
  if (mnemonic == "MOV" && number) {
    state_.rate_dps = 0;
    state_.position_deg = *number;
    return "";
  }
  if (number) return "?";
  if (mnemonic == "STO") {
    state_.rate_dps = 0;
    return "";
  }
  if (mnemonic == "PVE") return aero_number(state_.rate_dps);
  if (mnemonic == "PPO") return aero_number(state_.position_deg);
  if (mnemonic == "STA") return std::to_string(options_.status);
  return "?";
}

}  // namespace gyrotherm::testing
