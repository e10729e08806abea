// The AERO codec (aero.h) against the grammar of the public driver in
// actigraph/RateTableSweepGUI (`RateSweepGUI.py`, class IdealAerosmithTable:
// `'%s\r\n' % buf` sent, a reply line read up to '\r', then the prompt line),
// and AeroTable through a real pseudo-terminal with a scripted peer.
#include "gyrotherm/drivers/aero.h"

#include <gtest/gtest.h>
#include <poll.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/drivers/aero_table.h"
#include "gyrotherm/drivers/pty.h"
#include "test_time.h"

namespace gyrotherm::drivers {
namespace {

using namespace std::chrono_literals;

std::vector<std::string> decode_all(const std::string& bytes, std::size_t chunk) {
  aero::ReplyDecoder d;
  std::vector<std::string> out;
  for (std::size_t i = 0; i < bytes.size(); i += chunk) {
    d.feed(std::string_view(bytes).substr(i, chunk));
    for (;;) {
      auto r = d.next();
      EXPECT_TRUE(r.ok()) << r.error().message;
      if (!r.ok() || !*r) break;
      out.push_back(**r);
    }
  }
  return out;
}

TEST(AeroCodec, CommandLinesAsRateSweepGuiSendsThem) {
  EXPECT_EQ(aero::command_line("JOG", -100), "JOG-100\r\n");  // 'JOG%d' % -100
  EXPECT_EQ(aero::command_line("MOV", 90), "MOV90\r\n");
  EXPECT_EQ(aero::command_line("PPO"), "PPO\r\n");
  EXPECT_EQ(aero::command_line("STA"), "STA\r\n");
}

// RateSweepGUI.py sends JOG, MOV (and RMO, VEL, ACL) with %d, HOF, AMP, FRQ
// with %f: JOG and MOV get whole numbers, anything else is refused, named.
TEST(AeroCodec, JogAndMovTakeWholeNumbersOnly) {
  EXPECT_EQ(*aero::whole_argument("JOG", -100.0, "°/s"), -100);
  EXPECT_EQ(*aero::whole_argument("JOG", 6.9999999999, "°/s"), 7);  // rounding noise
  EXPECT_EQ(*aero::whole_argument("MOV", 359.0, "°"), 359);
  auto half = aero::whole_argument("JOG", 7.5, "°/s");
  ASSERT_FALSE(half.ok());
  EXPECT_FALSE(half.error().transient);
  EXPECT_NE(half.error().message.find("7.5 °/s is not a whole number"), std::string::npos)
      << half.error().message;
  EXPECT_NE(half.error().message.find("'JOG%d'"), std::string::npos) << half.error().message;
  EXPECT_FALSE(aero::whole_argument("MOV", 0.001, "°").ok());
  EXPECT_FALSE(aero::whole_argument("JOG", std::nan(""), "°/s").ok());
  EXPECT_FALSE(aero::whole_argument("JOG", 1e12, "°/s").ok());
}

// A controller that echoes its input: the echoed command line, first in
// the reply, is dropped; any other first line is the answer.
TEST(AeroCodec, AnEchoIsStripped) {
  EXPECT_EQ(aero::strip_echo("PVE\n-10.25", "PVE"), "-10.25");
  EXPECT_EQ(aero::strip_echo("jog12", "JOG12"), "");
  EXPECT_EQ(aero::strip_echo("MOV90\n?", "MOV90"), "?");
  EXPECT_EQ(aero::strip_echo("-10.25", "PVE"), "-10.25");
  EXPECT_EQ(aero::strip_echo("PPO\n1", "PVE"), "PPO\n1");
  EXPECT_EQ(aero::strip_echo("", "STO"), "");
}

TEST(AeroCodec, ReplyThenPromptWholeAndSplit) {
  // A reply line ending in CR, then the prompt line.
  const std::string stream =
      "123.456\r>\r"
      "-20.5\r\n>\r\n"
      "0\r>"
      ">";
  for (std::size_t chunk : {stream.size(), std::size_t{1}, std::size_t{2}}) {
    const auto replies = decode_all(stream, chunk);
    ASSERT_EQ(replies.size(), 4u) << "chunk " << chunk;
    EXPECT_EQ(replies[0], "123.456");
    EXPECT_EQ(replies[1], "-20.5");
    EXPECT_EQ(replies[2], "0");
    EXPECT_EQ(replies[3], "");  // a prompt alone
  }
}

TEST(AeroCodec, RefusalsNumbersStatus) {
  EXPECT_TRUE(aero::is_refusal("?"));
  EXPECT_TRUE(aero::is_refusal("JOG?"));
  EXPECT_FALSE(aero::is_refusal("12.5"));
  EXPECT_DOUBLE_EQ(*aero::parse_number(" 359.99 "), 359.99);
  EXPECT_DOUBLE_EQ(*aero::parse_number("-1.5E+2"), -150.0);
  EXPECT_FALSE(aero::parse_number("12 deg").ok());
  EXPECT_FALSE(aero::parse_number("").ok());
  EXPECT_EQ(*aero::parse_status("0"), 0);
  EXPECT_EQ(*aero::parse_status("17"), 17);
  EXPECT_FALSE(aero::parse_status("1.5").ok());
  EXPECT_FALSE(aero::parse_status("").ok());
}

TEST(AeroCodec, AnEndlessLineIsAnError) {
  aero::ReplyDecoder d;
  d.feed(std::string(aero::kMaxLineBytes + 1, '7'));
  auto r = d.next();
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("malformed"), std::string::npos);
  d.feed("1\r>\r");
  auto ok = d.next();
  ASSERT_TRUE(ok.ok() && *ok);
  EXPECT_EQ(**ok, "1");
}

// A scripted controller on the master side of a pty: `script` answers each
// command line (without "\r\n") with the bytes to send back (nullopt: none).
class PtyPeer {
 public:
  using Script = std::function<std::optional<std::string>(const std::string&)>;
  explicit PtyPeer(Script script) : script_(std::move(script)) {
    auto pty = Pty::open(/*nonblocking_master=*/true);
    if (!pty.ok()) {
      ADD_FAILURE() << pty.error().message;
      std::abort();
    }
    pty_.emplace(std::move(pty).value());
    thread_ = std::thread([this] { run(); });
  }
  ~PtyPeer() {
    stop_ = true;
    thread_.join();
  }
  std::string device() const { return pty_->slave_path(); }
  std::vector<std::string> commands() const {
    std::lock_guard lock(mu_);
    return commands_;
  }
  // Sends bytes now (from the test thread).
  void send(const std::string& bytes) {
    std::lock_guard lock(write_mu_);
    (void)pty_->write_master(
        std::span(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size()));
  }
  void hang_up() {
    stop_ = true;
    thread_.join();
    pty_->close_master();
    thread_ = std::thread([] {});
  }

