#include "gyrotherm/drivers/aero_table.h"

#include <fmt/format.h>

#include <chrono>
#include <cmath>
#include <cstdio>

#include "link_health.h"

namespace gyrotherm::drivers {

namespace {

std::string command_text(const std::string& mnemonic, std::optional<double> number) {
  std::string line = aero::command_line(mnemonic, number);
  line.resize(line.size() - 2);  // without "\r\n", for messages
  return line;
}

}  // namespace

AeroTable::AeroTable(TableConnection connection, TableLimits declared, std::string name,
                     const WallClock& clock)
    : connection_(std::move(connection)),
      declared_(declared),
      name_(std::move(name)),
      health_(std::make_unique<LinkHealth>(clock)) {
  auto link = make_table_link(connection_, name_);
  if (!link) {
    config_error_ = link.error();
  } else {
    link_ = std::move(*link);
  }
}

AeroTable::~AeroTable() = default;

DeviceHealth AeroTable::health() const {
  std::lock_guard lock(mu_);
  return health_->health();
}

std::string AeroTable::where() const {
  return fmt::format("{} ({})", name_, link_ ? link_->description() : std::string("no link"));
}

Error AeroTable::named(const std::string& command, const Error& e) const {
  return Error{fmt::format("{}: `{}`: {}", where(), command, e.message), e.transient};
}

void AeroTable::drop(const std::string& why) {
  if (link_) link_->close();
  decoder_.reset();
  pending_.reset();
  health_->on_link_failure(why);
}

Status AeroTable::ensure_open(bool ignore_backoff) {
  if (config_error_) return *config_error_;
  if (link_->is_open()) return Status::Ok();
  if (auto st = health_->open_link(*link_, deadline(), name_, where(), ignore_backoff); !st) {
    return st;
  }
  decoder_.reset();
  pending_.reset();
  return Status::Ok();
}

Status AeroTable::connect() {
  std::lock_guard lock(mu_);
  return ensure_open(/*ignore_backoff=*/true);
}

Result<std::optional<std::string>> AeroTable::await_reply(const std::string& command) {
  const auto until = deadline();
  std::string bytes;
  for (;;) {
    auto next = decoder_.next();
    if (!next) {
      Error e = named(command, next.error());
      drop(e.message);
      return e;
    }
    if (*next) return next;
    if (Steady::now() >= until) return std::optional<std::string>{};
    bytes.clear();
    auto n = link_->read_some(bytes, until);
    if (!n) {
      Error e = named(command, n.error());
      drop(e.message);
      return e;
    }
    if (*n == 0) return std::optional<std::string>{};
    decoder_.feed(bytes);
  }
}

Result<std::string> AeroTable::request(const std::string& mnemonic, std::optional<double> number,
                                       bool late_ok) {
  const std::string command = command_text(mnemonic, number);
  if (auto st = ensure_open(false); !st) return st.error();
  const auto t0 = Steady::now();
  if (pending_) {
    // The answer to an earlier JOG/STO that did not come in time.
    const std::string earlier = *pending_;
    auto late = await_reply(earlier);
    if (!late) return late.error();
    if (!*late) {
      Error e = named(earlier, Error::Transient(fmt::format("no reply within {:g} s (nor later)",
                                                            connection_.timeout_s)));
      drop(e.message);
      return e;
    }
    pending_.reset();
    const std::string_view late_text = aero::strip_echo(**late, earlier);
    if (aero::is_refusal(late_text)) {
      Error e = named(earlier, Error::Permanent(fmt::format("refused: \"{}\"", late_text)));
      health_->on_refusal(e.message);
      return e;
    }
  }
  if (auto st = link_->write_all(aero::command_line(mnemonic, number), deadline()); !st) {
    Error e = named(command, st.error());
    drop(e.message);
    return e;
  }
  auto reply = await_reply(command);
  if (!reply) return reply.error();
  if (!*reply) {
    if (late_ok) {
      pending_ = command;
      return std::string();
    }
    Error e = named(command,
                    Error::Transient(fmt::format("no reply within {:g} s", connection_.timeout_s)));
    drop(e.message);
    return e;
  }
  const std::string text(aero::strip_echo(**reply, command));
  if (aero::is_refusal(text)) {
    Error e = named(command, Error::Permanent(fmt::format("refused: \"{}\"", text)));
    health_->on_refusal(e.message);
    return e;
  }
  health_->on_success(std::chrono::duration<double, std::milli>(Steady::now() - t0).count());
  return text;
}

Result<TableState> AeroTable::read() {
  std::lock_guard lock(mu_);
  auto value = [&](const char* mnemonic) -> Result<double> {
    auto r = request(mnemonic, std::nullopt);
    if (!r) return r.error();
    auto v = aero::parse_number(*r);
    if (!v) {
      Error e = named(mnemonic, Error::Transient(v.error().message));
      drop(e.message);
      return e;
    }
    return v;
  };
  auto rate = value("PVE");
  if (!rate) return rate.error();
  auto position = value("PPO");
  if (!position) return position.error();
  auto sta = request("STA", std::nullopt);
  if (!sta) return sta.error();
  auto status = aero::parse_status(*sta);
  if (!status) {
    Error e = named("STA", Error::Transient(status.error().message));
    drop(e.message);
    return e;
  }
  TableState s;
  s.rate_dps = *rate;
  s.position_deg = *position;
  // The controller has no mode query: the mode is the last one commanded.
  s.mode = last_mode_;
  s.mode_text =
      fmt::format("{} (last commanded; AERO does not report its mode)", to_string(last_mode_));
  if (*status == 0) {
    s.interlock = TableInterlock::kClosed;
  } else {
    s.interlock = TableInterlock::kFault;
    s.fault = fmt::format("STA {}", *status);
  }
  return s;
}

Status AeroTable::set_rate(double rate_dps) {
  std::lock_guard lock(mu_);
  const std::string command = command_text("JOG", rate_dps);
  if (!std::isfinite(rate_dps)) {
    return named(command, Error::Permanent(fmt::format("{} is not a rate", rate_dps)));
  }
  if (std::fabs(rate_dps) > declared_.max_rate_dps) {
    Error e = named(command, Error::Permanent(fmt::format(
                                 "refused, not sent: |{:g}| °/s is beyond the rate limit {:g} °/s",
                                 rate_dps, declared_.max_rate_dps)));
    health_->on_local_error(e.message);
    return e;
  }
  auto whole = aero::whole_argument("JOG", rate_dps, "°/s");
  if (!whole) {
    Error e = named(command, Error::Permanent("refused, not sent: " + whole.error().message));
    health_->on_local_error(e.message);
    return e;
  }
  auto r = request("JOG", static_cast<double>(*whole), /*late_ok=*/true);
  if (!r) return r.error();
  last_mode_ = TableMode::kRate;
  return Status::Ok();
}

Status AeroTable::set_position(double position_deg) {
  std::lock_guard lock(mu_);
  const std::string command = command_text("MOV", position_deg);
  if (!std::isfinite(position_deg)) {
    return named(command, Error::Permanent(fmt::format("{} is not a position", position_deg)));
  }
  auto whole = aero::whole_argument("MOV", position_deg, "°");
  if (!whole) {
    Error e = named(command, Error::Permanent("refused, not sent: " + whole.error().message));
    health_->on_local_error(e.message);
    return e;
  }
  auto r = request("MOV", static_cast<double>(*whole));
  if (!r) return r.error();
  last_mode_ = TableMode::kPosition;
  return Status::Ok();
}

Status AeroTable::stop() {
  std::lock_guard lock(mu_);
  auto r = request("STO", std::nullopt, /*late_ok=*/true);
  if (!r) return r.error();
  last_mode_ = TableMode::kOff;
  return Status::Ok();
}

Status AeroTable::servo_off() {
  {
    std::lock_guard lock(mu_);
    if (!servo_off_noted_) {
      servo_off_noted_ = true;
      std::fprintf(stderr,
                   "%s: no servo-off command is known for AERO controllers; servo off stops the "
                   "table (STO) and leaves it servoed\n",
                   name_.c_str());
    }
  }
  return stop();
}

Status AeroTable::reset_faults() { return Status::Ok(); }

AeroTable::Steady::time_point AeroTable::deadline() const {
  return Steady::now() + std::chrono::duration_cast<Steady::duration>(
                             std::chrono::duration<double>(connection_.timeout_s));
}

Result<TableLimits> AeroTable::limits() { return declared_; }

}  // namespace gyrotherm::drivers
