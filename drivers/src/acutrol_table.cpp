#include "gyrotherm/drivers/acutrol_table.h"

#include <fmt/format.h>

#include <chrono>
#include <cmath>

#include "link_health.h"

namespace gyrotherm::drivers {

AcutrolTable::AcutrolTable(TableConnection connection, std::string name, const WallClock& clock)
    : connection_(std::move(connection)),
      name_(std::move(name)),
      decoder_(acl::ReplyFraming::kAscii),
      health_(std::make_unique<LinkHealth>(clock)) {
  auto link = make_table_link(connection_, name_);
  if (!link) {
    config_error_ = link.error();
  } else {
    link_ = std::move(*link);
  }
  auto framing = acl::parse_reply_framing(connection_.reply_header);
  if (!framing) {
    config_error_ = Error::Permanent(fmt::format("{}: {}", name_, framing.error().message));
  } else {
    framing_ = *framing;
    decoder_ = acl::ReplyDecoder(*framing);
  }
  if (connection_.axis < 1) {
    config_error_ =
        Error::Permanent(fmt::format("{}: axis {} (must be ≥ 1)", name_, connection_.axis));
  }
  if (!(connection_.timeout_s > 0)) {
    config_error_ = Error::Permanent(
        fmt::format("{}: timeout_s {} (must be positive)", name_, connection_.timeout_s));
  }
}

AcutrolTable::~AcutrolTable() {
  // Closing: the operator panel is not left locked out. Only on a live
  // connection (no reconnecting here); the station releases it earlier, in
  // the safe state (release_control()).
  if (is_open() && remote_held_ && !config_error_) (void)exchange(acl::release_remote());
}

bool AcutrolTable::is_open() const { return link_ && link_->is_open(); }

AcutrolTable::Steady::time_point AcutrolTable::deadline() const {
  return Steady::now() + std::chrono::duration_cast<Steady::duration>(
                             std::chrono::duration<double>(connection_.timeout_s));
}

DeviceHealth AcutrolTable::health() const {
  std::lock_guard lock(mu_);
  return health_->health();
}

std::string AcutrolTable::where() const {
  return fmt::format("{} ({})", name_, link_ ? link_->description() : std::string("no link"));
}

Error AcutrolTable::named(const std::string& command, const Error& e) const {
  return Error{fmt::format("{}: `{}`: {}", where(), command, e.message), e.transient};
}

void AcutrolTable::close_link() {
  if (link_) link_->close();
  decoder_.reset();
  remote_on_connection_ = false;
}

void AcutrolTable::drop(const std::string& why) {
  close_link();
  health_->on_link_failure(why);
}

Status AcutrolTable::ensure_connected(bool ignore_backoff) {
  if (config_error_) return *config_error_;
  if (is_open()) return Status::Ok();
  if (auto st = health_->open_link(*link_, deadline(), name_, where(), ignore_backoff); !st) {
    return st;
  }
  decoder_.reset();
  return first_contact();
}

std::optional<std::string> AcutrolTable::send_line(const std::string& command,
                                                   Steady::time_point deadline) {
  if (auto st = link_->write_all(acl::command_line(command), deadline); !st) {
    return st.error().message;
  }
  return std::nullopt;
}

std::optional<std::string> AcutrolTable::receive(Steady::time_point deadline, std::string& into) {
  const std::size_t before = into.size();
  auto n = link_->read_some(into, deadline);
  if (!n) return n.error().message;
  if (*n > 0) return std::nullopt;
  return before == 0 ? fmt::format("no reply within {:g} s", connection_.timeout_s)
                     : fmt::format("no complete reply within {:g} s; received {}",
                                   connection_.timeout_s, acl::describe_bytes(into));
}

Status AcutrolTable::first_contact() {
  const std::string command = acl::identify();
  const auto t0 = Steady::now();
  const auto deadline = this->deadline();
  auto lost = [&](const std::string& why, bool transient = true) -> Error {
    Error e = named(command, Error{why, transient});
    drop(e.message);
    return e;
  };
  if (auto failed = send_line(command, deadline)) return lost(*failed);
  std::string bytes;
  for (;;) {
    auto first = acl::detect_first_reply(bytes);
    if (!first) return lost(first.error().message);
    if (*first) {
      const acl::FirstReply& r = **first;
      if (r.framing != framing_) {
        return lost(fmt::format("the controller frames its replies {}, not {} as reply_header "
                                "says: set [table] reply_header = \"{}\" (first reply {})",
                                acl::to_string(r.framing), acl::to_string(framing_),
                                acl::to_string(r.framing),
                                acl::describe_bytes(std::string_view(bytes).substr(0, r.consumed))),
                    /*transient=*/false);
      }
      identity_ = r.reply.code == 0 ? r.reply.payload : std::string();
      decoder_.feed(std::string_view(bytes).substr(r.consumed));
      // The handshake does not reset the backoff: a controller that answers
      // it and then drops every request is retried ever more slowly.
      health_->on_success(std::chrono::duration<double, std::milli>(Steady::now() - t0).count(),
                          /*reset_backoff=*/false);
      return Status::Ok();
    }
    if (auto failed = receive(deadline, bytes)) return lost(*failed);
  }
}

Result<acl::Reply> AcutrolTable::roundtrip(const std::string& command,
                                           bool failure_is_link_failure) {
  const auto t0 = Steady::now();
  const auto deadline = this->deadline();
  auto lost = [&](const std::string& why) -> Error {
    Error e = named(command, Error::Transient(why));
    if (failure_is_link_failure) {
      drop(e.message);
    } else {
      close_link();
      health_->on_closed();
    }
    return e;
  };
  if (auto failed = send_line(command, deadline)) return lost(*failed);
  std::string bytes;
  for (;;) {
    decoder_.feed(bytes);
    bytes.clear();
    auto next = decoder_.next();
    if (!next) return lost(next.error().message);
    if (*next) {
      health_->on_success(std::chrono::duration<double, std::milli>(Steady::now() - t0).count());
      return std::move(**next);
    }
    if (auto failed = receive(deadline, bytes)) return lost(*failed);
  }
}

Result<std::string> AcutrolTable::exchange(const std::string& command) {
  auto reply = roundtrip(command);
  if (!reply) return reply.error();
  if (reply->code == 0) return std::move(reply->payload);
  // The controller refused: ask for the text of its code (TM-8004 §4.9.1),
  // unless that query went unanswered before (field firmware may lack it).
  // An unanswered query closes the connection (its reply may still come and
  // would be taken for the next one's), without counting as a link failure:
  // the next call reconnects at once. Either way the error names the code.
  const std::string query = acl::error_text_query(reply->code);
  std::string text;
  if (error_text_unanswered_) {
    text = " (no text: `:Q:E?` went unanswered before)";
  } else if (auto t = roundtrip(query, /*failure_is_link_failure=*/false); !t) {
    error_text_unanswered_ = true;
    std::string_view why = t.error().message;
    if (const auto at = why.find(fmt::format("`{}`: ", query)); at != std::string_view::npos) {
      why.remove_prefix(at + query.size() + 4);
    }
    text = fmt::format(" (no text: `{}` went unanswered: {})", query, why);
  } else if (t->code == 0 && !t->payload.empty()) {
    text = fmt::format(" ({})", t->payload);
  }
  Error e = named(command, Error::Permanent(fmt::format("error code {}{}", reply->code, text)));
  health_->on_refusal(e.message);
  return e;
}

std::string AcutrolTable::identity() const {
  std::lock_guard lock(mu_);
  return identity_;
}

Status AcutrolTable::connect() {
  std::lock_guard lock(mu_);
  if (config_error_) return *config_error_;
  if (is_open()) return Status::Ok();
  return ensure_connected(/*ignore_backoff=*/true);
}

Status AcutrolTable::simple_command(const std::string& command) {
  if (auto st = ensure_connected(false); !st) return st;
  auto r = exchange(command);
  if (!r) return r.error();
  return Status::Ok();
}

Result<TableState> AcutrolTable::read() {
  std::lock_guard lock(mu_);
  if (auto st = ensure_connected(false); !st) return st.error();
  const std::string q = acl::state_query(connection_.axis);
  auto payload = exchange(q);
  if (!payload) return payload.error();
  auto state = acl::parse_state(*payload);
  if (!state) {
    // The reply was framed but its content is wrong: resynchronise anyway.
    Error e = named(q, Error::Transient(state.error().message));
    drop(e.message);
    return e;
  }
  return state;
}

Result<TableLimits> AcutrolTable::limits_locked() {
  if (limits_) return *limits_;
  if (auto st = ensure_connected(false); !st) return st.error();
  const std::string q = acl::limits_query(connection_.axis);
  auto payload = exchange(q);
  if (!payload) return payload.error();
  auto limits = acl::parse_limits(*payload);
  if (!limits) {
    Error e = named(q, Error::Transient(limits.error().message));
    drop(e.message);
    return e;
  }
  limits_ = *limits;
  return *limits;
}

Result<TableLimits> AcutrolTable::limits() {
  std::lock_guard lock(mu_);
  return limits_locked();
}

Status AcutrolTable::servo_on_locked() {
  const std::string q = acl::interlock_query(connection_.axis);
  auto answer = exchange(q);
  if (!answer) return answer.error();
  auto interlock = acl::parse_interlock(*answer);
  if (!interlock) {
    Error e = named(q, Error::Transient(interlock.error().message));
    drop(e.message);
    return e;
  }
  if (*interlock == TableInterlock::kFault) {
    Error e = named(q, Error::Permanent("the interlock is in fault: reset faults first"));
    health_->on_local_error(e.message);
    return e;
  }
  if (*interlock == TableInterlock::kOpen)
    return simple_command(acl::interlock_close(connection_.axis));
  return Status::Ok();
}

Status AcutrolTable::take_remote_locked() {
  if (remote_on_connection_) return Status::Ok();
  auto r = exchange(acl::take_remote());
  if (!r) return r.error();
  remote_on_connection_ = true;
  remote_held_ = true;
  return Status::Ok();
}

Status AcutrolTable::release_control() {
  std::lock_guard lock(mu_);
  if (!remote_held_) return Status::Ok();
  if (auto st = ensure_connected(false); !st) return st;
  auto r = exchange(acl::release_remote());
  if (!r) return r.error();
  remote_held_ = false;
  remote_on_connection_ = false;
  return Status::Ok();
}

Status AcutrolTable::set_rate(double rate_dps) {
  std::lock_guard lock(mu_);
  const std::string command = acl::demand_rate(connection_.axis, rate_dps);
  if (!std::isfinite(rate_dps)) {
    return named(command, Error::Permanent(fmt::format("{} is not a rate", rate_dps)));
  }
  auto limits = limits_locked();
  if (!limits) {
    return Error{fmt::format("{}: rate {:g} °/s not sent, the limits are unknown: {}", name_,
                             rate_dps, limits.error().message),
                 limits.error().transient};
  }
  if (std::fabs(rate_dps) > limits->max_rate_dps) {
    Error e = named(command, Error::Permanent(fmt::format(
                                 "refused, not sent: |{:g}| °/s is beyond the rate limit {:g} °/s",
                                 rate_dps, limits->max_rate_dps)));
    health_->on_local_error(e.message);
    return e;
  }
  if (auto st = ensure_connected(false); !st) return st;
  if (auto st = take_remote_locked(); !st) return st;
  if (auto st = servo_on_locked(); !st) return st;
  return simple_command(command);
}

Status AcutrolTable::set_position(double position_deg) {
  std::lock_guard lock(mu_);
  const std::string command = acl::demand_position(connection_.axis, position_deg);
  if (!std::isfinite(position_deg)) {
    return named(command, Error::Permanent(fmt::format("{} is not a position", position_deg)));
  }
  if (auto st = ensure_connected(false); !st) return st;
  if (auto st = take_remote_locked(); !st) return st;
  if (auto st = servo_on_locked(); !st) return st;
  return simple_command(command);
}

Status AcutrolTable::stop() {
  std::lock_guard lock(mu_);
  return simple_command(acl::mode_off(connection_.axis));
}

Status AcutrolTable::servo_off() {
  std::lock_guard lock(mu_);
  return simple_command(acl::interlock_open(connection_.axis));
}

Status AcutrolTable::reset_faults() {
  std::lock_guard lock(mu_);
  return simple_command(acl::interlock_reset());
}

}  // namespace gyrotherm::drivers
