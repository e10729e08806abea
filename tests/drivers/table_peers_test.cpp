// AcutrolTable and AeroTable against peers written from the public manuals
// (tests/support/acl_peer.h on loopback TCP, aero_peer.h on a real pty),
// not from our simulator: the manual's `Close`, the remote lockout taken
// for motion and handed back, an error query the firmware does not answer,
// each reply framing and an unknown one, whole-number JOG/MOV and an echo.
// Then each protocol over the other transport ([table] transport): ACL on a
// serial line (a real pty: TM-9411's RS-232 interface) and AERO through a
// TCP serial device server (loopback TCP).
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <chrono>
#include <string>
#include <vector>

#include "acl_peer.h"
#include "aero_peer.h"
#include "gyrotherm/core/clock.h"
#include "gyrotherm/drivers/acl.h"
#include "gyrotherm/drivers/acutrol_table.h"
#include "gyrotherm/drivers/aero_table.h"
#include "peer_end.h"
#include "test_time.h"

namespace gyrotherm::drivers {
namespace {

using namespace std::chrono_literals;
using testing::AclPeer;
using testing::AeroPeer;

TableConnection acl_connection(const AclPeer& peer, std::string reply_header = "ascii",
                               double timeout_s = 1.0) {
  TableConnection c;
  c.profile = "acutrol";
  c.host = "127.0.0.1";
  c.port = peer.port();
  c.reply_header = std::move(reply_header);
  c.timeout_s = timeout_s;
  return c;
}

std::string joined(const std::vector<std::string>& v) { return ::testing::PrintToString(v); }

// TM-8004 §4.5.3: a closed interlock is `Close`. Read as servoed, so
// set_rate does not close it again; `Closed` (field firmware) the same.
TEST(AcutrolTableWithPeer, TheManualsCloseIsAServoedAxis) {
  for (const std::string word : {"Close", "Closed"}) {
    AclPeer::Options o;
    o.closed_word = word;
    AclPeer peer(o);
    AclPeer::State s;
    s.interlock = AclPeer::Interlock::kClosed;
    peer.set_state(s);
    AcutrolTable table(acl_connection(peer), "turntable");
    auto state = table.read();
    ASSERT_TRUE(state.ok()) << word << ": " << state.error().message;
    EXPECT_EQ(state->interlock, TableInterlock::kClosed) << word;
    EXPECT_EQ(state->mode, TableMode::kOff) << word;  // the manual's `O`
    ASSERT_TRUE(table.set_rate(10).ok()) << word;
    for (const auto& c : peer.commands()) EXPECT_NE(c, ":I:C 1") << word;
    EXPECT_EQ(peer.state().rate_dps, 10.0) << word;
  }
}

// `:U:L ON` is taken before the first motion command, not at connect;
// release_control() sends `:U:L OFF` once, and the next motion takes it
// again. The peer logs the whole conversation in order.
TEST(AcutrolTableWithPeer, RemoteControlIsTakenForMotionAndHandedBack) {
  AclPeer peer;
  AcutrolTable table(acl_connection(peer), "turntable");
  ASSERT_TRUE(table.read().ok());
  EXPECT_FALSE(peer.state().lockout) << "reading does not lock the panel out";
  ASSERT_TRUE(table.release_control().ok());  // nothing taken: nothing sent
  ASSERT_TRUE(table.set_rate(20).ok());
  EXPECT_TRUE(peer.state().lockout);
  ASSERT_TRUE(table.stop().ok());
  ASSERT_TRUE(table.servo_off().ok());
  ASSERT_TRUE(table.release_control().ok());
  EXPECT_FALSE(peer.state().lockout);
  ASSERT_TRUE(table.release_control().ok());  // already handed back
  const std::vector<std::string> expected = {
      "*IDN?",   ":M? 1", ":I? 1",  ":R:R? 1",   ":R:P? 1", ":L:R? R,1", ":L:A? R,1", ":L:V? R,1",
      ":U:L ON", ":I? 1", ":I:C 1", ":D:R 1,20", ":M:R 1",  ":M:O 1",    ":I:O 1",    ":U:L OFF"};
  EXPECT_EQ(peer.commands(), expected) << joined(peer.commands());
  EXPECT_EQ(table.identity(), "Acutronic R&D USA,Acutrol3000,0,A8800-001-01.000-a");

  peer.clear_log();
  ASSERT_TRUE(table.set_position(90).ok());
  const std::vector<std::string> again = {":U:L ON", ":I? 1", ":I:C 1", ":D:P 1,90", ":M:P 1"};
  EXPECT_EQ(peer.commands(), again) << joined(peer.commands());
  EXPECT_EQ(peer.connections(), 1);
}

// The driver closing (the daemon or the CLI exiting) hands the panel back
// when it still holds it, so the operator is not locked out of a table the
// daemon no longer drives.
TEST(AcutrolTableWithPeer, ClosingTheDriverHandsThePanelBack) {
  AclPeer peer;
  {
    AcutrolTable table(acl_connection(peer), "turntable");
    ASSERT_TRUE(table.set_rate(5).ok());
    EXPECT_TRUE(peer.state().lockout);
  }
  ASSERT_TRUE(testing::wait_for_condition([&] { return !peer.state().lockout; }, 2000ms))
      << joined(peer.commands());
  EXPECT_EQ(peer.commands().back(), ":U:L OFF");
}

// Field firmware may not implement `:Q:E?` (TM-8004 §4.9.1): the refusal
// still names its code and command, is permanent, the link is reopened at
// once (not a failure with a backoff), and the query is not asked again.
TEST(AcutrolTableWithPeer, AnUnansweredErrorQueryDoesNotHideTheCode) {
  AclPeer::Options o;
  o.answer_error_query = false;
  AclPeer peer(o);
  peer.refuse(":D:P", 12, "Parameter out of range");
  ManualWallClock clock(100.0);  // never advanced: no backoff ever runs out
  AcutrolTable table(acl_connection(peer, "ascii", 0.3), "turntable", clock);
  const Status st = table.set_position(400);
  ASSERT_FALSE(st.ok());
  const std::string& m = st.error().message;
  EXPECT_FALSE(st.error().transient) << m;
  EXPECT_NE(m.find("turntable"), std::string::npos) << m;
  EXPECT_NE(m.find("`:D:P 1,400;:M:P 1`"), std::string::npos) << m;
  EXPECT_NE(m.find("error code 12"), std::string::npos) << m;
  EXPECT_NE(m.find("`:Q:E? 12` went unanswered"), std::string::npos) << m;
  EXPECT_EQ(table.health().last_error, m);

  auto r = table.read();  // at once: a new connection, no backoff to wait out
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(peer.connections(), 2);

  const auto t0 = std::chrono::steady_clock::now();
  const Status again = table.set_position(400);
  const double waited_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_FALSE(again.ok());
  EXPECT_NE(again.error().message.find("error code 12"), std::string::npos)
      << again.error().message;
  EXPECT_LT(waited_s, 0.3) << "the error query was awaited again";
  int asked = 0;
  for (const auto& c : peer.commands()) asked += c == ":Q:E? 12";
  EXPECT_EQ(asked, 1) << joined(peer.commands());
  EXPECT_TRUE(table.read().ok());
}

// Each framing, with each way a command without data may answer (TM-9389:
// CR/LF; ac117.json: OK; or nothing), works end to end once reply_header
// names it; the mode words of the manual (`P`) and of the field (`Position`).
TEST(AcutrolTableWithPeer, EveryFramingAndCommandAnswer) {
  const std::vector<std::pair<AclPeer::Framing, std::string>> framings{
      {AclPeer::Framing::kAscii, "ascii"},
      {AclPeer::Framing::kBinaryLe, "binary-le"},
      {AclPeer::Framing::kBinaryBe, "binary-be"},
      {AclPeer::Framing::kLine, "line"}};
  for (const auto& [framing, name] : framings) {
    for (const auto answer : {AclPeer::CommandAnswer::kCrLf, AclPeer::CommandAnswer::kOk,
                              AclPeer::CommandAnswer::kEmpty}) {
      const std::string where = name + " answer " + std::to_string(static_cast<int>(answer));
      AclPeer::Options o;
      o.framing = framing;
      o.command_answer = answer;
      o.long_mode_words = answer == AclPeer::CommandAnswer::kOk;
      AclPeer peer(o);
      AcutrolTable table(acl_connection(peer, name), "turntable");
      ASSERT_TRUE(table.connect().ok()) << where;
      EXPECT_EQ(table.identity(), o.idn) << where;
      ASSERT_TRUE(table.set_position(45).ok()) << where;
      auto s = table.read();
      ASSERT_TRUE(s.ok()) << where << ": " << s.error().message;
      EXPECT_EQ(s->mode, TableMode::kPosition) << where;
      EXPECT_EQ(s->interlock, TableInterlock::kClosed) << where;
      EXPECT_DOUBLE_EQ(s->position_deg, 45.0) << where;
      ASSERT_TRUE(table.stop().ok()) << where;
      ASSERT_TRUE(table.release_control().ok()) << where;
      EXPECT_FALSE(peer.state().lockout) << where;
      EXPECT_EQ(peer.connections(), 1) << where;
    }
  }
}

// reply_header naming another framing than the controller's: refused at the
// first contact, naming the framing seen and the setting to change.
TEST(AcutrolTableWithPeer, AFramingOtherThanConfiguredIsNamed) {
  AclPeer::Options o;
  o.framing = AclPeer::Framing::kBinaryLe;
  AclPeer peer(o);
  AcutrolTable table(acl_connection(peer, "ascii"), "turntable");
  const Status st = table.connect();
  ASSERT_FALSE(st.ok());
  const std::string& m = st.error().message;
  EXPECT_FALSE(st.error().transient) << m;
  EXPECT_NE(m.find("`*IDN?`"), std::string::npos) << m;
  EXPECT_NE(m.find("frames its replies binary-le, not ascii"), std::string::npos) << m;
  EXPECT_NE(m.find("reply_header = \"binary-le\""), std::string::npos) << m;
  EXPECT_NE(m.find(R"(\x00\x00\x00\x00)"), std::string::npos) << m;
  EXPECT_EQ(peer.commands(), std::vector<std::string>{"*IDN?"}) << "nothing sent after it";
}

// A first reply in no framing we know: refused, naming the bytes received,
// printable-escaped, so that the technician can tell what the controller
// speaks (docs/table.md, "Capturing a reply").
TEST(AcutrolTableWithPeer, AnUnknownFramingIsRefusedNamingTheBytes) {
  AclPeer::Options o;
  o.idn_reply_bytes = std::string("\x02\x00\x30\x00", 4) + "Acutronic\r\n";
  AclPeer peer(o);
  AcutrolTable table(acl_connection(peer, "ascii", 0.3), "turntable");
  const Status st = table.connect();
  ASSERT_FALSE(st.ok());
  const std::string& m = st.error().message;
  EXPECT_NE(m.find("turntable (127.0.0.1:"), std::string::npos) << m;
  EXPECT_NE(m.find("fits no known framing"), std::string::npos) << m;
  EXPECT_NE(m.find(R"("\x02\x000\x00Acutronic\x0d\x0a" (15 bytes))"), std::string::npos) << m;
  EXPECT_FALSE(table.health().connected);
}

// ---------------------------------------------------------------- AERO

// JOG and MOV go out as whole numbers; a rate or position that is not one
// is refused before anything is sent, naming it: a controller that
// truncates (this peer does, like `'JOG%d' % 7.5` in RateSweepGUI.py) would
// otherwise spin at 7 °/s for a demanded 7.5.
TEST(AeroTableWithPeer, RatesAndPositionsGoOutAsWholeNumbers) {
  AeroPeer peer;  // truncates decimals
  TableConnection c;
  c.profile = "aero";
  c.device = peer.device();
  AeroTable table(c, TableLimits{300.0, 100.0, std::nullopt}, "aero table");
  const Status st = table.set_rate(7.5);
  ASSERT_FALSE(st.ok());
  const std::string& m = st.error().message;
  EXPECT_FALSE(st.error().transient);
  EXPECT_NE(m.find("aero table"), std::string::npos) << m;
  EXPECT_NE(m.find("refused, not sent: 7.5 °/s is not a whole number"), std::string::npos) << m;
  EXPECT_NE(m.find("JOG"), std::string::npos) << m;
  const Status pos = table.set_position(90.25);
  ASSERT_FALSE(pos.ok());
  EXPECT_NE(pos.error().message.find("90.25 ° is not a whole number"), std::string::npos)
      << pos.error().message;
  EXPECT_TRUE(peer.commands().empty()) << joined(peer.commands());

  ASSERT_TRUE(table.set_rate(-100).ok());
  ASSERT_TRUE(table.set_rate(7.0000000001).ok());  // a whole number up to rounding
  ASSERT_TRUE(table.set_position(90).ok());
  const std::vector<std::string> expected{"JOG-100", "JOG7", "MOV90"};
  ASSERT_TRUE(testing::wait_for_condition([&] { return peer.commands().size() == 3; }, 2000ms));
  EXPECT_EQ(peer.commands(), expected);
  EXPECT_EQ(peer.state().position_deg, 90.0);
}

// A controller that echoes each command line before its answer: the echo
// is not taken for the answer (PVE's "PVE" would not read as a number), nor
// for a refusal, also when JOG's answer comes late.
TEST(AeroTableWithPeer, AnEchoedCommandLineIsSkipped) {
  AeroPeer::Options o;
  o.echo = true;
  o.answer_motion_at_once = false;
  AeroPeer peer(o);
  TableConnection c;
  c.profile = "aero";
  c.device = peer.device();
  c.timeout_s = 0.2;
  AeroTable table(c, TableLimits{300.0, 100.0, std::nullopt}, "aero table");
  ASSERT_TRUE(table.set_rate(12).ok());  // answer held back: taken before the next command
  ASSERT_TRUE(testing::wait_for_condition([&] { return peer.answer_held() == 1; }, 2000ms));
  auto s = table.read();
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_DOUBLE_EQ(s->rate_dps, 12.0);
  EXPECT_EQ(s->interlock, TableInterlock::kClosed);
  peer.set_status(5);
  s = table.read();
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_EQ(s->fault, "STA 5");
  const std::vector<std::string> expected{"JOG12", "PVE", "PPO", "STA", "PVE", "PPO", "STA"};
  EXPECT_EQ(peer.commands(), expected);
}

// ------------------------------------------------- the other transport

// ACL on a serial line (transport = "serial"): the same conversation as
// over TCP, in every framing, on a real pty; the line is one session, so
// the lockout taken for motion is handed back on it.
TEST(AcutrolTableWithPeer, AclOnASerialLineSpeaksAsOverTcp) {
  const std::vector<std::pair<AclPeer::Framing, std::string>> framings{
      {AclPeer::Framing::kAscii, "ascii"},
      {AclPeer::Framing::kBinaryLe, "binary-le"},
      {AclPeer::Framing::kBinaryBe, "binary-be"},
      {AclPeer::Framing::kLine, "line"}};
  for (const auto& [framing, name] : framings) {
    AclPeer::Options o;
    o.transport = testing::PeerEnd::Transport::kPty;
    o.framing = framing;
    AclPeer peer(o);
    TableConnection c;
    c.profile = "acutrol";
    c.transport = "serial";
    c.device = peer.device();
    c.reply_header = name;
    AcutrolTable table(c, "turntable");
    ASSERT_TRUE(table.connect().ok()) << name;
    EXPECT_EQ(table.identity(), o.idn) << name;
    ASSERT_TRUE(table.set_rate(20).ok()) << name;
    auto s = table.read();
    ASSERT_TRUE(s.ok()) << name << ": " << s.error().message;
    EXPECT_EQ(s->mode, TableMode::kRate) << name;
    EXPECT_DOUBLE_EQ(s->rate_dps, 20.0) << name;
    ASSERT_TRUE(table.stop().ok()) << name;
    ASSERT_TRUE(table.servo_off().ok()) << name;
    ASSERT_TRUE(table.release_control().ok()) << name;
    const std::vector<std::string> expected = {
        "*IDN?",  ":L:R? R,1", ":L:A? R,1", ":L:V? R,1", ":U:L ON", ":I? 1",  ":I:C 1", ":D:R 1,20",
        ":M:R 1", ":M? 1",     ":I? 1",     ":R:R? 1",   ":R:P? 1", ":M:O 1", ":I:O 1", ":U:L OFF"};
    EXPECT_EQ(peer.commands(), expected) << name << ": " << joined(peer.commands());
    EXPECT_FALSE(peer.state().lockout) << name;
    EXPECT_TRUE(table.health().connected) << name;
  }
}

// The framing check of `*IDN?` holds on a serial line too, and the error
// names the device instead of a host and port.
TEST(AcutrolTableWithPeer, OnASerialLineAFramingOtherThanConfiguredNamesTheDevice) {
  AclPeer::Options o;
  o.transport = testing::PeerEnd::Transport::kPty;
  o.framing = AclPeer::Framing::kBinaryLe;
  AclPeer peer(o);
  TableConnection c;
  c.profile = "acutrol";
  c.transport = "serial";
  c.device = peer.device();
  AcutrolTable table(c, "turntable");
  const Status st = table.connect();
  ASSERT_FALSE(st.ok());
  const std::string& m = st.error().message;
  EXPECT_FALSE(st.error().transient) << m;
  EXPECT_EQ(m.rfind(fmt::format("turntable ({}): `*IDN?`: ", peer.device()), 0), 0u) << m;
  EXPECT_NE(m.find("frames its replies binary-le, not ascii"), std::string::npos) << m;
  EXPECT_EQ(peer.commands(), std::vector<std::string>{"*IDN?"}) << "nothing sent after it";
}

TableConnection aero_over_tcp(const AeroPeer& peer, double timeout_s = 1.0) {
  TableConnection c;
  c.profile = "aero";
  c.transport = "tcp";
  c.host = "127.0.0.1";
  c.port = peer.port();
  c.timeout_s = timeout_s;
  return c;
}

// AERO through a serial device server (transport = "tcp"): commands,
// readings, and a JOG answer that comes late (taken before the next
// command), as on the serial line; errors name host and port.
TEST(AeroTableWithPeer, AeroThroughATcpSerialServer) {
  AeroPeer::Options o;
  o.transport = testing::PeerEnd::Transport::kTcp;
  o.answer_motion_at_once = false;
  AeroPeer peer(o);
  AeroTable table(aero_over_tcp(peer, 0.2), TableLimits{300.0, 100.0, std::nullopt}, "aero table");
  ASSERT_TRUE(table.connect().ok());
  ASSERT_TRUE(table.set_rate(-100).ok());  // answer held back
  ASSERT_TRUE(testing::wait_for_condition([&] { return peer.answer_held() == 1; }, 2000ms));
  auto s = table.read();
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_DOUBLE_EQ(s->rate_dps, -100.0);
  EXPECT_EQ(s->mode, TableMode::kRate);
  ASSERT_TRUE(table.set_position(90).ok());
  EXPECT_EQ(peer.state().position_deg, 90.0);
  const std::vector<std::string> expected{"JOG-100", "PVE", "PPO", "STA", "MOV90"};
  EXPECT_EQ(peer.commands(), expected) << joined(peer.commands());
  EXPECT_EQ(peer.connections(), 1);

  const Status st = table.set_rate(7.5);
  ASSERT_FALSE(st.ok());
  EXPECT_EQ(st.error().message.rfind(
                fmt::format("aero table (127.0.0.1:{}): `JOG7.5`: ", peer.port()), 0),
            0u)
      << st.error().message;
}

// The server dropping the session is a link failure like a hang-up of the
// serial line: transient, the backoff runs, then a new connection.
TEST(AeroTableWithPeer, ADroppedTcpSessionReconnectsAfterTheBackoff) {
  AeroPeer::Options o;
  o.transport = testing::PeerEnd::Transport::kTcp;
  AeroPeer peer(o);
  ManualWallClock clock(0);
  AeroTable table(aero_over_tcp(peer), TableLimits{300.0, 100.0, std::nullopt}, "aero table",
                  clock);
  ASSERT_TRUE(table.read().ok());
  peer.hang_up();
  auto r = table.read();
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(r.error().transient) << r.error().message;
  EXPECT_FALSE(table.health().connected);
  r = table.read();  // within the backoff: not even tried
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("next attempt"), std::string::npos) << r.error().message;
  EXPECT_EQ(peer.connections(), 1);
  clock.advance(0.6);
  r = table.read();
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(peer.connections(), 2);
  EXPECT_EQ(table.health().reconnects, 1u);
}

}  // namespace
}  // namespace gyrotherm::drivers