 private:
  void run() {
    std::string buf;
    while (!stop_) {
      pollfd p{pty_->master_fd(), POLLIN, 0};
      if (::poll(&p, 1, 10) <= 0) continue;
      char tmp[256];
      const ssize_t n = ::read(pty_->master_fd(), tmp, sizeof tmp);
      if (n <= 0) continue;
      buf.append(tmp, static_cast<std::size_t>(n));
      for (auto end = buf.find("\r\n"); end != std::string::npos; end = buf.find("\r\n")) {
        const std::string command = buf.substr(0, end);
        buf.erase(0, end + 2);
        {
          std::lock_guard lock(mu_);
          commands_.push_back(command);
        }
        if (auto out = script_(command)) send(*out);
      }
    }
  }

  Script script_;
  std::optional<Pty> pty_;
  std::atomic<bool> stop_{false};
  mutable std::mutex mu_;
  std::mutex write_mu_;
  std::vector<std::string> commands_;
  std::thread thread_;
};

std::optional<std::string> answer(const std::string& text) { return text + "\r>\r"; }

TableConnection aero_connection(const PtyPeer& peer, double timeout_s = 1.0) {
  TableConnection c;
  c.profile = "aero";
  c.device = peer.device();
  c.timeout_s = timeout_s;
  return c;
}

const TableLimits kDeclared{300.0, 100.0, std::nullopt};

TEST(AeroTable, ReadAsksVelocityPositionStatus) {
  std::atomic<int> status{0};
  PtyPeer peer([&](const std::string& c) -> std::optional<std::string> {
    if (c == "PVE") return answer("-10.25");
    if (c == "PPO") return answer("45.5");
    if (c == "STA") return answer(std::to_string(status.load()));
    return answer("");
  });
  AeroTable table(aero_connection(peer), kDeclared, "aero table");
  ASSERT_TRUE(table.connect().ok());
  auto s = table.read();
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_DOUBLE_EQ(s->rate_dps, -10.25);
  EXPECT_DOUBLE_EQ(s->position_deg, 45.5);
  EXPECT_EQ(s->interlock, TableInterlock::kClosed);
  EXPECT_EQ(s->fault, "");
  const std::vector<std::string> expected = {"PVE", "PPO", "STA"};
  EXPECT_EQ(peer.commands(), expected);

  status = 4;
  s = table.read();
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->interlock, TableInterlock::kFault);
  EXPECT_EQ(s->fault, "STA 4");
}

TEST(AeroTable, CommandsAndLimits) {
  PtyPeer peer([&](const std::string&) { return answer(""); });
  AeroTable table(aero_connection(peer), kDeclared);
  ASSERT_TRUE(table.set_rate(-100).ok());
  ASSERT_TRUE(table.set_position(90).ok());
  ASSERT_TRUE(table.stop().ok());
  ASSERT_TRUE(table.servo_off().ok());  // no servo-off known: a stop
  ASSERT_TRUE(table.reset_faults().ok());
  const std::vector<std::string> expected = {"JOG-100", "MOV90", "STO", "STO"};
  ASSERT_TRUE(testing::wait_for_condition([&] { return peer.commands().size() == 4; }, 2000ms));
  EXPECT_EQ(peer.commands(), expected);

  const Status st = table.set_rate(300.5);
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.error().message.find("beyond the rate limit 300"), std::string::npos);
  auto limits = table.limits();
  ASSERT_TRUE(limits.ok());
  EXPECT_DOUBLE_EQ(limits->max_rate_dps, 300.0);
  EXPECT_DOUBLE_EQ(limits->max_accel_dps2, 100.0);
  EXPECT_EQ(peer.commands().size(), 4u);  // nothing sent for the refused rate
}

// RateSweepGUI.py sends JOG without reading and swallows the answer later:
// an answer that comes after the timeout is taken before the next command.
TEST(AeroTable, AJogAnswerThatComesLateIsSwallowedBeforeTheNextCommand) {
  std::atomic<bool> refuse_late{false};
  std::mutex m;
  std::optional<std::string> late;  // what the peer owes for JOG
  PtyPeer* peer_ptr = nullptr;
  PtyPeer peer([&](const std::string& c) -> std::optional<std::string> {
    if (c.rfind("JOG", 0) == 0) {
      std::lock_guard lock(m);
      late = refuse_late ? "?\r>\r" : "\r>\r";
      return std::nullopt;  // answered only when the test says so
    }
    if (c == "PVE") return answer("5");
    if (c == "PPO") return answer("10");
    if (c == "STA") return answer("0");
    return answer("");
  });
  peer_ptr = &peer;
  AeroTable table(aero_connection(peer, 0.1), kDeclared, "aero table");
  ASSERT_TRUE(table.set_rate(5).ok());  // no answer within 0.1 s: not an error
  {
    std::lock_guard lock(m);
    ASSERT_TRUE(late.has_value());
    peer_ptr->send(*late);  // the JOG answer arrives late
  }
  auto s = table.read();
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_DOUBLE_EQ(s->rate_dps, 5);  // not shifted by the late answer
  EXPECT_DOUBLE_EQ(s->position_deg, 10);
  EXPECT_EQ(s->mode, TableMode::kRate);

  refuse_late = true;
  ASSERT_TRUE(table.set_rate(7).ok());
  {
    std::lock_guard lock(m);
    peer_ptr->send(*late);
  }
  auto r = table.read();
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("JOG7"), std::string::npos) << r.error().message;
  EXPECT_NE(r.error().message.find("refused"), std::string::npos);
  ASSERT_TRUE(table.read().ok());  // and then things go on
}

TEST(AeroTable, ARefusalNamesTheCommand) {
  PtyPeer peer([&](const std::string& c) -> std::optional<std::string> {
    if (c.rfind("MOV", 0) == 0) return answer("?");
    return answer("");
  });
  AeroTable table(aero_connection(peer), kDeclared, "aero table");
  const Status st = table.set_position(400);
  ASSERT_FALSE(st.ok());
  EXPECT_FALSE(st.error().transient);
  EXPECT_NE(st.error().message.find("aero table"), std::string::npos);
  EXPECT_NE(st.error().message.find("MOV400"), std::string::npos);
}

TEST(AeroTable, SilenceAndHangUpAreTransientWithBackoff) {
  std::atomic<bool> mute{true};
  PtyPeer peer([&](const std::string& c) -> std::optional<std::string> {
    if (mute) return std::nullopt;
    return answer(c == "STA" ? "0" : "1");
  });
  ManualWallClock clock(0);
  AeroTable table(aero_connection(peer, 0.1), kDeclared, "aero table", clock);
  auto r = table.read();
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(r.error().transient);
  EXPECT_NE(r.error().message.find("no reply within 0.1 s"), std::string::npos)
      << r.error().message;
  r = table.read();  // within the backoff: not even tried
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("next attempt"), std::string::npos);
  EXPECT_EQ(peer.commands().size(), 1u);
  mute = false;
  clock.advance(0.6);
  ASSERT_TRUE(table.read().ok());
  EXPECT_EQ(table.health().reconnects, 1u);

  peer.hang_up();
  r = table.read();
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(r.error().transient);
  EXPECT_FALSE(table.health().connected);
}

}  // namespace
}  // namespace gyrotherm::drivers
